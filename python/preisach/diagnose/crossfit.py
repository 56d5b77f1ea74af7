"""Cross-fitting on the holdouts: an effect that only the holdouts carry.

The stepwise search fits effects on the training record, so an effect the training
record does not carry (the model identified on a clean sensor channel, the loop reading
a delayed one) is not found there. Here the effect's parameter is fitted on some
holdouts, with the chain found (masses and effects) fixed, and scored on the others:
leave one holdout out, or, with a single holdout, one half against the other. No
scored sample was used to fit the parameter it is scored with.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np
from numpy.typing import NDArray

from preisach.diagnose.effects import FitState, Record, _grid_then_parabola
from preisach.diagnose.ranges import Bound, delay_grid

Errors = Callable[[FitState], list[NDArray[np.float64]]]


def _with_delay(st: FitState, extra: float) -> FitState:
    """The chain with ``extra`` seconds added to its delay (its timing delay, if any)."""
    eff = {k: dict(v) for k, v in st.effects.items()}
    d0 = float(eff.get("delay", {}).get("delay_s", 0.0))
    eff["delay"] = {"delay_s": d0 + extra}
    return FitState(st.model, eff, st.train_rmse)


def _fit_delay(st: FitState, parts: list[tuple[Record, slice]], bound: Bound) -> float:
    """The added delay that fits the parts best (masses and the other effects fixed):
    a grid (``delay_grid``) up to the bound, then parabolic steps."""
    d0 = float(st.effects.get("delay", {}).get("delay_s", 0.0))
    hi = max(bound.hi - d0, 0.0)
    dt = min(r.dt for r, _ in parts)
    if hi <= dt:
        return 0.0
    grid = delay_grid(dt, hi)

    def sse(d: float) -> float:
        s = _with_delay(st, max(d, 0.0))
        return float(sum(np.sum((s.predict(r) - r.y)[sl] ** 2) for r, sl in parts))

    d, _ = _grid_then_parabola(sse, grid)
    return float(min(max(d, 0.0), hi))


def holdout_delay(st: FitState, hos: list[Record], errors: Errors, bound: Bound) -> dict[str, Any]:
    """A delay only the holdouts carry, cross-fitted: the added delay fitted on the other
    holdouts (or the other half of a single one) and each holdout (half) scored with it.

    Returns ``errors`` (per holdout, cross-fitted, as ``errors`` computes them for a
    chain), ``folds`` (what was fitted on what, and the delay found), ``added_s`` (the
    delay fitted on every holdout, for the saved chain) and ``state`` (the chain with
    it)."""
    out = [np.empty(h.y.size) for h in hos]
    folds = []
    if len(hos) >= 2:
        for i, h in enumerate(hos):
            fit = [(g, slice(None)) for g in hos if g is not h]
            d = _fit_delay(st, fit, bound)
            out[i] = errors(_with_delay(st, d))[i]
            folds.append({"fit": [g.name for g, _ in fit], "score": h.name, "added_s": d})
    else:
        h = hos[0]
        m = h.y.size // 2
        for on, score, label in ((slice(0, m), slice(m, None), "second"), (slice(m, None), slice(0, m), "first")):
            d = _fit_delay(st, [(h, on)], bound)
            out[0][score] = errors(_with_delay(st, d))[0][score]
            folds.append({"fit": [f"{h.name} {'first' if label == 'second' else 'second'} half"],
                          "score": f"{h.name} {label} half", "added_s": d})
    added = _fit_delay(st, [(h, slice(None)) for h in hos], bound)
    return {"errors": out, "folds": folds, "added_s": added, "state": _with_delay(st, added)}


def consistent(folds: list[dict[str, Any]], min_delay: float) -> bool:
    """Every fold found a delay longer than ``min_delay``, within 25 % of each other (a
    channel's delay is the same on every record it reads)."""
    ds = [float(f["added_s"]) for f in folds]
    return min(ds) >= min_delay and max(ds) <= 1.25 * min(ds)
