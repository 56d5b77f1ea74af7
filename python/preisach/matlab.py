"""MATLAB interop: dSPACE / MATLAB captures (``.mat``) as records (``preisach import-mat``),
and models as MAT files (``preisach export-mat``).

Two layouts are understood:

- **dSPACE ControlDesk / TRACE captures** saved to MAT: a top-level struct with ``X``
  (the time axis, ``X.Data``; ``X.Name`` if present) and ``Y`` (an array of structs,
  each with ``Name`` and ``Data``). Each ``Y(i)`` is a channel named ``Y(i).Name``; the
  time axis is a channel too (named ``X.Name``, or ``time``). The capture's own sample
  period, ``Capture.SamplingPeriod`` times ``Capture.Downsampling`` when the struct has
  them, sets the time step: ``X.Data`` is often stored in single precision, whose
  rounding would otherwise read as a rate such as 10001 Hz.
- **plain MATLAB files**: every top-level numeric vector is a channel named after the
  variable; a matrix contributes one channel per column, named ``M(:,1)``, ``M(:,2)``, ...
  (1-based, as MATLAB writes them).

Channels are picked by name or by the 0-based index that :func:`list_channels` (and
``preisach import-mat FILE --list``) prints. A name matches exactly, else by its
printable form, else by its last path components (dSPACE names are often paths such as
``Model Root/Plant/y``), each when that is unique. The printable form (what ``--list``
prints, :func:`printable`) shows a control character as ``?``: real captures carry one
where a character such as "å" was lost in an encoding. Matching folds case and accents
(``Pådrag`` matches ``padrag``) and lets such a ``?`` stand for any one character or
none (``Pdrag``, ``Pådrag`` and ``P?drag`` all match a channel stored as ``P\\x86drag``).

Reading needs SciPy (``pip install 'preisach[mat]'``), which reads MAT v4, v6 and v7.
MAT v7.3 files are HDF5 and are not read: save them in MATLAB with ``save(f, '-v7')``.

:func:`write_model_mat` goes the other way (``preisach export-mat``): a model as plain
MATLAB matrices.
"""
from __future__ import annotations

import re
import unicodedata
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Optional, Union

import numpy as np
from numpy.typing import NDArray

from preisach._matsize import MatSizeError, check_v5
from preisach.io import PathLike

__all__ = ["Channel", "list_channels", "printable", "read_mat", "sample_rate", "select", "write_model_mat"]

#: Most values one variable of a MAT file may declare (2^27 doubles: 1 GiB), arrays
#: nested in its structs and cell arrays included, checked from the file's headers before
#: any data is read (a compressed element is inflated chunk by chunk for that).
MAX_MAT_VALUES = 2**27

#: The one-line hint when SciPy is missing.
SCIPY_HINT = "MAT files need SciPy: pip install 'preisach[mat]'"


@dataclass(frozen=True)
class Channel:
    """One signal of a MAT file: ``index`` (0-based, what ``--list`` prints), ``name``
    (as stored), ``data`` (1-D float64), ``source`` (``"dspace-time"``, ``"dspace"`` or
    ``"variable"``) and, for a dSPACE time axis, the capture's own sample ``period`` in
    seconds (``None`` where the file does not say)."""

    index: int
    name: str
    data: NDArray[np.float64]
    source: str
    period: Optional[float] = None

    @property
    def label(self) -> str:
        """The name in printable form (see :func:`printable`)."""
        return printable(self.name)


def printable(name: str) -> str:
    """``name`` with every control, format or unassigned character shown as ``?`` (what
    ``--list`` prints; a terminal would otherwise swallow or act on it)."""
    return "".join("?" if unicodedata.category(c).startswith("C") else c for c in name).strip()


def _fold(name: str) -> str:
    """The form names are compared in: printable, accents dropped (NFKD), case-folded."""
    decomposed = unicodedata.normalize("NFKD", printable(name))
    return "".join(c for c in decomposed if not unicodedata.combining(c)).casefold().strip()


def _same(query: str, name: str) -> bool:
    """Folded names equal, where a ``?`` in ``name`` (a lost character) stands for any one
    character or none, and a ``?`` typed in ``query`` for any one character."""
    q, n = _fold(query), _fold(name)
    if q == n:
        return True
    lost = "".join(".?" if c == "?" else re.escape(c) for c in n)
    typed = "".join("." if c == "?" else re.escape(c) for c in q)
    return re.fullmatch(lost, q) is not None or re.fullmatch(typed, n) is not None


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
        _check_sizes(p, head)
        return dict(scipy.io.loadmat(str(p), squeeze_me=True, struct_as_record=False, chars_as_strings=True))
    except ValueError as exc:
        if str(exc).startswith(f"{p}: "):
            raise
        raise ValueError(f"{p}: not a readable MAT file (ValueError: {exc})") from None
    except NotImplementedError as exc:  # scipy's message for v7.3
        raise ValueError(f"{p}: {exc}; save it in MATLAB with '-v7'") from None
    except Exception as exc:  # scipy raises many kinds on corrupt files
        raise ValueError(f"{p}: not a readable MAT file ({type(exc).__name__}: {exc})") from None


def _check_sizes(p: Path, head: bytes) -> None:
    """Refuse a variable that declares more than :data:`MAX_MAT_VALUES` values, nested
    arrays and compressed elements included (MAT v5: :mod:`preisach._matsize`; MAT v4
    has top-level matrices only, whose dimensions ``whosmat`` reads)."""
    import scipy.io

    if head[126:128] in (b"IM", b"MI"):
        try:
            with open(p, "rb") as f:
                check_v5(f, p.stat().st_size, MAX_MAT_VALUES)
        except MatSizeError as exc:
            raise ValueError(f"{p}: variable {printable(exc.variable)}: {printable(exc.detail)}") from None
        return
    for name, shape, _ in scipy.io.whosmat(str(p)):
        n = int(np.prod([int(k) for k in shape], dtype=object))
        if n > MAX_MAT_VALUES:
            raise ValueError(f"{p}: variable {printable(name)} declares {'x'.join(map(str, shape))} = {n} values, "
                             f"above the limit of {MAX_MAT_VALUES} (1 GiB of doubles)")


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


_Found = tuple[str, NDArray[np.float64], str, Optional[float]]


def _dspace(var: str, s: Any) -> Optional[list[_Found]]:
    """Channels of a dSPACE capture struct, or None if ``s`` is not one."""
    if not (_is_struct(s) and "X" in s._fieldnames and "Y" in s._fieldnames):
        return None
    out: list[_Found] = []
    period = _capture_period(s)
    xs = np.atleast_1d(s.X) if isinstance(s.X, np.ndarray) else [s.X]
    for k, x in enumerate(xs):
        if _is_struct(x) and "Data" in x._fieldnames:
            v = _vector(x.Data)
            if v is not None and v.ndim == 1:
                name = _text(getattr(x, "Name", None)) or ("time" if k == 0 else f"time{k}")
                out.append((name, v, "dspace-time", period))
    ys = np.atleast_1d(s.Y) if isinstance(s.Y, np.ndarray) else [s.Y]
    for k, y in enumerate(ys):
        if not (_is_struct(y) and "Data" in y._fieldnames):
            continue
        v = _vector(y.Data)
        if v is None or v.ndim != 1:
            continue
        name = _text(getattr(y, "Name", None)) or f"{var}.Y({k + 1})"
        out.append((name, v, "dspace", None))
    return out


def _capture_period(s: Any) -> Optional[float]:
    """The capture's sample period in seconds, ``Capture.SamplingPeriod`` times
    ``Capture.Downsampling``, or None if the struct does not carry a usable one."""
    cap: Any = getattr(s, "Capture", None)
    if not _is_struct(cap) or "SamplingPeriod" not in cap._fieldnames:
        return None
    try:
        period = float(np.asarray(cap.SamplingPeriod, dtype=np.float64).ravel()[0])
        down = float(np.asarray(getattr(cap, "Downsampling", 1), dtype=np.float64).ravel()[0])
    except (TypeError, ValueError, IndexError):
        return None
    dt = period * (down if np.isfinite(down) and down >= 1 else 1.0)
    return dt if np.isfinite(dt) and dt > 0 else None


def list_channels(path: PathLike) -> list[Channel]:
    """Every signal in the MAT file at ``path`` as :class:`Channel` objects, in file
    order (dSPACE time first). Raises ``ValueError`` for unreadable files, v7.3 files
    and files without any numeric signal, or if SciPy is missing."""
    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such file")
    d = _loadmat(p)
    found: list[_Found] = []
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
            found.append((var, v, "variable", None))
        else:
            cols = v if v.shape[0] >= v.shape[1] else v.T  # signals along the long axis
            for j in range(cols.shape[1]):
                found.append((f"{var}(:,{j + 1})", np.ascontiguousarray(cols[:, j]), "variable", None))
    if not found:
        names = ", ".join(printable(k) for k in d if not k.startswith("__")) or "none"
        raise ValueError(f"{p}: no numeric signals found (variables: {names})")
    return [Channel(i, n, v, s, dt) for i, (n, v, s, dt) in enumerate(found)]


def _available(chs: list[Channel]) -> str:
    shown = ", ".join(f"{c.index}:{c.label}" for c in chs[:30])
    return shown + (f", ... ({len(chs)} channels)" if len(chs) > 30 else "")


def select(channels: list[Channel], key: Union[str, int], what: str = "channel") -> Channel:
    """The channel ``key`` names: an index (int, or a string of digits) or a name. A name
    matches exactly, else by its printable form (case and accents folded, a lost
    character as a wildcard; see the module doc), else by its last path components
    (``y_sensor`` or ``Plant/y_sensor`` for ``Model Root/Plant/y_sensor``). The
    ``ValueError`` for a missing or ambiguous channel names it and lists the available
    ones; ``what`` (e.g. ``"--u"``) says which option asked."""
    s = str(key).strip()
    if isinstance(key, (int, np.integer)) or s.lstrip("-").isdigit():
        i = int(s)
        if not 0 <= i < len(channels):
            raise ValueError(f"{what}: channel index {i} out of range 0..{len(channels) - 1} "
                             f"(available: {_available(channels)})")
        return channels[i]
    parts = _path(s)
    for match in (lambda c: c.name == s, lambda c: _same(s, c.name),
                  lambda c: _tail_matches(parts, _path(c.name))):
        hits = [c for c in channels if match(c)]
        if len(hits) == 1:
            return hits[0]
        if len(hits) > 1:
            listed = ", ".join(f"{c.index}:{c.label}" for c in hits)
            raise ValueError(f"{what}: channel name {printable(s)!r} is ambiguous ({listed}); pick one by index")
    raise ValueError(f"{what}: no channel named {printable(s)!r} (available: {_available(channels)})")


def _path(name: str) -> list[str]:
    """The components of a dSPACE path (``/``, ``\\`` or ``.`` separated, quotes dropped)."""
    for sep in ("\\", "."):
        name = name.replace(sep, "/")
    return [part.strip().strip('"') for part in name.strip().strip('"').split("/")]


def _tail_matches(query: list[str], name: list[str]) -> bool:
    """The query's path components match the last components of the name's path."""
    if len(query) > len(name):
        return False
    return all(_same(q, n) for q, n in zip(query, name[len(name) - len(query):]))


def sample_rate(t: NDArray[np.float64]) -> float:
    """The mean sample rate of a time axis in Hz: the whole span over the sample count,
    which rounding of single time stamps (single-precision captures) does not bias."""
    if t.size < 2 or not t[-1] > t[0]:
        raise ValueError("t: need at least 2 increasing time stamps for a sample rate")
    return float((t.size - 1) / (t[-1] - t[0]))


def read_mat(path: PathLike, u: Union[str, int], y: Optional[Union[str, int]] = None,
             t: Optional[Union[str, int]] = None, fs: Optional[float] = None) -> dict[str, NDArray[np.float64]]:
    """Read a record (``t``, ``u`` and optionally ``y``) from a MAT file.

    ``u``, ``y``, ``t`` pick channels by name or index (see :func:`select`); they must be
    different channels. Without ``t`` the dSPACE time axis is used if the file has one,
    else ``fs`` (Hz) builds ``t = arange(n) / fs``. A dSPACE time axis that carries the
    capture's sample period comes out on that exact grid (``t0 + k * period``) when its
    stored stamps agree with it to within half a period. Errors (``ValueError``) name
    the option and the channel: missing, the same channel twice, mismatched lengths,
    NaN/inf, a time axis that does not increase."""
    if fs is not None and t is not None:
        raise ValueError("give either --t or --fs, not both")
    if fs is not None and not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"--fs: must be a positive sample rate in Hz, got {fs}")
    chs = list_channels(path)
    picked = {"u": select(chs, u, "--u")}
    if y is not None:
        picked["y"] = select(chs, y, "--y")
    if t is not None:
        picked["t"] = select(chs, t, "--t")
    elif fs is None:
        times = [c for c in chs if c.source == "dspace-time"]
        if len(times) != 1:
            raise ValueError(f"{path}: no time axis found; pick one with --t NAME|INDEX or give --fs HZ "
                             f"(available: {_available(chs)})")
        picked["t"] = times[0]
    out = _checked(picked)
    n = out["u"].size
    if fs is not None:
        out["t"] = np.arange(n) / float(fs)
    elif picked["t"].period is not None:
        out["t"] = _on_grid(out["t"], picked["t"].period)
    if n < 2 or not np.all(np.diff(out["t"]) > 0):
        name = picked["t"].label if "t" in picked else ""
        raise ValueError(f"--t: the time axis {name!r} must increase strictly")
    return {k: out[k] for k in ("t", "u", "y") if k in out}


def _checked(picked: dict[str, Channel]) -> dict[str, NDArray[np.float64]]:
    """The picked channels' data, after checking they are distinct, equally long and
    finite (errors name the option and the channel)."""
    seen: dict[int, str] = {}
    for k, c in picked.items():
        if c.index in seen:
            raise ValueError(f"--{k}: channel {c.index} ({c.label!r}) is already --{seen[c.index]}; "
                             "pick a different channel")
        seen[c.index] = k
    n = picked["u"].data.size
    out: dict[str, NDArray[np.float64]] = {}
    for k, c in picked.items():
        if c.data.size != n:
            raise ValueError(f"--{k}: channel {c.label!r} has {c.data.size} samples but --u "
                             f"({picked['u'].label!r}) has {n}")
        bad = ~np.isfinite(c.data)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"--{k}: channel {c.label!r} has {'NaN' if np.isnan(c.data[i]) else 'inf'} at sample {i}")
        out[k] = np.array(c.data, dtype=np.float64)
    return out


def _on_grid(t: NDArray[np.float64], period: float) -> NDArray[np.float64]:
    """``t`` replaced by ``t[0] + k * period`` if every stamp lies within half a period
    of that grid (stamps rounded in single precision); else ``t`` as stored (a capture
    with gaps, or a period field that does not describe this axis)."""
    grid = t[0] + np.arange(t.size) * period
    return grid if np.all(np.abs(t - grid) < 0.5 * period) else t


def write_model_mat(path: PathLike, model: Any, chain: Optional[Mapping[str, Any]] = None) -> list[str]:
    """Write ``model`` (a :class:`~preisach.PreisachModel`) to a MAT file (v5, written
    atomically) for MATLAB, and return the names of the variables written.

    Variables: ``weights`` (n_h x n_h, β-cell rows, α-cell columns, zero below the
    diagonal), ``levels`` (1 x (n_h + 1)), ``offset``, ``u_range`` (1 x 2, ``[lo hi]``),
    ``n_h``, ``output`` (``'stepwise'`` or ``'interpolated'``) and ``format``
    (``'preisach-model'``). ``chain``: a chain's JSON-ready dict; its blocks (every entry
    but the hysteresis model, which the variables above already hold) are written as the
    struct ``chain``. ``docs/guide/matlab.md`` has a MATLAB loop that evaluates the
    model from these variables."""
    try:
        import scipy.io
    except ImportError:
        raise ValueError(SCIPY_HINT) from None
    from preisach.io import atomic_write

    w = np.triu(np.asarray(model.weights, dtype=np.float64))
    lo, hi = model.u_range
    out: dict[str, Any] = {
        "weights": w, "levels": np.asarray(model.levels, dtype=np.float64).reshape(1, -1),
        "offset": float(model.offset), "u_range": np.array([[lo, hi]]), "n_h": float(model.n_h),
        "output": str(model.output), "format": "preisach-model"}
    if chain is not None:
        out["chain"] = _to_mat(dict(chain))

    def _w(tmp: str) -> None:
        with open(tmp, "wb") as f:
            scipy.io.savemat(f, out, format="5", do_compression=True, oned_as="row")

    atomic_write(path, _w)
    return list(out)


def _to_mat(x: Any) -> Any:
    """JSON data as scipy.io.savemat writes it: objects as structs (field names made
    valid MATLAB identifiers), number lists as row vectors, other lists as cell arrays,
    null as []."""
    if isinstance(x, Mapping):
        return {_field(str(k)): _to_mat(v) for k, v in x.items()}
    if x is None:
        return np.zeros((0, 0))
    if isinstance(x, (list, tuple)):
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in x):
            return np.asarray(x, dtype=np.float64).reshape(1, -1)
        cell = np.empty((1, len(x)), dtype=object)
        for i, v in enumerate(x):
            cell[0, i] = _to_mat(v)
        return cell
    return x


def _field(name: str) -> str:
    s = re.sub(r"\W", "_", name, flags=re.ASCII)
    return s if s[:1].isalpha() else f"x{s}"
