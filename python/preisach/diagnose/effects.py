"""The pieces the diagnoser's search is made of: records, fitted chains (an interpolated
Preisach model plus effect parameters), the one-dimensional searches, the residual's
spectral peaks, and the conversion of internal parametrizations to the pinned JSON ones.
The search itself is :mod:`preisach.diagnose.search`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.chain import Chain
from preisach.model import PreisachModel

#: Candidate effects the diagnoser tries (``discretization`` is handled separately).
CANDIDATES = ("delay", "lowpass", "vibration", "creep", "drift", "rate")


@dataclass
class Record:
    """One record: name, absolute time ``t`` (s), input ``u``, output ``y``, period ``dt``."""

    name: str
    t: NDArray[np.float64]
    u: NDArray[np.float64]
    y: NDArray[np.float64]
    dt: float


@dataclass
class FitState:
    """A fitted chain: interpolated model plus effect parameters."""

    model: PreisachModel
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)
    train_rmse: float = float("nan")

    def predict(self, rec: Record) -> NDArray[np.float64]:
        return Chain(self.model, self.effects).predict(rec.t, rec.u)


def rate_branch(p: dict[str, Any], t: NDArray[np.float64], u: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rate branch ``gain_s s / (1 + s tau_s)`` of input ``u`` alone (behind a
    hysteresis block without mass)."""
    lo, hi = float(np.min(u)), float(np.max(u))
    zero = PreisachModel(np.zeros((1, 1)), (lo - 1.0, hi + 1.0))
    return Chain(zero, {"rate": p}).predict(t, u)


def rmse(a: NDArray[np.float64]) -> float:
    """Root mean square."""
    return float(np.sqrt(np.mean(np.square(a))))


def _golden(f: Callable[[float], float], lo: float, hi: float, iters: int = 18) -> tuple[float, float]:
    """Minimize a unimodal function on [lo, hi]; returns (x, f(x))."""
    g = (math.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(iters):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(d)
    return (c, fc) if fc < fd else (d, fd)


def _grid_then_golden(f: Callable[[float], float], grid: NDArray[np.float64], iters: int = 12) -> tuple[float, float]:
    """Coarse grid (robust to several minima), then golden search between the
    neighbours of the best grid point."""
    vals = np.array([f(float(x)) for x in grid])
    k = int(np.argmin(vals))
    lo = grid[max(0, k - 1)]
    hi = grid[min(grid.size - 1, k + 1)]
    x, fx = _golden(f, float(lo), float(hi), iters)
    return (x, fx) if fx < vals[k] else (float(grid[k]), float(vals[k]))


def _parabolic_search(f: Callable[[float], float], x0: list[float], lo: float, hi: float,
                      refine: int = 3, expand: int = 4,
                      known: Optional[dict[float, float]] = None,
                      fmany: Optional[Callable[[list[float]], list[float]]] = None) -> tuple[float, float]:
    """Minimize a smooth function from three starting points: extend the bracket
    (by the starting spacing, within [lo, hi]) until the best point has a higher value
    on either side, then successive parabolic steps through the best point and its
    neighbours. ``known``: values already computed; ``fmany``: ``f`` on a list of points
    at once (the starting points are independent: evaluated together, in parallel).
    Returns (x, f(x)); few evaluations when f is close to a parabola."""
    pts = dict(known or {})
    new = [float(x) for x in sorted(x0) if float(x) not in pts]
    for x, v in zip(new, fmany(new) if fmany is not None and len(new) > 1 else [f(x) for x in new]):
        pts[x] = v
    step = ((max(x0) - min(x0)) / 2 if x0 else 0.0) or 1e-12
    for _ in range(expand):
        xs = sorted(pts)
        b = min(pts, key=pts.__getitem__)
        if b == xs[0] and b > lo:
            x = max(lo, b - step)
        elif b == xs[-1] and b < hi:
            x = min(hi, b + step)
        else:
            break
        step *= 1.6
        pts[x] = f(x)
    for _ in range(refine):
        xs = sorted(pts)
        b = min(pts, key=pts.__getitem__)
        i = xs.index(b)
        if i == 0 or i == len(xs) - 1:
            break
        a, c = xs[i - 1], xs[i + 1]
        fa, fb, fc = pts[a], pts[b], pts[c]
        num = (b - a) ** 2 * (fb - fc) - (b - c) ** 2 * (fb - fa)
        den = (b - a) * (fb - fc) - (b - c) * (fb - fa)
        if den == 0:
            break
        x = b - 0.5 * num / den
        # Keep the new point strictly inside the bracket and away from known points.
        x = min(max(x, a + 0.05 * (c - a)), c - 0.05 * (c - a))
        if min(abs(x - q) for q in xs) < 1e-3 * (c - a):
            break
        pts[x] = f(x)
    b = min(pts, key=pts.__getitem__)
    return b, pts[b]


def _grid_then_parabola(f: Callable[[float], float], grid: NDArray[np.float64], refine: int = 3,
                        fmany: Optional[Callable[[list[float]], list[float]]] = None,
                        coarse_first: bool = False) -> tuple[float, float]:
    """Coarse grid (robust to several minima), then successive parabolic steps around the
    best grid point (for smooth objectives: 2-3 evaluations instead of a golden search's 8).
    ``coarse_first``, for an error that varies slowly over two grid steps: every other
    grid point first (both ends included), then the two beside the best of them; the same
    choice as the whole grid unless a minimum is narrower than two grid steps, about a
    third fewer evaluations. ``fmany``: ``f`` on several points at once (in parallel)."""
    xs = [float(x) for x in grid]
    known: dict[float, float] = {}

    def evaluate(pts: list[float]) -> None:
        known.update(zip(pts, fmany(pts) if fmany is not None and len(pts) > 1 else [f(x) for x in pts]))

    evaluate([xs[i] for i in sorted(set(range(0, len(xs), 2)) | {len(xs) - 1})] if coarse_first else xs)
    if coarse_first:
        b = xs.index(min(known, key=known.__getitem__))
        evaluate([xs[i] for i in (b - 1, b + 1) if 0 <= i < len(xs) and xs[i] not in known])
    return _parabolic_search(f, [], xs[0], xs[-1], refine=refine, expand=0, known=known)


def _mode_guess(r: NDArray[np.float64], dt: float, k: int = 3) -> list[float]:
    """Frequencies of the ``k`` largest peaks of the residual spectrum above 300 Hz
    (below that, harmonics of the drive signal dominate the residual)."""
    n = r.size
    nseg = 1 << int(min(16, max(8, math.floor(math.log2(max(n // 8, 256))))))
    nseg = min(nseg, n)
    win = np.hanning(nseg)
    psd = np.zeros(nseg // 2 + 1)
    for s in range(0, n - nseg + 1, nseg // 2):
        seg = r[s:s + nseg]
        psd += np.abs(np.fft.rfft((seg - seg.mean()) * win)) ** 2
    f = np.fft.rfftfreq(nseg, dt)
    ok = (f > 300) & (f < 0.4 / dt)
    # Whiten by a smooth trend so a broadband low-frequency residual does not win.
    logp = np.log(psd[ok] + 1e-300)
    kw = min(max(3, ok.sum() // 40), max(1, logp.size))  # a short record has few bins
    trend = np.convolve(logp, np.ones(kw) / kw, mode="same")
    ex = logp - trend
    out: list[float] = []
    df = f[1] - f[0]
    for i in np.argsort(ex)[::-1]:
        if len(out) >= k:
            break
        if all(abs(f[ok][i] - q) > 5 * df for q in out):
            out.append(float(f[ok][i]))
    return out


def export_state(st: FitState) -> FitState:
    """Convert internal parametrizations to the pinned JSON ones (creep: DC-normalized
    gains c -> Kelvin-Voigt gains c / (1 - S), masses and offset scaled by 1 - S)."""
    eff = {k: dict(v) for k, v in st.effects.items()}
    model = st.model
    cr = eff.get("creep")
    if cr is not None and cr.pop("normalized", False):
        S = float(sum(cr["amplitudes"]))
        if S < 0.95:
            cr["amplitudes"] = [c / (1 - S) for c in cr["amplitudes"]]
            model = PreisachModel(model.weights * (1 - S), model.u_range, model.offset * (1 - S), model.output)
    return FitState(model, eff, st.train_rmse)
