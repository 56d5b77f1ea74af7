"""Records that start with a step from an unrecorded rest level.

A capture that starts the moment the command leaves its rest level (a dSPACE capture
triggered by the first command) shows the stage's response to that step: a lightly
damped mode rings for tens of milliseconds after the first sample. A chain run from rest
at the record's first input (the default) cannot explain it, and a mode fitted on such
a record has nothing to fit.

The chain's linear blocks are linear, so the response to a step from the rest input
``r`` to the first input ``u0`` is the chain's output settled at ``u0`` plus
``A (1 - s(t))``: ``s`` the unit step response of the fast linear blocks (vibration,
low-pass, delay; their DC gain is 1) and ``A = H(r) - H(u0)`` the change of the
hysteresis output. ``A`` enters linearly: it is one column of the least squares (the
training record's, solved with the masses) and one scalar per scored record, fitted on
the record's start (the samples the transient reaches). The rest input reported is the
input whose output on the rising branch of the training input's major loop differs from
the first sample's by ``A`` (for a rest below the first input the rise to the first
sample wipes the rest out of the memory, so only that change matters).
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.chain import Chain
from preisach.diagnose.effects import FitState, Record, _grid_then_parabola, rmse
from preisach.diagnose.initial import concentrated

#: The blocks whose step response the rest step excites within a record's start (creep's
#: slow one is left out: a slow transient at the start is unrecorded history's, or a
#: drift's, as much as a rest step's).
FAST = ("vibration", "lowpass", "delay")


def fast_blocks(effects: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The fast linear blocks of a chain's effects."""
    return {k: {kk: vv for kk, vv in v.items() if not kk.startswith("_")} for k, v in effects.items() if k in FAST}


def transient(effects: dict[str, dict[str, Any]], t: NDArray[np.float64]) -> Optional[NDArray[np.float64]]:
    """``1 - s(t)`` on the times ``t``: the fast blocks run from rest at 1 with input 0
    (None when the chain has no fast block with dynamics: a delay alone only holds the
    first samples)."""
    fast = fast_blocks(effects)
    if not any(k in fast for k in ("vibration", "lowpass")):
        return None
    y: NDArray[np.float64] = Chain(None, fast).predict(t, np.zeros(t.size), initial_input=1.0)
    return y


def support(col: NDArray[np.float64], share: float = 0.05) -> int:
    """The samples the transient reaches: up to where ``|col|`` has fallen below
    ``share`` of its peak for good (at least 16)."""
    big = np.flatnonzero(np.abs(col) >= share * float(np.max(np.abs(col))))
    return int(min(col.size, max(16, (big[-1] + 1) if big.size else 0)))


def amplitude(err: NDArray[np.float64], col: NDArray[np.float64]) -> float:
    """The least-squares ``A`` of ``measured - chain = A col`` (``err`` is chain minus
    measured, as the scoring computes it)."""
    den = float(col @ col)
    return float(-(err @ col) / den) if den > 0 else 0.0


def remove(st: FitState, rec: Record, err: NDArray[np.float64]) -> tuple[NDArray[np.float64], float]:
    """The record's error (chain minus measured) with the rest step's transient fitted on
    the record's start and removed, and its amplitude ``A``; the error unchanged and
    ``A = 0`` where the chain has no fast dynamics or the start shows no step of its
    own (``concentrated``: the start errs at least twice the rest of the record's RMSE,
    and the transient halves that)."""
    col = transient(st.effects, rec.t)
    if col is None:
        return err, 0.0
    k = support(col)
    a = amplitude(err[:k], col[:k])
    fixed = err + a * col
    if not concentrated(rmse(err[:k]), rmse(fixed[:k]), rmse(err[k:]) if k < err.size else 0.0):
        return err, 0.0
    return fixed, a


def rest_input(st: FitState, rec: Record, a: float, known: tuple[float, float]) -> float:
    """The rest input ``r`` whose output differs from the first sample's by ``a``, on the
    rising branch of the major loop of ``known`` (the training input's range: the model
    run up to its top, down to its bottom, then up). Only increments along that branch
    are used: they are what the training record identifies (the masses below its lowest
    input trade off with the offset, so the branch from "every relay down" is not
    identified). Clipped to ``known``."""
    model = st.model
    grid = np.linspace(known[0], known[1], 513)
    # A rise: monotone (the running maximum irons out rounding).
    branch = np.maximum.accumulate(model.predict(np.r_[known[1], known[0], grid])[2:])
    target = float(np.interp(float(rec.u[0]), grid, branch)) + a
    k = int(np.searchsorted(branch, target))
    if k <= 0:
        return float(grid[0])
    if k >= grid.size:
        return float(grid[-1])
    a0, a1 = branch[k - 1], branch[k]
    w = 0.0 if a1 == a0 else (target - a0) / (a1 - a0)
    return float(grid[k - 1] + w * (grid[k] - grid[k - 1]))


def starts_with_step(r: NDArray[np.float64], dt: float, window_s: float = 0.02) -> bool:
    """The residual of the hysteresis alone errs in the record's first ``window_s``
    seconds at least three times as much as over the rest of the record: what a step
    from rest leaves (the evidence that turns on the training record's transient)."""
    k = max(16, int(round(window_s / dt)))
    return r.size > 4 * k and rmse(r[:k]) >= 3.0 * rmse(r[k:])


def rest_inputs(st: FitState, recs: list[Record], known: tuple[float, float]) -> dict[str, dict[str, float]]:
    """For each record that starts with a step of its own (by record name; the others
    started at rest at their first input and are left out): ``rest_step``, the change
    of the chain's output from the rest to the first sample (the transient's amplitude,
    output units), and ``rest_input`` (``rest_input``; ``known`` the training input's
    range)."""
    out = {}
    for r in recs:
        _, a = remove(st, r, st.predict(r) - r.y)
        if a != 0.0:
            out[r.name] = {"rest_input": rest_input(st, r, a, known), "rest_step": -a}
    return out


def start_mode(along: Any, eff: dict[str, dict[str, Any]], lo: float = 2e-3, hi: float = 0.15,
               span: float = 0.03) -> dict[str, Any]:
    """The mode refitted on grids (then parabolic steps): its damping, its frequency
    within ``span`` (in steps of a tenth of a percent: a ringing of tens of milliseconds
    turns its phase quickly with the frequency), its damping again. A record's start
    ringing after a step from rest fixes both directly in time, where the fit of the
    residual spectrum (the chain's settled output has none of that ringing) can be far
    off. ``along``: the fitter's error along a family of chains."""
    def damping(e: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
        f, fm = along(lambda lz: dict(e, vibration=dict(e["vibration"], damping=float(np.exp(lz)))))
        lz, _ = _grid_then_parabola(f, np.log(np.geomspace(lo, hi, 10)), fmany=fm)
        return dict(e, vibration=dict(e["vibration"], damping=float(np.exp(lz))))

    eff = damping(eff)
    f0 = float(eff["vibration"]["frequency_hz"])
    f, fm = along(lambda lf: dict(eff, vibration=dict(eff["vibration"], frequency_hz=float(np.exp(lf)))))
    lf, _ = _grid_then_parabola(f, np.log(f0) + np.linspace(-span, span, int(round(2 * span / 1e-3)) + 1), fmany=fm)
    return damping(dict(eff, vibration=dict(eff["vibration"], frequency_hz=float(np.exp(lf)))))
