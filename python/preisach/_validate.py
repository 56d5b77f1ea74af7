"""Input validation at the Python boundary: any array-like in, contiguous float64 out,
with errors that name the argument and the problem."""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray


def as_signal(name: str, x: ArrayLike, *, allow_empty: bool = False) -> NDArray[np.float64]:
    """Convert ``x`` to a 1-D C-contiguous float64 array, rejecting NaN/inf (naming the
    first bad index), wrong dimensions and, unless ``allow_empty``, empty input."""
    try:
        a = np.ascontiguousarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to a float64 array ({exc})") from None
    if a.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array, got shape {a.shape}")
    if a.size == 0 and not allow_empty:
        raise ValueError(f"{name}: empty array")
    bad = ~np.isfinite(a)
    if bad.any():
        i = int(np.argmax(bad))
        what = "NaN" if np.isnan(a[i]) else "inf"
        raise ValueError(f"{name}: {what} at index {i}")
    return a


def as_range(name: str, r: object) -> tuple[float, float]:
    """Validate a ``(lo, hi)`` pair: two finite numbers with lo < hi."""
    try:
        lo, hi = (float(v) for v in r)  # type: ignore[attr-defined]
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a pair (lo, hi), got {r!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi)):
        raise ValueError(f"{name}: must be finite, got ({lo}, {hi})")
    if lo >= hi:
        raise ValueError(f"{name}: lo must be below hi, got ({lo}, {hi})")
    return lo, hi


def as_n_h(n_h: object) -> int:
    """Validate the discretization level."""
    if isinstance(n_h, bool) or not isinstance(n_h, (int, np.integer)):
        raise ValueError(f"n_h: expected an integer, got {n_h!r}")
    if n_h < 1:
        raise ValueError(f"n_h: must be >= 1, got {n_h}")
    return int(n_h)
