"""Input validation at the Python boundary: any array-like in, contiguous float64 out,
with errors that name the argument and the problem."""
from __future__ import annotations

import functools
from typing import Any, Callable, TypeVar, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

_F = TypeVar("_F", bound=Callable[..., Any])

#: Largest n_h of a model (the core's limit: the Everett table of (n_h + 1)^2 doubles).
MAX_N_H = 16_000


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


def as_number(name: str, x: object) -> float:
    """A real number (Python or NumPy; not a bool, a string or an array) as a float."""
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}: expected a number, got {x!r}")
    try:
        return float(x)
    except OverflowError:
        raise ValueError(f"{name}: {x} is too large for a float64") from None


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


def upper_triangular(name: str, w: NDArray[np.float64]) -> None:
    """Reject a square matrix with a non-zero entry below the diagonal, naming the first
    one (row-major order): the Preisach plane has no cell with β above α."""
    below = np.tril(w, -1) != 0
    if below.any():
        i, j = (int(k) for k in np.argwhere(below)[0])
        raise ValueError(f"{name}: entry [{i}, {j}] = {float(w[i, j]):g} lies below the diagonal; only the upper "
                         f"triangle (β-cell row <= α-cell column) holds masses, the rest must be 0")


def check_range_reached(name: str, u: NDArray[np.float64], u_range: tuple[float, float], n_h: int) -> None:
    """Reject a model range in which the input ``u`` switches no relay after its first
    sample: relays switch at the cell centres ``lo + (k + 1/2) Δ``, so an input that
    never crosses one (it stays outside the range, or inside one cell) leaves every mass
    unidentifiable."""
    lo, hi = u_range
    if n_h > MAX_N_H:
        return  # refused by the core, naming n_h, before anything is allocated
    centres = lo + (np.arange(n_h) + 0.5) * (hi - lo) / n_h
    side = np.searchsorted(centres, u, side="right")
    if np.all(side == side[0]):
        where = "outside the range" if side[0] in (0, n_h) else f"inside one of its n_h = {n_h} cells"
        raise ValueError(f"{name}: no relay of the model range ({lo:.6g}, {hi:.6g}) would switch: the input "
                         f"({float(u.min()):.6g} .. {float(u.max()):.6g}) lies {where}; give a range the input "
                         "sweeps (the default fits the input)")


def one_thread(method: _F) -> _F:
    """Method decorator for objects with state (streams, inverters, stages): a call made
    while another thread is inside the same object raises a clear ``RuntimeError``
    naming the class, instead of the compiled module's bare "Already borrowed". The
    object is unchanged by the refused call."""

    @functools.wraps(method)
    def wrapper(self: Any, *args: Any, **kwargs: Any) -> Any:
        try:
            return method(self, *args, **kwargs)
        except RuntimeError as exc:
            if "borrowed" not in str(exc):
                raise
            raise RuntimeError(f"{type(self).__name__}: in use by another thread; give each thread its own "
                               "(or guard it with a lock)") from None

    return cast(_F, wrapper)
