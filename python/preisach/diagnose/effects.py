"""Fitting augmented chains: the Preisach masses and the parameters of added effects,
jointly (DESIGN.md: a baseline fitted to data with an unmodelled effect has absorbed
part of it, so adding the effect means refitting the masses with it).

Alternation: masses given the effects (exact corrections: a pure delay commutes with
the rate-independent operator, so the masses are refitted on the delayed input; for
linear blocks L behind the hysteresis, ``y_corr = y - (L[h] - h)``; drift is undone
first), then each effect's parameters given the masses (1-D golden searches, linear
least squares where the parameters enter linearly). The hysteresis inside an augmented
chain is the interpolated (continuous) model.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Callable, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.chain import ORDER, apply_effects, apply_linear, delay_signal, rate_term
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

    def decimated(self, stride: int) -> "Record":
        """Every ``stride``-th sample (point decimation: no filter, so no added delay)."""
        if stride <= 1:
            return self
        return Record(self.name, self.t[::stride], self.u[::stride], self.y[::stride], self.dt * stride)


@dataclass
class FitState:
    """A fitted chain: interpolated model plus effect parameters."""

    model: PreisachModel
    effects: dict[str, dict[str, Any]] = field(default_factory=dict)
    train_rmse: float = float("nan")

    def predict(self, rec: Record) -> NDArray[np.float64]:
        h = self.model.predict(rec.u)
        return apply_effects(self.effects, rec.t, rec.u, h, rec.dt)


def rmse(a: NDArray[np.float64]) -> float:
    """Root mean square."""
    return float(np.sqrt(np.mean(np.square(a))))


def _rows(u: NDArray[np.float64], cap: int) -> NDArray[np.intp]:
    """Sample indices for a mass fit: a stride plus every turning point of ``u`` (so the
    memory sees the true extrema), about ``cap`` rows. The exact fit merges nothing for
    the interpolated output, so its cost grows with the rows."""
    n = u.size
    stride = max(1, n // cap)
    idx = np.arange(0, n, stride)
    d = np.diff(u)
    nz = np.flatnonzero(d)
    if nz.size > 1:
        s = np.sign(d[nz])
        turn = nz[1:][s[1:] != s[:-1]]  # first sample after a sign change of the slope
        if turn.size < cap:
            idx = np.union1d(idx, turn)
    return idx


def fit_masses(u: NDArray[np.float64], y: NDArray[np.float64], n_h: int, u_range: tuple[float, float],
               cap: int = 12000) -> PreisachModel:
    """Interpolated model fitted on a subset of rows (see :func:`_rows`)."""
    idx = _rows(u, cap)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return PreisachModel.fit(u[idx], y[idx], n_h, u_range=u_range, output="interpolated", solver="structured")


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


def _nnls_small(A: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Least squares with x >= 0 for a handful of columns: drop the most negative
    coefficient and solve again (enough for <= 10 columns)."""
    active = list(range(A.shape[1]))
    x = np.zeros(A.shape[1])
    while active:
        sol, *_ = np.linalg.lstsq(A[:, active], b, rcond=None)
        if np.all(sol >= 0):
            x[:] = 0
            x[active] = sol
            return x
        del active[int(np.argmin(sol))]
    return x


def _mode_guess(r: NDArray[np.float64], dt: float) -> list[float]:
    """Frequencies of the three largest peaks of the residual spectrum above 300 Hz
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
    k = max(3, ok.sum() // 40)
    trend = np.convolve(logp, np.ones(k) / k, mode="same")
    ex = logp - trend
    out: list[float] = []
    df = f[1] - f[0]
    for i in np.argsort(ex)[::-1]:
        if len(out) >= 3:
            break
        if all(abs(f[ok][i] - q) > 5 * df for q in out):
            out.append(float(f[ok][i]))
    return out


class ChainFitter:
    """Fits chains on one (possibly decimated) training record."""

    def __init__(self, rec: Record, n_h: int, u_range: tuple[float, float], cap: int = 3500) -> None:
        self.rec = rec
        self.n_h = n_h
        self.u_range = u_range
        self.cap = cap

    # -- masses given effects ------------------------------------------------------
    def masses(self, effects: dict[str, dict[str, Any]], prev: Optional[PreisachModel], n_h: Optional[int] = None) -> PreisachModel:
        r = self.rec
        nh = n_h or self.n_h
        z = r.y
        if "drift" in effects:
            p = effects["drift"]
            z = (z - p["offset"] - p["offset_per_s"] * r.t) / (1 + p["gain_per_s"] * r.t)
        ud = delay_signal(r.u, effects["delay"]["delay_s"], r.dt) if "delay" in effects else r.u
        lin = {k: v for k, v in effects.items() if k in ("rate", "creep", "vibration", "lowpass")}
        if lin and prev is not None:
            h = prev.predict(ud)
            z = z - (apply_effects(lin, r.t, ud, h, r.dt) - h)
        elif "rate" in lin:
            z = z - rate_term(lin["rate"], ud, r.dt)
        return fit_masses(ud, z, nh, self.u_range, self.cap)

    # -- effect parameters given masses -------------------------------------------
    def params(self, name: str, effects: dict[str, dict[str, Any]], h: NDArray[np.float64]) -> dict[str, Any]:
        r = self.rec
        others = {k: v for k, v in effects.items() if k != name}

        def err(p: dict[str, Any]) -> float:
            e = dict(others)
            e[name] = p
            return float(np.mean((apply_effects(e, r.t, r.u, h, r.dt) - r.y) ** 2))

        cur = effects.get(name)
        if name == "delay":
            hi = 3e-3 if cur is None else max(3e-3, 3 * cur["delay_s"])
            grid = np.concatenate([[0.0], np.geomspace(max(r.dt / 4, 1e-6), hi, 14)])
            d, _ = _grid_then_golden(lambda d: err({"delay_s": d}), grid)
            return {"delay_s": float(d)}
        if name == "lowpass":
            best = None
            nyq = 0.5 / r.dt
            for order in (1, 2):
                grid = np.geomspace(30.0, 0.45 * nyq, 16)
                lf, fx = _grid_then_golden(lambda lf: err({"cutoff_hz": math.exp(lf), "order": order}), np.log(grid))
                if best is None or fx < best[1]:
                    best = ({"cutoff_hz": float(math.exp(lf)), "order": order}, fx)
            assert best is not None
            return best[0]
        if name == "vibration":
            if cur is None:
                base = apply_effects(others, r.t, r.u, h, r.dt)
                zeta = 0.02
                cands = _mode_guess(r.y - base, r.dt) or [1000.0]
                f0 = min(cands, key=lambda f: err({"frequency_hz": f, "damping": zeta}))
                span = 0.1
            else:
                f0, zeta, span = cur["frequency_hz"], cur["damping"], 0.03
            nyq = 0.5 / r.dt
            for _ in range(2):
                lf, _ = _golden(lambda lf: err({"frequency_hz": math.exp(lf), "damping": zeta}),
                                math.log(f0 * (1 - span)), math.log(min(f0 * (1 + span), 0.45 * nyq)), 14)
                f0 = math.exp(lf)
                lz, _ = _golden(lambda lz: err({"frequency_hz": f0, "damping": math.exp(lz)}),
                                math.log(1e-3), math.log(0.5), 14)
                zeta = math.exp(lz)
                span = 0.02
            return {"frequency_hz": float(f0), "damping": float(zeta)}
        if name == "creep":
            # Kelvin-Voigt elements on a fixed log grid of time constants; the gains
            # enter linearly (non-negative least squares).
            T = r.t[-1] - r.t[0]
            taus = [x for x in (0.003, 0.01, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0) if x <= max(0.01, 2 * T)]
            pre = {k: v for k, v in others.items() if k in ("rate",)}
            x = apply_effects(pre, r.t, r.u, h, r.dt)
            post = {k: v for k, v in others.items() if k in ("vibration", "lowpass", "delay")}

            def down(s: NDArray[np.float64]) -> NDArray[np.float64]:
                for k in ("vibration", "lowpass", "delay"):
                    if k in post:
                        s = apply_linear(k, post[k], s, r.dt)
                return s

            cols = [down(apply_linear("creep", {"taus_s": [tau], "amplitudes": [1.0], "_norm": True}, x, r.dt) - x)
                    for tau in taus]
            base = down(x)
            A = np.stack(cols, axis=1)
            target = r.y
            if "drift" in others:
                p = others["drift"]
                target = (r.y - p["offset"] - p["offset_per_s"] * r.t) / (1 + p["gain_per_s"] * r.t)
            b = target - base
            # Free offset column: the masses' offset is not refitted here.
            A1 = np.concatenate([A, np.ones((A.shape[0], 1))], axis=1)
            sol, *_ = np.linalg.lstsq(A1, b, rcond=None)
            amps = _nnls_small(A, b - sol[-1])
            keep = [i for i in range(len(taus)) if amps[i] > 1e-4]
            return {"taus_s": [float(taus[i]) for i in keep] or [taus[0]],
                    "amplitudes": [float(amps[i]) for i in keep] or [0.0], "_norm": True}
        if name == "drift":
            pre = apply_effects(others, r.t, r.u, h, r.dt)
            A = np.stack([r.t * pre, np.ones_like(pre), r.t], axis=1)
            sol, *_ = np.linalg.lstsq(A, r.y - pre, rcond=None)
            return {"gain_per_s": float(sol[0]), "offset": float(sol[1]), "offset_per_s": float(sol[2])}
        if name == "rate":
            best = None
            for tau in (1e-4, 3e-4, 1e-3, 3e-3, 1e-2):
                col = apply_effects(dict(others, rate={"gain_s": 1.0, "tau_s": tau}), r.t, r.u, h, r.dt) \
                    - apply_effects(others, r.t, r.u, h, r.dt)
                rr = r.y - apply_effects(others, r.t, r.u, h, r.dt)
                k = float(col @ rr / max(col @ col, 1e-300))
                e = err({"gain_s": k, "tau_s": tau})
                if best is None or e < best[1]:
                    best = ({"gain_s": k, "tau_s": tau}, e)
            assert best is not None
            return best[0]
        raise ValueError(f"unknown effect {name!r}")

    # -- profile search over one scalar, refitting the masses at each point ------------
    def profile(self, name: str, eff: dict[str, dict[str, Any]], model: PreisachModel,
                iters: int = 5) -> tuple[dict[str, dict[str, Any]], PreisachModel]:
        """Refine the effect's main scalar with the masses refitted at every trial value.
        Alternation alone converges slowly where the masses absorb the effect (a delay or
        a lag widens the loops; creep scales them), so it stops short of the truth."""
        r = self.rec
        p0 = dict(eff[name])
        if name == "delay":
            d = p0["delay_s"]
            lo, hi, setp = max(0.0, 0.5 * d), 2.0 * d + r.dt, lambda p, x: dict(p, delay_s=x)
        elif name == "lowpass":
            c = math.log(p0["cutoff_hz"])
            lo, hi, setp = c - math.log(3.0), c + math.log(1.5), lambda p, x: dict(p, cutoff_hz=math.exp(x))
        elif name == "creep":
            lo, hi = 0.7, 1.8
            setp = lambda p, x: dict(p, amplitudes=[a * x for a in p0["amplitudes"]])  # noqa: E731
        else:
            return eff, model
        cache: dict[float, tuple[float, PreisachModel]] = {}

        def f(x: float) -> float:
            e = dict(eff)
            e[name] = setp(p0, x)
            m = self.masses(e, model)
            err = float(np.mean((apply_effects(e, r.t, r.u, m.predict(r.u), r.dt) - r.y) ** 2))
            cache[x] = (err, m)
            return err

        x, _ = _golden(f, lo, hi, iters)
        e = dict(eff)
        e[name] = setp(p0, x)
        return e, cache[x][1]

    # -- the alternation -----------------------------------------------------------
    def fit(self, effects: dict[str, dict[str, Any]], new: Optional[str] = None, iters: int = 4,
            start: Optional[PreisachModel] = None, n_h: Optional[int] = None) -> FitState:
        """Fit masses and all effect parameters jointly. ``effects`` holds the current
        parameters; ``new`` names an effect to add (initialised from the data)."""
        r = self.rec
        eff = {k: dict(v) for k, v in effects.items()}
        model = start if start is not None else self.masses(eff, None, n_h)
        names = [k for k in ORDER if k in eff or k == new]
        e0 = None
        for it in range(iters):
            h = model.predict(r.u)
            if e0 is None:
                e0 = float(np.mean((apply_effects(eff, r.t, r.u, h, r.dt) - r.y) ** 2))
            for name in names:
                eff[name] = self.params(name, eff, h)
            if it == 0 and new is not None and new not in ("drift", "creep"):
                # Gate: an effect that does not lower the training error at fixed masses by
                # 2 % will not shrink the holdout error by 10 % either; skip the costly part.
                # (Not for drift and creep: the masses absorb those at first.)
                e1 = float(np.mean((apply_effects(eff, r.t, r.u, h, r.dt) - r.y) ** 2))
                if e1 > 0.98 * e0:
                    break
            model = self.masses(eff, model, n_h)
            if new is not None and it == 0 and new in eff:
                eff, model = self.profile(new, eff, model)
        pred = apply_effects(eff, r.t, r.u, model.predict(r.u), r.dt)
        return FitState(model, eff, rmse(pred - r.y))


def export_state(st: FitState) -> FitState:
    """Convert internal parametrizations to the pinned JSON ones (creep: DC-normalized
    gains c -> Kelvin-Voigt gains c / (1 - S), masses and offset scaled by 1 - S)."""
    eff = {k: dict(v) for k, v in st.effects.items()}
    model = st.model
    cr = eff.get("creep")
    if cr is not None and cr.pop("_norm", False):
        S = float(sum(cr["amplitudes"]))
        if S < 0.95:
            cr["amplitudes"] = [c / (1 - S) for c in cr["amplitudes"]]
            model = PreisachModel(model.weights * (1 - S), model.u_range, model.offset * (1 - S), model.output)
    return FitState(model, eff, st.train_rmse)
