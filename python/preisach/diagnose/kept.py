"""A simulator kept as the baseline: the gap between "my simulator" and "my stage".

The given chain (a simulated stage, every block of it) is kept as it is: its output on
each record's input is what the effects act on. The records are rewritten with that
output as their input, and the hysteresis in front is the identity (a Preisach model
with equal masses on the diagonal, exact for the interpolated output), fixed: the
candidate effects' parameters are searched on the training record's error with nothing
refitted but the effects' own linear coefficients (the drift's offset slope).

With ``refit_masses`` the masses of the simulator's own hysteresis block are refitted on
the training record first (``refitted``: the blocks before it give its input, the series
linear blocks after it are what the masses are fitted behind, every block is kept), and
the chain so refitted is the one kept.
"""
from __future__ import annotations

import math
from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.chain import Chain
from preisach.diagnose.effects import FitState, Record, export_state
from preisach.diagnose.search import Effects, Fitter, Trials, _key, window_mean
from preisach.model import PreisachModel

#: The effects searched behind a kept simulator: the output-side ones whose chain
#: blocks follow it unchanged (a rate effect acts on the hysteresis input, creep's
#: pinned form rescales the masses).
KEPT_CANDIDATES = ("delay", "lowpass", "vibration", "drift")


def identity(lo: float, hi: float, n_h: int) -> PreisachModel:
    """A Preisach model whose interpolated output is its input on ``[lo, hi]``."""
    w = np.zeros((n_h, n_h))
    np.fill_diagonal(w, (hi - lo) / (2 * n_h))
    return PreisachModel(w, (lo, hi), 0.5 * (lo + hi), "interpolated")


def run_on(chain: Chain, rec: Record) -> NDArray[np.float64]:
    """The chain's output on a record's input, run per sample as a simulator runs
    (``simulate``: the input held, its noise included), or, when a block cannot run at
    the record's rate, with ``predict``."""
    try:
        y = chain.simulate(rec.t, rec.u)
    except ValueError:
        y = chain.predict(rec.t, rec.u)
    return np.asarray(y, dtype=np.float64)


def through(stage: Chain, recs: list[Record]) -> tuple[list[Record], tuple[float, float]]:
    """The records with the stage's output on their input as input, and a range that
    holds every such output (a fifth of their span wider each side)."""
    out = [Record(r.name, r.t, run_on(stage, r), r.y, r.dt) for r in recs]
    lo = min(float(np.min(r.u)) for r in out)
    hi = max(float(np.max(r.u)) for r in out)
    pad = 0.2 * max(hi - lo, 1e-9)
    return out, (lo - pad, hi + pad)


class KeptFitter(Fitter):
    """A :class:`Fitter` whose hysteresis is fixed (``model``): the error of a chain is
    its training MSE with only the drift's offset slope solved (least squares)."""

    def __init__(self, rec: Record, model: PreisachModel, stride: int, trials: Optional[Trials] = None) -> None:
        super().__init__(rec, model.n_h, model.u_range, stride, trials=trials)
        self.model = model
        self._fixed: dict[tuple[Any, ...], Effects] = {}

    def _fit(self, eff: Effects) -> tuple[float, Effects]:
        e = {k: dict(v) for k, v in eff.items()}
        if "drift" in e:
            e["drift"].update(offset=0.0, offset_per_s=0.0)
        r = self.y - self.predict(FitState(self.model, e))
        if "drift" in e:
            o = float(np.dot(self.t, r) / max(float(np.dot(self.t, self.t)), 1e-300))
            e["drift"]["offset_per_s"] = o
            r = r - o * self.t
        return float(np.mean(r * r)), e

    def J(self, eff: Effects, above: Optional[float] = None) -> float:
        k = _key(eff)
        got = self._memoized(k, None)  # (its fits are exact: no ceiling)
        if got is not None:
            return got
        mse, e = self._fit(eff)
        self.evaluations += 1
        with self._lock:
            self._memo[k] = (mse, [], None)
            self._fixed[k] = e
        return mse

    def with_linear(self, eff: Effects) -> Effects:
        self.J(eff)
        return {k: dict(v) for k, v in self._fixed[_key(eff)].items()}

    def state(self, eff: Effects, n_h: Optional[int] = None) -> FitState:
        e = self.with_linear(eff)
        return FitState(self.model, e, math.sqrt(self.J(eff)))

    def hysteresis(self, model: PreisachModel, eff: Effects) -> NDArray[np.float64]:
        return super().hysteresis(self.model, eff)


def saved_chain(stage: Chain, st: FitState) -> Chain:
    """The stage followed by the effects found (the identity in front dropped; with
    refitted masses, their map is kept as a hysteresis block after the stage)."""
    final = export_state(st)
    blocks = list(stage.blocks)
    ident = identity(*final.model.u_range, final.model.n_h)
    if not (np.allclose(final.model.weights, ident.weights, rtol=1e-9, atol=0.0)
            and math.isclose(final.model.offset, ident.offset, rel_tol=1e-9, abs_tol=1e-12)):
        blocks += Chain(final.model).blocks
    blocks += Chain(None, final.effects).blocks if final.effects else []
    return Chain.from_blocks(blocks, stage.sample_rate_hz)


def _series_linear(block: dict[str, Any]) -> bool:
    """A block the masses can be fitted behind (creep, vibration, lowpass, delay, sensor)."""
    try:
        Chain.from_blocks([block]).response([1.0])
    except ValueError:
        return False
    return True


def refitted(stage: Chain, rec: Record, n_h: int, fit_rate_hz: float = 25e3) -> Chain:
    """``stage`` with its hysteresis block replaced by one of ``n_h`` levels whose masses
    (>= 0) are fitted on ``rec``: its input is the blocks before it run on the record's
    input, and its output passes the series linear blocks after it (the others, noise or
    a quantizer, do not enter the fit); every other block is kept as it is."""
    from preisach import _preisach

    blocks = stage.blocks
    k = next((i for i, b in enumerate(blocks) if b.get("type") == "hysteresis"), None)
    if k is None:
        raise ValueError("baseline: refit_masses needs a chain with a hysteresis block")
    x = run_on(Chain.from_blocks(blocks[:k]), rec) if k else rec.u
    lo, hi = float(np.min(x)), float(np.max(x))
    pad = 0.05 * max(hi - lo, 1e-9)
    post = [b for b in blocks[k + 1:] if _series_linear(b)]
    stride = max(1, int(round(1.0 / (rec.dt * fit_rate_hz))))
    sess = _preisach.Behind(np.ascontiguousarray(x), n_h, (lo - pad, hi + pad), stride)
    behind = Chain.from_blocks(post) if post else Chain(None, {})
    res = sess.solve(window_mean(rec.y, stride), rec.dt * stride, behind._core, None, None, None, 1e-6, nnls=True)
    model = PreisachModel._wrap(res["model"], "interpolated")
    return Chain.from_blocks(blocks[:k] + Chain(model).blocks + blocks[k + 1:], stage.sample_rate_hz)
