"""Creep beside a drift: the pair's parameters proposed across records.

A training record that is short against a creep element's time constant cannot tell
the element from a drift: within the record both are slow trends, and the masses and a
drift's gain take up an element of any amplitude equally well (the training error is
flat along that valley). The held-out records tell them apart (the element starts again
at rest with every record, a drift runs on in absolute time), but only for masses
fitted with the right amplitude: ``calibrate_slow`` keeps the training record's scale
and level, which the masses set for the amplitude they were fitted with.

So the pair is found by alternating, on one fold's data (the training record and one
half of each holdout): the slow effects calibrated across the records with the scale
free as well (:func:`preisach.diagnose.search.level_calibrated`), then the masses
refitted on the training record with them. At the pair the records show, the
calibration returns the time constant the masses were fitted with and no scale (the
masses lack none). Those two mismatches are driven to zero by Broyden's method on the
time constant (in log units) and the amplitude: a plain alternation oscillates in the
amplitude and creeps in the time constant, as the masses take up part of each change.
Each fold's chains are proposals that the caller's held-out score chooses among, judged
cross-fitted (a fold's chain scores best on the halves it was calibrated on, so it is
judged on the others).
"""
from __future__ import annotations

import math
from typing import Callable, Optional

import numpy as np

from preisach.diagnose.effects import Record
from preisach.diagnose.ranges import CREEP_AMP_MAX
from preisach.diagnose.search import Effects, Fitter, Trials, less, level_calibrated

#: Alternations per fold (each a masses' fit; Broyden's steps settle in three or four).
STEPS = 4
#: The amplitude's unit in the pair's steps (the time constant's is a factor e).
C_UNIT = 0.05
#: How much worse (a share of the training error above the noise) the pair may fit the
#: training record than the chain it is added to: the record does not tell the pair
#: apart, so its error is flat along the valley up to the masses' fit.
TRAIN_SLACK = 0.01


def applies(eff: Effects, name: str) -> bool:
    """Whether adding ``name`` to the chain ``eff`` makes the pair: creep (of one
    element) and drift."""
    creep = eff.get("creep")
    return (name in ("creep", "drift") and {"creep", "drift"} <= set(eff) | {name}
            and (creep is None or len(creep["taus_s"]) == 1))


def proposals(fitter: Fitter, eff: Effects, data: list[tuple[Record, slice]]) -> list[Effects]:
    """The pair's chains from alternating on ``data`` (records and the part of each to
    fit), starting from ``eff`` (a chain with the pair; its other effects kept). The
    steps' Jacobian starts as the plain alternation's (the calibrated time constant, the
    amplitude moved by the scale the masses lack) and is updated by each step (Broyden);
    a step moves at most a factor e in the time constant and ``C_UNIT`` in the
    amplitude, within their ranges."""
    st = fitter.state(eff)
    x = _point(st.effects)
    tau = fitter.ranges["creep"]["tau"]
    lo, hi = math.log(tau.lo), math.log(tau.hi)
    B = -np.eye(2)
    prev: Optional[tuple[np.ndarray, np.ndarray]] = None
    out: list[Effects] = []
    for _ in range(STEPS):
        cal, s = level_calibrated(st, data)
        F = np.array([_point(cal.effects)[0] - x[0], s / C_UNIT])
        if prev is not None:
            dx, dF = x - prev[0], F - prev[1]
            if float(dx @ dx) > 0:
                B = B + np.outer(dF - B @ dx, dx) / float(dx @ dx)
        try:
            step = -np.linalg.solve(B, F)
        except np.linalg.LinAlgError:
            break
        prev = (x, F)
        x = x + step / max(1.0, float(np.max(np.abs(step))))  # (at most a unit per step)
        x[0] = min(max(x[0], lo), hi)
        x[1] = min(max(x[1], 0.0), CREEP_AMP_MAX / C_UNIT)
        e = {k: dict(v) for k, v in eff.items()}
        e["creep"] = {"taus_s": [float(math.exp(x[0]))], "amplitudes": [float(x[1] * C_UNIT)], "normalized": True}
        e["drift"] = dict(cal.effects["drift"], offset_per_s=0.0)
        e = fitter.with_linear(e)
        out.append(e)
        st = fitter.state(e)
    return out


def _point(eff: Effects) -> np.ndarray:
    """A chain's pair as the steps' coordinates: log time constant, amplitude in ``C_UNIT``."""
    cr = eff["creep"]
    return np.array([math.log(cr["taus_s"][0]), cr["amplitudes"][0] / C_UNIT])


def best(fitter: Fitter, eff: Effects, name: str, folds: list[list[tuple[Record, slice]]],
         held: Callable[[Effects], float], score: Callable[[Effects], float], trials: Trials,
         j_max: float, min_shrink: float) -> Effects:
    """Of ``eff`` (the candidate ``name``'s own fit, with the pair) and every fold's
    proposals that fit the training record to ``j_max`` (its MSE; a chain beyond it
    trades the training record's error for the holdouts'), the chain ``held`` scores best
    (``held`` remembers each, for the cross-fitted judgement). A drift added to a chain
    with creep is credited only with what it adds to the creep the pair moved: the best
    proposal is kept when it beats itself without the drift by ``min_shrink`` (``score``:
    a chain's holdout RMSE, not remembered); else ``eff``."""
    props = [c for cs in trials.map(lambda d: proposals(fitter, eff, d), folds) for c in cs]
    chains = [eff] + [c for c in props if fitter.J(c) <= j_max]
    scores = trials.map(held, chains)
    i = int(np.argmin(scores))
    if i and name == "drift" and score(less(chains[i], "drift")) * (1 - min_shrink) < scores[i]:
        return eff
    return chains[i]
