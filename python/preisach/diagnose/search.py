"""The search over augmented chains, on the profiled training error.

For a chain (effects with parameters), the masses that fit the training record best are a
linear least-squares problem, solved exactly behind the chain's linear blocks by the core
(``_preisach.Behind``: rows built once per delayed input, conjugate gradients
preconditioned by the unfiltered Gram matrix, warm-started). So every effect parameter is
searched on the *profiled* error ``J(θ) = min over masses of the training MSE``: the
masses absorb part of any unmodelled effect (a delay widens the loops, creep scales them),
and only with the masses refitted at every trial value does the search land on the truth.
The coefficients that enter linearly are solved with the masses (drift offset slope, rate
gain). The masses >= 0 (the exact NNLS fit) are computed only for chains that are scored.

Effects that trade off against each other (a delay and a low-pass share the low-frequency
lag; creep and drift both make slow trends; a mode's ringing phase needs the timing) are
polished jointly: after a candidate's own search, coordinate steps on every scalar of the
chain. A chain with a mode or a low-pass always carries a delay as the sub-sample timing
of the record (a DAC's zero-order hold delays the dynamics by half a sample); it is
reported as a detected delay only when it is longer than the sampling can explain.
"""
from __future__ import annotations

import math
import threading
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.chain import apply_effects, delay_signal, partial_fractions, rate_term
from preisach.diagnose.effects import FitState, Record, _grid_then_parabola, _mode_guess, _parabolic_search, rmse
from preisach.model import PreisachModel

Effects = dict[str, dict[str, Any]]

#: Shortest creep time constant searched: faster "creep" is a low-pass's business.
CREEP_TAU_MIN = 5e-3

#: Scalars polished per effect: (parameter, log scale?, lower bound, upper bound, first
#: step: relative, or in log units). A mode's frequency needs small steps: a long
#: ringing turns its phase quickly with the frequency, so the error is smooth only
#: within a fraction of a percent.
SCALARS: dict[str, list[tuple[str, bool, float, float, float]]] = {
    "delay": [("delay_s", False, 0.0, 5e-3, 0.1)],
    "lowpass": [("cutoff_hz", True, 10.0, 1e6, 0.1)],
    "vibration": [("frequency_hz", True, 50.0, 1e6, 0.002), ("damping", True, 1e-3, 0.5, 0.15)],
    "creep": [("tau", True, CREEP_TAU_MIN, 100.0, 0.2), ("amp", False, 0.0, 0.5, 0.2)],
    "drift": [("gain_per_s", False, -0.5, 0.5, 0.1)],
    "rate": [("tau_s", True, 1e-3, 3e-2, 0.2)],
}
DYNAMIC = ("vibration", "lowpass")
#: Effects whose parameters trade off against each other's (polished together): a delay
#: and the dynamics share the lag; creep, drift and a low-pass all shape slow trends.
COUPLED: dict[str, tuple[str, ...]] = {
    "delay": ("lowpass", "vibration"),
    "lowpass": ("delay", "vibration", "creep"),
    "vibration": ("delay", "lowpass"),
    "creep": ("drift", "lowpass"),
    "drift": ("creep",),
    "rate": (),
}


def _get(eff: Effects, name: str, key: str) -> float:
    p = eff[name]
    if name == "creep":
        return float(p["taus_s"][0] if key == "tau" else p["amplitudes"][0])
    return float(p[key])


def _set(eff: Effects, name: str, key: str, v: float) -> Effects:
    e = {k: dict(p) for k, p in eff.items()}
    if name == "creep":
        if key == "tau":
            e[name]["taus_s"] = [float(v)]
        else:
            e[name]["amplitudes"] = [float(v)]
    else:
        e[name][key] = float(v)
    return e


def group_delay(p: dict[str, Any]) -> float:
    """Low-frequency group delay of a Butterworth low-pass (order 1: 1/wc; 2: sqrt(2)/wc)."""
    wc = 2 * math.pi * p["cutoff_hz"]
    return (1.0 if int(p["order"]) == 1 else math.sqrt(2.0)) / wc


def _key(eff: Effects) -> tuple[Any, ...]:
    out = []
    for k in sorted(eff):
        p = eff[k]
        out.append((k, tuple((kk, tuple(v) if isinstance(v, list) else v) for kk, v in sorted(p.items())
                             if kk not in ("offset_per_s", "gain_s", "offset"))))
    return tuple(out)


def window_mean(x: NDArray[np.float64], stride: int) -> NDArray[np.float64]:
    """Means of consecutive windows of ``stride`` samples (the last partial one dropped)."""
    n = x.size // stride
    return np.ascontiguousarray(x[:n * stride].reshape(n, stride).mean(axis=1))


class Fitter:
    """Profiled-error fits of chains on one training record, on windows of ``stride``
    samples averaged (the record's rate divided by ``stride``; see the core's
    ``Behind``: averaging commutes with the dynamics and keeps the timing of steps)."""

    def __init__(self, rec: Record, n_h: int, u_range: tuple[float, float], stride: int = 1,
                 tol: float = 1e-5) -> None:
        from preisach import _preisach

        self._behind = _preisach.Behind
        self.rec = rec
        self.stride = max(1, int(stride))
        self.n_h = n_h
        self.u_range = (float(u_range[0]), float(u_range[1]))
        self.tol = tol
        self._local = threading.local()
        self._lock = threading.Lock()
        self._memo: dict[tuple[Any, ...], tuple[float, list[float]]] = {}
        self.evaluations = 0
        self._u = np.ascontiguousarray(rec.u, dtype=np.float64)
        # The averaged record the chains are fitted to.
        self.t = window_mean(rec.t, self.stride)
        self.y = window_mean(rec.y, self.stride)
        self.dt = rec.dt * self.stride

    def coarse(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """A full-rate signal of the training record, averaged like the fit's target."""
        return window_mean(x, self.stride)

    def _delayed(self, x: NDArray[np.float64], eff: Effects) -> NDArray[np.float64]:
        """A full-rate signal delayed like the chain delays its output, then averaged."""
        d = eff.get("delay", {}).get("delay_s", 0.0)
        return self.coarse(delay_signal(x, d, self.rec.dt) if d > 0 else x)

    def hysteresis(self, model: PreisachModel, eff: Effects) -> NDArray[np.float64]:
        """The model's output on the training input, delayed like the chain, averaged."""
        return self._delayed(model.predict(self._u), eff)

    def predict(self, st: FitState) -> NDArray[np.float64]:
        """The chain's output on the averaged training record (a delay commutes with the
        linear blocks, and the average with all of them)."""
        eff = st.effects
        x = st.model.predict(self._u)
        if "rate" in eff:
            x = x + rate_term(eff["rate"], self._u, self.rec.dt)
        rest = {k: v for k, v in eff.items() if k not in ("rate", "delay")}
        return apply_effects(rest, self.t, self.t, self._delayed(x, eff), self.dt)

    # -- the profiled objective -----------------------------------------------------
    def _solve(self, pb: dict[str, Any], nnls: bool = False) -> dict[str, Any]:
        """One solve on this thread's session (a session serves one thread at a time, and
        warm-starts from its previous solve: the neighbouring trial of the same search)."""
        sess = getattr(self._local, "session", None)
        if sess is None:
            sess = self._local.session = self._behind(self._u, self.n_h, self.u_range, self.stride)
        return sess.solve(pb["z"], self.dt, pb["blocks"], pb["w"], pb["pre"], pb["post"], self.tol,
                          nnls=nnls, delay=pb["delay"])

    def _problem(self, eff: Effects) -> dict[str, Any]:
        t, y = self.t, self.y
        blocks = []
        for k in ("creep", "vibration", "lowpass"):
            if k in eff:
                poles, res, direct = partial_fractions(k, eff[k])
                blocks.append(([(p.real, p.imag) for p in poles], [(q.real, q.imag) for q in res], float(direct)))
        z, w, post, pre, q = y, None, None, None, None
        if "drift" in eff:
            q = 1 + eff["drift"]["gain_per_s"] * t
            z = y / q
            w = q * q
            # y = (1 + g t)(chain + c) + o'' t: the constant stays in the model's offset.
            post = np.ascontiguousarray((t / q)[None, :])
        if "rate" in eff:
            rt = rate_term({"gain_s": 1.0, "tau_s": eff["rate"]["tau_s"]}, self._u, self.rec.dt)
            pre = np.ascontiguousarray(self._delayed(rt, eff)[None, :])
        d = eff.get("delay", {}).get("delay_s", 0.0) / self.rec.dt
        return {"z": np.ascontiguousarray(z), "blocks": blocks, "w": w, "pre": pre, "post": post, "q": q,
                "delay": float(max(d, 0.0))}

    def _linear(self, eff: Effects, extra: list[float]) -> Effects:
        e = {k: dict(p) for k, p in eff.items()}
        i = 0
        if "rate" in e:
            e["rate"]["gain_s"] = float(extra[i])
            i += 1
        if "drift" in e:
            e["drift"]["offset"] = 0.0
            e["drift"]["offset_per_s"] = float(extra[i])
        return e

    def J(self, eff: Effects) -> float:
        """Training MSE with the masses (unconstrained) and the linear coefficients
        refitted; memoized."""
        k = _key(eff)
        with self._lock:
            if k in self._memo:
                return self._memo[k][0]
        pb = self._problem(eff)
        res = self._solve(pb)
        mse = res["rmse"] ** 2
        if pb["q"] is not None:
            mse *= float(np.mean(pb["q"] ** 2))  # back to the output's units
        self.evaluations += 1
        with self._lock:
            self._memo[k] = (mse, list(res["extra"]))
        return mse

    def with_linear(self, eff: Effects) -> Effects:
        """``eff`` with its linear coefficients from the profiled fit."""
        self.J(eff)
        return self._linear(eff, self._memo[_key(eff)][1])

    def state(self, eff: Effects, n_h: Optional[int] = None) -> FitState:
        """The chain with masses >= 0 (exact NNLS projection) and its linear
        coefficients refitted with them."""
        if n_h is not None and n_h != self.n_h:
            return Fitter(self.rec, n_h, self.u_range, self.stride, self.tol).state(eff)
        pb = self._problem(eff)
        res = self._solve(pb, nnls=True)
        model = PreisachModel._wrap(res["model"], "interpolated")
        e = self._linear(eff, res["extra_nnls"])
        st = FitState(model, e)
        st.train_rmse = rmse(self.predict(st) - self.y)
        return st

    # -- one-dimensional searches on J ----------------------------------------------
    def line(self, eff: Effects, name: str, key: str, scale: float = 1.0, refine: int = 2) -> tuple[Effects, float]:
        """Narrow search on one scalar from its current value (parabolic steps; the first
        step is the scalar's own, times ``scale``)."""
        _, logs, lo, hi, rel = next(s for s in SCALARS[name] if s[0] == key)
        rel *= scale
        x0 = _get(eff, name, key)
        if logs:
            c = math.log(max(x0, 1e-300))
            f = lambda x: self.J(_set(eff, name, key, math.exp(x)))  # noqa: E731
            lo_, hi_ = math.log(lo), math.log(hi)
            c = min(max(c, lo_), hi_)
            pts = sorted({max(lo_, c - rel), c, min(hi_, c + rel)})
        else:
            step = rel * abs(x0) if x0 != 0 else rel * (hi - lo) * 0.01
            f = lambda x: self.J(_set(eff, name, key, x))  # noqa: E731
            x0 = min(max(x0, lo), hi)
            pts = sorted({max(lo, x0 - step), x0, min(hi, x0 + step)})
            lo_, hi_ = lo, hi
        x, fx = _parabolic_search(f, pts, lo_, hi_, refine=refine, expand=3)
        return _set(eff, name, key, math.exp(x) if logs else x), fx

    def split_lag(self, eff: Effects, share: float) -> Effects:
        """The chain with its low-frequency lag (delay plus the low-pass's group delay)
        kept and the share ``share`` of it given to the delay."""
        lag = eff["delay"]["delay_s"] + group_delay(eff["lowpass"])
        share = min(max(share, 0.0), 0.97)
        p = dict(eff["lowpass"])
        k = 1.0 if int(p["order"]) == 1 else math.sqrt(2.0)
        p["cutoff_hz"] = k / (2 * math.pi * (1 - share) * lag)
        return dict(eff, delay={"delay_s": share * lag}, lowpass=p)

    def line_lag(self, eff: Effects) -> tuple[Effects, float]:
        """Search along the valley of a delay and a low-pass: the same total lag split
        differently (coordinate steps cross it only slowly)."""
        lag = eff["delay"]["delay_s"] + group_delay(eff["lowpass"])
        s0 = eff["delay"]["delay_s"] / lag if lag > 0 else 0.0
        f = lambda sh: self.J(self.split_lag(eff, sh))  # noqa: E731
        grid = np.unique(np.clip(np.concatenate([[s0], np.linspace(0.0, 0.9, 7)]), 0.0, 0.97))
        sh, fx = _grid_then_parabola(f, grid)
        return (self.split_lag(eff, sh), fx) if fx < self.J(eff) else (eff, self.J(eff))

    def polish(self, eff: Effects, names: list[str], sweeps: int = 1, scale: float = 1.0) -> tuple[Effects, float]:
        """Coordinate steps on every scalar of ``names`` (the coupled effects re-balance),
        and along the delay/low-pass valley when the chain has both."""
        fx = self.J(eff)
        for _ in range(sweeps):
            f0 = fx
            if "delay" in eff and "lowpass" in eff and ("delay" in names or "lowpass" in names):
                eff, fx = self.line_lag(eff)
            for n in names:
                if n not in eff:
                    continue
                for key, *_ in SCALARS[n]:
                    eff, fx = self.line(eff, n, key, scale)
            if fx > 0.999 * f0:
                break
        return eff, fx

    # -- candidate searches -----------------------------------------------------------
    def add(self, base: Effects, name: str, h: Optional[NDArray[np.float64]] = None) -> Effects:
        """Chain ``base`` plus effect ``name``: the effect's own search with the others
        fixed, then a joint polish of the coupled effects."""
        r = self.rec
        T = float(r.t[-1] - r.t[0])
        eff = {k: dict(p) for k, p in base.items()}
        if name == "delay":
            grid = np.concatenate([[0.0], np.geomspace(max(r.dt / 2, 1e-5), 3e-3, 11)])
            d, _ = _grid_then_parabola(lambda d: self.J(dict(eff, delay={"delay_s": d})), grid)
            eff["delay"] = {"delay_s": float(max(d, 0.0))}
        elif name == "lowpass":
            d0 = eff.get("delay", {}).get("delay_s", 0.0)
            best = None
            for order in (1, 2):
                def f(lf: float, order: int = order) -> float:
                    p = {"cutoff_hz": math.exp(lf), "order": order}
                    e = dict(eff, lowpass=p)
                    if "delay" in eff:
                        # The delay absorbed the low-pass's lag: keep the total.
                        e["delay"] = {"delay_s": max(0.0, d0 - group_delay(p))}
                    return self.J(e)
                grid = np.log(np.geomspace(50.0, 0.4 / self.dt, 10))
                lf, fx = _grid_then_parabola(f, grid)
                if best is None or fx < best[1]:
                    best = (lf, fx, order)
            assert best is not None
            p = {"cutoff_hz": float(math.exp(best[0])), "order": best[2]}
            eff["lowpass"] = p
            if "delay" in eff:
                eff["delay"] = {"delay_s": max(0.0, d0 - group_delay(p))}
        elif name == "vibration":
            eff = self.mode_band(eff, h)
        elif name == "creep":
            tau, c = self.creep_init(eff)
            eff["creep"] = {"taus_s": [tau], "amplitudes": [c], "_norm": True}
        elif name == "drift":
            gmax = min(0.1, 0.5 / max(T, 1e-9))
            g, _ = _grid_then_parabola(lambda g: self.J(dict(eff, drift={"gain_per_s": g, "offset": 0.0,
                                                                          "offset_per_s": 0.0})),
                                       np.linspace(-gmax, gmax, 9))
            eff["drift"] = {"gain_per_s": float(g), "offset": 0.0, "offset_per_s": 0.0}
        elif name == "rate":
            lt, _ = _grid_then_parabola(lambda lt: self.J(dict(eff, rate={"gain_s": 0.0, "tau_s": math.exp(lt)})),
                                        np.log(np.array([1e-3, 2e-3, 5e-3, 1e-2, 2e-2])))
            eff["rate"] = {"gain_s": 0.0, "tau_s": float(math.exp(lt))}
        else:
            raise ValueError(f"unknown effect {name!r}")
        if any(k in eff for k in DYNAMIC) and "delay" not in eff:
            eff["delay"] = {"delay_s": 0.0}  # the record's sub-sample timing (polished below)
        if "lowpass" in eff and name != "lowpass" and eff["lowpass"]["cutoff_hz"] > 0.4 / self.dt:
            del eff["lowpass"]  # a band-fit nuisance beyond what the fit resolves
        # The new effect and those it trades off against are polished together (the rest
        # of the chain stays; the chain found is polished as a whole at the end).
        names = [name] + [k for k in eff if k != name and (k in COUPLED[name] or name in COUPLED[k])]
        eff, _ = self.polish(eff, names, sweeps=2)
        if name == "lowpass":
            eff = self.other_order(eff)
        return self.with_linear(eff)

    def other_order(self, eff: Effects) -> Effects:
        """Try the other low-pass order with the same low-frequency group delay."""
        p = eff["lowpass"]
        o2 = 3 - int(p["order"])
        fc2 = p["cutoff_hz"] * (math.sqrt(2.0) if o2 == 2 else 1 / math.sqrt(2.0))
        e2 = dict(eff, lowpass={"cutoff_hz": fc2, "order": o2})
        e2, f2 = self.polish(e2, ["lowpass", "delay"], sweeps=1)
        return e2 if f2 < self.J(eff) else eff

    def creep_init(self, eff: Effects) -> tuple[float, float]:
        """Creep (one element): a grid over the time constant (5 ms to 20x the record),
        the amplitude by parabolic steps at each, all on the profiled error."""
        T = float(self.rec.t[-1] - self.rec.t[0])
        best: Optional[tuple[float, float, float]] = None
        for tau in np.geomspace(CREEP_TAU_MIN, max(0.05, 20 * T), 9):
            f = lambda c, tau=tau: self.J(dict(eff, creep={"taus_s": [float(tau)], "amplitudes": [c],  # noqa: E731
                                                           "_norm": True}))
            c, fx = _parabolic_search(f, [0.0, 0.02, 0.05], 0.0, 0.5, refine=2, expand=3)
            if best is None or fx < best[2]:
                best = (float(tau), float(c), fx)
        assert best is not None
        return best[0], max(best[1], 1e-4)

    def mode_band(self, eff: Effects, h: Optional[NDArray[np.float64]]) -> Effects:
        """A lightly damped mode: frequency and damping fitted on the error in a band
        around the largest peaks of the residual spectrum (0.6x to 1.6x), with masses
        fixed. In the band a delay is a phase shift, a low-pass a phase shift and an
        attenuation: when the chain has neither, one of them is fitted as a nuisance (an
        unmodelled 0.3 ms puts a 1.5 kHz ringing out of phase). Returns the chain with
        the mode (and the nuisance block)."""
        from preisach.diagnose.effects import _golden, _grid_then_golden

        t, y, dt = self.t, self.y, self.dt
        others = {k: v for k, v in eff.items() if k != "vibration"}
        if h is None:
            h = self.hysteresis(self.state(others).model, others)
        if "rate" in others:
            h = h + self._delayed(rate_term(others["rate"], self._u, self.rec.dt), others)
        lin = {k: v for k, v in others.items() if k not in ("rate", "delay")}
        base = apply_effects(lin, t, t, h, dt)
        n = y.size
        f = np.fft.rfftfreq(n, dt)
        ramp = np.linspace(0.0, 1.0, n)

        def spec(x: NDArray[np.float64]) -> NDArray[np.complex128]:
            return np.fft.rfft(x - x[0] - (x[-1] - x[0]) * ramp)

        Y = spec(y)
        nyq = 0.5 / dt
        nuisance = "delay" not in others and "lowpass" not in others
        # Nuisance phase and gain in the band when the chain has no delay or low-pass yet:
        # a delay (0 to 1.5 ms), or a first-order low-pass (100 Hz to 20 kHz), which also
        # explains the band's attenuation (a mode behind a sensor filter).
        dgrid = np.arange(0.0, 1.5e-3, 2e-5) if nuisance else np.zeros(1)
        cgrid = np.geomspace(100.0, 2e4, 24) if nuisance else np.zeros(0)
        found = [("delay", 0.0)]
        B = spec(base)
        om = 2 * np.pi * f
        masks: dict[tuple[float, float], NDArray[np.intp]] = {}
        phc: dict[tuple[float, float], NDArray[np.complex128]] = {}

        def band_err(p: dict[str, Any], m: tuple[float, float]) -> float:
            # The mode's analog response times the rest of the chain's spectrum (the blocks
            # commute): no simulation per trial; the profiled error judges the result. At
            # most about 600 lines of the band (a mode's peak spans several at that).
            if m not in masks:
                idx = np.flatnonzero((f > m[0]) & (f < m[1]))
                masks[m] = idx[::max(1, -(-idx.size // 600))]
                w = om[masks[m]]
                phc[m] = np.vstack([np.exp(-1j * np.outer(dgrid, w)), 1 / (1 + 1j * np.outer(1 / (2 * np.pi * cgrid), w))])
            mk = masks[m]
            w0, zt = 2 * np.pi * p["frequency_hz"], p["damping"]
            P = w0 * w0 / (w0 * w0 - om[mk] ** 2 + 2j * zt * w0 * om[mk]) * B[mk]
            errs = np.sum(np.abs(P[None, :] * phc[m] - Y[mk][None, :]) ** 2, axis=1)
            k = int(np.argmin(errs))
            found[0] = ("delay", float(dgrid[k])) if k < dgrid.size else ("lowpass", float(cgrid[k - dgrid.size]))
            return float(errs[k])

        def refine(f0: float, zeta: float, span: float) -> tuple[float, float, float, float]:
            m = (0.6 * f0, 1.6 * f0)
            lz, _ = _grid_then_golden(lambda lz: band_err({"frequency_hz": f0, "damping": math.exp(lz)}, m),
                                      np.linspace(math.log(2e-3), math.log(0.3), 12), 8)
            zeta = math.exp(lz)
            lf, _ = _grid_then_golden(lambda lf: band_err({"frequency_hz": math.exp(lf), "damping": zeta}, m),
                                      np.linspace(math.log(f0 * (1 - span)), math.log(min(f0 * (1 + span), 0.45 * nyq)),
                                                  15), 8)
            f0 = math.exp(lf)
            lz, _ = _golden(lambda lz: band_err({"frequency_hz": f0, "damping": math.exp(lz)}, m),
                            lz - 0.4, min(lz + 0.4, math.log(0.5)), 10)
            zeta = math.exp(lz)
            fx = band_err({"frequency_hz": f0, "damping": zeta}, m)
            return f0, zeta, fx, found[0]

        # Every peak's band fit (with its nuisance as a delay or a low-pass) is then judged
        # on the profiled training error (the band ratio alone can prefer a broad peak
        # fitted by a heavily damped "mode").
        best = None
        for fc in (_mode_guess(y - base, dt, 3) or [1000.0]):
            f1, z1, _, nz = refine(fc, 0.02, 0.03)
            e = dict(eff, vibration={"frequency_hz": f1, "damping": z1})
            if nuisance and nz[0] == "delay" and nz[1] > 0:
                e["delay"] = {"delay_s": nz[1]}
            elif nuisance and nz[0] == "lowpass":
                e["lowpass"] = {"cutoff_hz": nz[1], "order": 1}
                e["delay"] = {"delay_s": 0.0}
            j = self.J(e)
            if best is None or j < best[1]:
                best = (e, j)
        assert best is not None
        return best[0]

    def without(self, eff: Effects, name: str) -> Effects:
        """The chain less ``name``, the rest polished (backward elimination)."""
        e = {k: dict(p) for k, p in eff.items() if k != name}
        if name == "lowpass" and "delay" in e:
            e["delay"] = {"delay_s": e["delay"]["delay_s"] + group_delay(eff["lowpass"])}
        if not any(k in e for k in DYNAMIC) and "delay" in e and e["delay"]["delay_s"] <= 0:
            del e["delay"]
        e, _ = self.polish(e, list(e), sweeps=1)
        return self.with_linear(e)


def calibrate_drift(st: FitState, data: list[tuple[Record, slice]]) -> FitState:
    """The drift of a chain recalibrated on the time axis: with the masses and the other
    effects fixed, ``y ~ a x + b x t + o + o'' t`` (``x`` the chain's output before the
    drift block) is linear, solved on the given parts of records. A drift fitted on one
    short record extrapolates poorly to later ones (its slope trades off against what the
    masses absorb), so the diagnoser calibrates it on the training record and the other
    half of each holdout (cross-fitting: no sample is scored with a drift fitted on it).
    Returns the chain with the model scaled by ``a`` and the drift ``(b / a, o, o'')``."""
    if "drift" not in st.effects:
        return st
    pre = FitState(st.model, {k: v for k, v in st.effects.items() if k != "drift"})
    xs, ts, ys = [], [], []
    for rec, sl in data:
        xs.append(pre.predict(rec)[sl])
        ts.append(rec.t[sl])
        ys.append(rec.y[sl])
    x, t, y = np.concatenate(xs), np.concatenate(ts), np.concatenate(ys)
    A = np.column_stack([x, x * t, np.ones_like(t), t])
    (a, b, o, o2), *_ = np.linalg.lstsq(A, y, rcond=None)
    if not (a > 0 and np.isfinite([a, b, o, o2]).all()):
        return st
    eff = {k: dict(v) for k, v in st.effects.items()}
    eff["drift"] = {"gain_per_s": float(b / a), "offset": float(o), "offset_per_s": float(o2)}
    if "rate" in eff:
        eff["rate"]["gain_s"] = float(eff["rate"]["gain_s"] * a)
    m = st.model
    return FitState(PreisachModel(m.weights * a, m.u_range, m.offset * a, m.output), eff, st.train_rmse)
