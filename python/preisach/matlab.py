"""Import dSPACE / MATLAB captures (``.mat``) as records (``preisach import-mat``).

Two layouts are understood:

- **dSPACE ControlDesk / TRACE captures** saved to MAT: a top-level struct with ``X``
  (the time axis, ``X.Data``; ``X.Name`` if present) and ``Y`` (an array of structs,
  each with ``Name`` and ``Data``). Each ``Y(i)`` is a channel named ``Y(i).Name``; the
  time axis is a channel too (named ``X.Name``, or ``time``).
- **plain MATLAB files**: every top-level numeric vector is a channel named after the
  variable; a matrix contributes one channel per column, named ``M(:,1)``, ``M(:,2)``, ...
  (1-based, as MATLAB writes them).

Channels are picked by name or by the 0-based index that :func:`list_channels` (and
``preisach import-mat FILE --list``) prints. A name matches exactly, else
case-insensitively, else by its last path component (dSPACE names are often paths
such as ``Model Root/Plant/y``) when that is unique.

Reading needs SciPy (``pip install 'preisach[mat]'``), which reads MAT v4, v6 and v7.
MAT v7.3 files are HDF5 and are not read: save them in MATLAB with ``save(f, '-v7')``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional, Union

import numpy as np
from numpy.typing import NDArray

from preisach.io import PathLike

__all__ = ["Channel", "list_channels", "read_mat", "select"]

#: The one-line hint when SciPy is missing.
SCIPY_HINT = "reading .mat files needs SciPy: pip install 'preisach[mat]'"


@dataclass(frozen=True)
class Channel:
    """One signal of a MAT file: ``index`` (0-based, what ``--list`` prints), ``name``,
    ``data`` (1-D float64) and ``source`` (``"dspace-time"``, ``"dspace"`` or
    ``"variable"``)."""

    index: int
    name: str
    data: NDArray[np.float64]
    source: str


def _loadmat(p: Path) -> dict[str, Any]:
    try:
        import scipy.io  # type: ignore[import-untyped]
    except ImportError:
        raise ValueError(SCIPY_HINT) from None
    try:
        with open(p, "rb") as f:
            head = f.read(128)
    except OSError as exc:
        raise ValueError(f"{p}: cannot read ({exc})") from None
    if b"MATLAB 7.3" in head or head[:8] == b"\x89HDF\r\n\x1a\n":
        raise ValueError(f"{p}: MAT v7.3 (HDF5) files are not supported; save it in MATLAB with "
                         f"save('{p.name}', ..., '-v7') and import that")
    try:
        return dict(scipy.io.loadmat(str(p), squeeze_me=True, struct_as_record=False, chars_as_strings=True))
    except NotImplementedError as exc:  # scipy's message for v7.3
        raise ValueError(f"{p}: {exc}; save it in MATLAB with '-v7'") from None
    except Exception as exc:  # scipy raises many kinds on corrupt files
        raise ValueError(f"{p}: not a readable MAT file ({type(exc).__name__}: {exc})") from None


def _is_struct(x: Any) -> bool:
    return hasattr(x, "_fieldnames")


def _text(x: Any) -> Optional[str]:
    if isinstance(x, str):
        return x
    if isinstance(x, np.ndarray) and x.dtype.kind == "U":
        return "".join(str(s) for s in x.ravel())
    return None


def _vector(x: Any) -> Optional[NDArray[np.float64]]:
    """A real numeric 1-D array, or None."""
    if isinstance(x, (int, float, np.number)) and not isinstance(x, (bool, complex, np.complexfloating)):
        return None  # scalars are parameters, not signals
    if not isinstance(x, np.ndarray) or x.dtype.kind not in "biuf":
        return None
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 2 and 1 in a.shape:
        a = a.ravel()
    return a if a.ndim in (1, 2) and a.size > 1 else None


def _dspace(var: str, s: Any) -> Optional[list[tuple[str, NDArray[np.float64], str]]]:
    """Channels of a dSPACE capture struct, or None if ``s`` is not one."""
    if not (_is_struct(s) and "X" in s._fieldnames and "Y" in s._fieldnames):
        return None
    out: list[tuple[str, NDArray[np.float64], str]] = []
    xs = np.atleast_1d(s.X) if isinstance(s.X, np.ndarray) else [s.X]
    for k, x in enumerate(xs):
        if _is_struct(x) and "Data" in x._fieldnames:
            v = _vector(x.Data)
            if v is not None and v.ndim == 1:
                name = _text(getattr(x, "Name", None)) or ("time" if k == 0 else f"time{k}")
                out.append((name, v, "dspace-time"))
    ys = np.atleast_1d(s.Y) if isinstance(s.Y, np.ndarray) else [s.Y]
    for k, y in enumerate(ys):
        if not (_is_struct(y) and "Data" in y._fieldnames):
            continue
        v = _vector(y.Data)
        if v is None or v.ndim != 1:
            continue
        name = _text(getattr(y, "Name", None)) or f"{var}.Y({k + 1})"
        out.append((name, v, "dspace"))
    return out


def list_channels(path: PathLike) -> list[Channel]:
    """Every signal in the MAT file at ``path`` as :class:`Channel` objects, in file
    order (dSPACE time first). Raises ``ValueError`` for unreadable files, v7.3 files
    and files without any numeric signal, or if SciPy is missing."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such file")
    d = _loadmat(p)
    found: list[tuple[str, NDArray[np.float64], str]] = []
    for var, val in d.items():
        if var.startswith("__"):
            continue
        ds = _dspace(var, val)
        if ds is not None:
            found.extend(ds)
            continue
        v = _vector(val)
        if v is None:
            continue
        if v.ndim == 1:
            found.append((var, v, "variable"))
        else:
            cols = v if v.shape[0] >= v.shape[1] else v.T  # signals along the long axis
            for j in range(cols.shape[1]):
                found.append((f"{var}(:,{j + 1})", np.ascontiguousarray(cols[:, j]), "variable"))
    if not found:
        raise ValueError(f"{p}: no numeric signals found (variables: {', '.join(k for k in d if not k.startswith('__')) or 'none'})")
    return [Channel(i, n, v, s) for i, (n, v, s) in enumerate(found)]


def _available(chs: list[Channel]) -> str:
    shown = ", ".join(f"{c.index}:{c.name}" for c in chs[:30])
    return shown + (f", ... ({len(chs)} channels)" if len(chs) > 30 else "")


def select(channels: list[Channel], key: Union[str, int], what: str = "channel") -> Channel:
    """The channel ``key`` names: an index (int, or a string of digits) or a name
    (exact, case-insensitive, or unique last path component). The ``ValueError`` for a
    missing or ambiguous channel names it and lists the available ones; ``what`` (e.g.
    ``"--u"``) says which option asked."""
    s = str(key).strip()
    if isinstance(key, (int, np.integer)) or s.lstrip("-").isdigit():
        i = int(s)
        if not 0 <= i < len(channels):
            raise ValueError(f"{what}: channel index {i} out of range 0..{len(channels) - 1} "
                             f"(available: {_available(channels)})")
        return channels[i]
    for match in (lambda c: c.name == s, lambda c: c.name.lower() == s.lower(),
                  lambda c: _leaf(c.name).lower() == _leaf(s).lower()):
        hits = [c for c in channels if match(c)]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            raise ValueError(f"{what}: channel name {s!r} is ambiguous ({', '.join(f'{c.index}:{c.name}' for c in hits)}); "
                             "pick one by index")
    raise ValueError(f"{what}: no channel named {s!r} (available: {_available(channels)})")


def _leaf(name: str) -> str:
    for sep in ("/", "\\", "."):
        name = name.replace(sep, "/")
    return name.strip().strip('"').split("/")[-1].strip('"')


def read_mat(path: PathLike, u: Union[str, int], y: Optional[Union[str, int]] = None,
             t: Optional[Union[str, int]] = None, fs: Optional[float] = None) -> dict[str, NDArray[np.float64]]:
    """Read a record (``t``, ``u`` and optionally ``y``) from a MAT file.

    ``u``, ``y``, ``t`` pick channels by name or index (see :func:`select`). Without
    ``t`` the dSPACE time axis is used if the file has one, else ``fs`` (Hz) builds
    ``t = arange(n) / fs``. Errors (``ValueError``) name the channel: missing,
    mismatched lengths, NaN/inf, a time axis that does not increase."""
    chs = list_channels(path)
    out: dict[str, NDArray[np.float64]] = {}
    picked = {"u": select(chs, u, "--u")}
    if y is not None:
        picked["y"] = select(chs, y, "--y")
    n = picked["u"].data.size
    if t is not None:
        if fs is not None:
            raise ValueError("give either --t or --fs, not both")
        picked["t"] = select(chs, t, "--t")
    elif fs is None:
        times = [c for c in chs if c.source == "dspace-time"]
        if len(times) != 1:
            raise ValueError(f"{path}: no time axis found; pick one with --t NAME|INDEX or give --fs HZ "
                             f"(available: {_available(chs)})")
        picked["t"] = times[0]
    for k, c in picked.items():
        if c.data.size != n:
            raise ValueError(f"--{k}: channel {c.name!r} has {c.data.size} samples but --u "
                             f"({picked['u'].name!r}) has {n}")
        bad = ~np.isfinite(c.data)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"--{k}: channel {c.name!r} has {'NaN' if np.isnan(c.data[i]) else 'inf'} at sample {i}")
        out[k] = np.array(c.data, dtype=np.float64)
    if fs is not None:
        if not np.isfinite(fs) or fs <= 0:
            raise ValueError(f"--fs: must be a positive sample rate in Hz, got {fs}")
        out["t"] = np.arange(n) / float(fs)
    if n < 2 or not np.all(np.diff(out["t"]) > 0):
        raise ValueError(f"--t: the time axis {picked['t'].name if 't' in picked else ''!r} must increase strictly")
    return {k: out[k] for k in ("t", "u", "y") if k in out}
