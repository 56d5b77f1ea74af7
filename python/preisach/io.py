"""Records on disk: CSV with a header (``t,u,y``; ``t,r`` for references) or ``.npz``
with arrays of the same names. Output files are written to a temporary name and
renamed, so a failed write never leaves a half file behind."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable, Mapping, Sequence, Union

import numpy as np
from numpy.typing import NDArray

PathLike = Union[str, "os.PathLike[str]"]


def read_record(path: PathLike, required: Sequence[str]) -> dict[str, NDArray[np.float64]]:
    """Read the columns ``required`` (and any others present) from a CSV or ``.npz``
    record. Errors name the file and the problem: missing columns, mismatched lengths,
    NaN/inf (with the row), empty records."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such file")
    cols: dict[str, NDArray[np.float64]] = {}
    if p.suffix.lower() == ".npz":
        try:
            with np.load(p, allow_pickle=False) as z:
                for k in z.files:
                    cols[k] = np.asarray(z[k], dtype=np.float64).ravel()
        except (OSError, ValueError) as exc:
            raise ValueError(f"{p}: not a readable .npz file ({exc})") from None
    else:
        try:
            with open(p, encoding="utf-8") as f:
                header = f.readline()
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"{p}: cannot read ({exc})") from None
        names = [h.strip().strip('"') for h in header.strip().split(",")]
        if not header.strip() or any(not n for n in names):
            raise ValueError(f"{p}: expected a CSV header such as 't,u,y', got {header.strip()!r}")
        try:
            data = np.loadtxt(p, delimiter=",", skiprows=1, dtype=np.float64, ndmin=2)
        except ValueError as exc:
            raise ValueError(f"{p}: malformed CSV ({exc})") from None
        if data.size == 0:
            data = np.zeros((0, len(names)))
        if data.shape[1] != len(names):
            raise ValueError(f"{p}: header has {len(names)} columns but rows have {data.shape[1]}")
        cols = {n: np.ascontiguousarray(data[:, i]) for i, n in enumerate(names)}
    missing = [c for c in required if c not in cols]
    if missing:
        raise ValueError(f"{p}: missing column(s) {', '.join(missing)} (has {', '.join(cols) or 'none'})")
    lengths = {k: len(v) for k, v in cols.items()}
    if len(set(lengths.values())) > 1:
        raise ValueError(f"{p}: columns have mismatched lengths {lengths}")
    for c in required:
        v = cols[c]
        if v.size == 0:
            raise ValueError(f"{p}: empty record (no rows)")
        bad = ~np.isfinite(v)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"{p}: {'NaN' if np.isnan(v[i]) else 'inf'} in column {c} at row {i}")
    return cols


def atomic_write(path: PathLike, write: Callable[[str], None]) -> None:
    """Call ``write(tmp)`` on a temporary file beside ``path``, then rename it over
    ``path``. On any error the temporary file is removed and ``path`` is untouched."""
    p = Path(path)
    d = p.parent if str(p.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=d)
    os.close(fd)
    try:
        write(tmp)
        # mkstemp creates 0600; give the file the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, p)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


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
