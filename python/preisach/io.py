"""Records on disk: CSV with a header (``t,u,y``; ``t,r`` for references) or ``.npz``
with arrays of the same names. Output files are written to a temporary name and
renamed, so a failed write never leaves a half file behind."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable, Mapping, Optional, Sequence, Union

import numpy as np
from numpy.typing import NDArray

PathLike = Union[str, "os.PathLike[str]"]


def read_record(path: PathLike, required: Sequence[str] = ("t", "u", "y")) -> dict[str, NDArray[np.float64]]:
    """Read a record from a CSV file with a header (``t,u,y``; ``t,r`` for references) or
    from an ``.npz`` file with arrays of those names.

    Parameters
    ----------
    path : str or path-like
        The record. CSV: a header line naming the columns, then one row per sample.
    required : sequence of str
        The columns that must be present (default ``("t", "u", "y")``); any others are
        returned too.

    Returns
    -------
    dict of str to float64 array
        One 1-D array per column, all of the same length.

    Raises
    ------
    ValueError
        Naming the file and the problem: missing columns, mismatched lengths, no rows,
        NaN or inf (with the row), a time column ``t`` that does not increase strictly
        (with the row).
    """
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such file")
    cols = _read_npz(p) if p.suffix.lower() == ".npz" else _read_csv(p)
    missing = [c for c in required if c not in cols]
    if missing:
        raise ValueError(f"{p}: missing column(s) {', '.join(missing)} (has {', '.join(cols) or 'none'})")
    lengths = {k: len(v) for k, v in cols.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{p}: columns have mismatched lengths {lengths}")
    if any(v.size == 0 for v in cols.values()) or not cols:
        raise ValueError(f"{p}: empty record (no rows)")
    line = 2 if p.suffix.lower() != ".npz" else None  # CSV: row 0 is on line 2, after the header
    for c in list(required) + (["t"] if "t" in cols and "t" not in required else []):
        v = cols[c]
        bad = ~np.isfinite(v)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"{p}: {'NaN' if np.isnan(v[i]) else 'inf'} in column {c} at row {i}{_line(line, i)}")
    if "t" in cols and cols["t"].size > 1:
        t = cols["t"]
        step = np.diff(t)
        if not np.all(step > 0):
            i = int(np.argmax(~(step > 0))) + 1
            raise ValueError(f"{p}: column t must increase strictly, but row {i}{_line(line, i)} has "
                             f"t = {t[i]:.17g} after {t[i - 1]:.17g}")
    return cols


def _line(first: Optional[int], i: int) -> str:
    return "" if first is None else f" (line {first + i})"


def _read_npz(p: Path) -> dict[str, NDArray[np.float64]]:
    cols: dict[str, NDArray[np.float64]] = {}
    try:
        with open(p, "rb") as f, np.load(f, allow_pickle=False) as z:  # our handle: closed on any error
            for k in z.files:
                cols[k] = np.asarray(z[k], dtype=np.float64).ravel()
    except Exception as exc:  # zipfile, zlib and numpy raise many kinds on corrupt files
        raise ValueError(f"{p}: not a readable .npz file ({type(exc).__name__}: {exc})") from None
    return cols


def _read_csv(p: Path) -> dict[str, NDArray[np.float64]]:
    try:
        with open(p, encoding="utf-8") as f:
            header = f.readline()
            has_rows = any(line.strip() for line in f)
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{p}: cannot read ({exc})") from None
    names = [h.strip().strip('"') for h in header.strip().split(",")]
    if not header.strip() or any(not n for n in names):
        raise ValueError(f"{p}: expected a CSV header such as 't,u,y', got {header.strip()!r}")
    if not has_rows:  # numpy would warn "input contained no data"
        raise ValueError(f"{p}: empty record (a header, no rows)")
    try:
        data = np.loadtxt(p, delimiter=",", skiprows=1, dtype=np.float64, ndmin=2)
    except ValueError as exc:
        raise ValueError(f"{p}: malformed CSV ({exc})") from None
    if data.shape[1] != len(names):
        raise ValueError(f"{p}: header has {len(names)} columns but rows have {data.shape[1]}")
    return {n: np.ascontiguousarray(data[:, i]) for i, n in enumerate(names)}


def check_writable(path: PathLike, what: str, directory: bool = False) -> None:
    """Raise ``ValueError`` naming ``what`` (e.g. ``"--json"``) and ``path`` if an output
    cannot be written there, before any work is done. ``directory``: ``path`` is a
    directory that may not exist yet (it is created later). Nothing is created here."""
    p = Path(path)
    if directory:
        if p.exists() and not p.is_dir():
            raise ValueError(f"{what}: {p} exists and is not a directory")
        probe = p
        while not probe.exists() and probe != probe.parent:
            probe = probe.parent
        if not probe.is_dir():
            raise ValueError(f"{what}: cannot create {p}: {probe} is not a directory")
    else:
        if p.is_dir():
            raise ValueError(f"{what}: {p} is a directory, not a file name")
        probe = p.parent if str(p.parent) else Path(".")
        if not probe.is_dir():
            raise ValueError(f"{what}: cannot write {p}: directory {probe} does not exist")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise ValueError(f"{what}: cannot write {p}: no permission to write in {probe}")


def atomic_write(path: PathLike, write: Callable[[str], None]) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, flush it to disk
    (``fsync``), then rename it over ``path`` and flush the directory. A process killed
    at any point leaves the old file or the new one, never a torn one (at worst a
    stray ``.NAME.*.tmp`` beside it). On any error the temporary file is removed and
    ``path`` is untouched; an ``OSError`` is reported as a ``ValueError`` naming
    ``path`` (not the temporary file)."""
    p = Path(path)
    d = p.parent if str(p.parent) else Path(".")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=d)
    except OSError as exc:
        raise ValueError(f"{p}: cannot write ({exc.strerror or exc})") from None
    os.close(fd)
    try:
        write(tmp)
        # mkstemp creates 0600; give the file the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        _fsync(tmp)
        os.replace(tmp, p)
        _fsync(d, directory=True)
    except OSError as exc:
        _unlink(tmp)
        raise ValueError(f"{p}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        _unlink(tmp)
        raise


def _fsync(path: PathLike, directory: bool = False) -> None:
    """Flush a file's (or a directory's entries') data to disk. Directories that cannot
    be opened or synced (some file systems) are skipped."""
    try:
        fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    except OSError:
        if directory:
            return
        raise
    try:
        os.fsync(fd)
    except OSError:
        if not directory:
            raise
    finally:
        os.close(fd)


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


def write_csv(path: PathLike, columns: Mapping[str, NDArray[np.float64]]) -> None:
    """Write equal-length columns as a CSV with a header, atomically."""
    names = list(columns)
    data = np.column_stack([np.asarray(columns[n], dtype=np.float64) for n in names])

    def _w(tmp: str) -> None:
        np.savetxt(tmp, data, delimiter=",", header=",".join(names), comments="", fmt="%.17g")

    atomic_write(path, _w)


def write_text(path: PathLike, text: str) -> None:
    """Write text atomically."""

    def _w(tmp: str) -> None:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)

    atomic_write(path, _w)
