"""The hysteresis memory at a record's start, when history nobody recorded came before.

A record that starts mid-range after unrecorded excursions does not start with every
relay at -1: the output carries an offset that fades once the input has swept the range
(wiping-out erases the history). The starting staircase is estimated per record as
alternating extrema in input units (the hysteresis block's ``initial_extrema``: the
input rose to ``M``, fell to ``m``, then went to the first sample), with the chain
fixed, on the part of the record before the input has swept its range (the only part
the memory at the start reaches).
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from numpy.typing import NDArray

from preisach.chain import Chain
from preisach.diagnose.effects import FitState, Record, rmse


def swept(u: NDArray[np.float64]) -> int:
    """The sample after which the input has reached both its lowest and its highest
    value: beyond it the starting memory is wiped out."""
    return int(max(np.argmin(u), np.argmax(u))) + 1


def predict_from(st: FitState, rec: Record, extrema: Optional[list[float]]) -> NDArray[np.float64]:
    """The chain's output on ``rec`` with the hysteresis memory after ``extrema``."""
    if not extrema:
        return st.predict(rec)
    blocks = Chain(st.model, st.effects).blocks
    blocks[0] = dict(blocks[0], initial_extrema=[float(x) for x in extrema])
    y: NDArray[np.float64] = Chain.from_blocks(blocks).predict(rec.t, rec.u)
    return y + st.offsets.get(rec.name, 0.0) if st.offsets else y


def estimate(st: FitState, rec: Record, levels: int = 9) -> tuple[list[float], float, float]:
    """The starting staircase of ``rec`` (``[M, m]``, ``[M]`` or none) that fits the
    part before the sweep best, on a grid of the model's range; returns it with the
    RMSE of that part before and after."""
    k = max(swept(rec.u), 16)
    part = Record(rec.name, rec.t[:k], rec.u[:k], rec.y[:k], rec.dt)
    lo, hi = st.model.u_range
    grid = np.linspace(lo, hi, levels)
    before = rmse(predict_from(st, part, None) - part.y)
    best: tuple[float, list[float]] = (before, [])
    for M in grid[1:]:
        for m in [None] + [float(x) for x in grid if x < M]:
            ex = [float(M)] if m is None else [float(M), m]
            e = rmse(predict_from(st, part, ex) - part.y)
            if e < best[0]:
                best = (e, ex)
    return best[1], before, best[0]
