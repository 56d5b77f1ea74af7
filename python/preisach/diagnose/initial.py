"""The hysteresis memory at a record's start, when history nobody recorded came before.

A record that starts mid-range after unrecorded excursions does not start with every
relay at -1: the output carries an offset that fades once the input has swept the range
(wiping-out erases the history). The starting staircase is estimated per record as
alternating extrema in input units (the hysteresis block's ``initial_extrema``: the
input rose to ``M``, fell to ``m``, then went to the first sample), on a grid of the
model's range and refined below it, with the chain fixed, on the part of the record
before the input has swept its range (the only part the memory at the start reaches).
Two numbers fitted on the samples they are scored on: the staircase counts only where
that part's error is its own (``concentrated``).
"""
from __future__ import annotations

import threading
from typing import Any, Callable, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.chain import Chain
from preisach.diagnose.effects import FitState, Record, rmse

#: A ``map``: the builtin, or a thread pool's (``search.Trials.map``), which keeps the order.
Map = Callable[..., Any]
#: A starting staircase estimated for a chain on a record, with the RMSE of the part
#: before the sweep before and after it (``estimate``).
Estimate = tuple[list[float], float, float]
Start = Callable[[FitState, Record], Estimate]


def swept(u: NDArray[np.float64]) -> int:
    """The sample after which the input has reached both its lowest and its highest
    value (within 0.1 % of its span: a periodic input reaches them every period, in
    values equal to rounding): beyond it the starting memory is wiped out."""
    tol = 1e-3 * float(np.ptp(u))
    lo = int(np.argmax(u <= np.min(u) + tol))
    hi = int(np.argmax(u >= np.max(u) - tol))
    return max(lo, hi) + 1


def predict_from(st: FitState, rec: Record, extrema: Optional[list[float]]) -> NDArray[np.float64]:
    """The chain's output on ``rec`` with the hysteresis memory after ``extrema``."""
    if not extrema:
        return st.predict(rec)
    return predictor(st, rec)(extrema)


def predictor(st: FitState, rec: Record) -> Callable[[Optional[list[float]]], NDArray[np.float64]]:
    """``predict_from`` of the chain on ``rec`` as a function of the extrema, the chain's
    blocks built once (for many staircases; safe to call from several threads)."""
    blocks = Chain(st.model, st.effects).blocks

    def one(extrema: Optional[list[float]]) -> NDArray[np.float64]:
        if not extrema:
            return st.predict(rec)
        b = [dict(blocks[0], initial_extrema=[float(x) for x in extrema])] + blocks[1:]
        y: NDArray[np.float64] = Chain.from_blocks(b).predict(rec.t, rec.u)
        return y

    return one


def fitted_part(rec: Record) -> int:
    """The samples the starting staircase is fitted on: the part before the sweep."""
    return max(swept(rec.u), 16)


def concentrated(before: float, after: float, rest: float) -> bool:
    """The part before the sweep carries an error of its own (at least twice the rest
    of the record's RMSE ``rest``) that the staircase halves at least: what a memory
    at the start leaves, unlike an effect that errs all along the record."""
    return before >= 2.0 * rest and after <= 0.5 * before


def staircases(st: FitState, levels: int = 9) -> list[list[float]]:
    """The starting staircases tried (``[M]`` or ``[M, m]``, ``m < M``) on a grid of
    ``levels`` points of the model's range."""
    lo, hi = st.model.u_range
    grid = np.linspace(lo, hi, levels)
    return [[float(M)] if m is None else [float(M), m]
            for M in grid[1:] for m in [None] + [float(x) for x in grid if x < M]]


def own_memory(ex: list[float], u0: float) -> bool:
    """Whether starting staircase ``ex`` (``[M]`` or ``[M, m]``) leaves a memory of its
    own once the input has moved to the record's first sample ``u0``: rising to ``M`` or
    beyond wipes the staircase out (the memory from rest), and falling to ``m`` or below
    goes on with the fall from ``M`` (the memory after ``[M]``)."""
    return u0 < ex[0] and (len(ex) == 1 or u0 > ex[1])


def estimate(st: FitState, rec: Record, levels: int = 9, run: Map = map) -> Estimate:
    """The starting staircase of ``rec`` (``[M, m]``, ``[M]`` or none) that fits the
    part before the sweep best (``fitted_part``), on a grid of the model's range, then
    refined (``refine``); returns it with the RMSE of that part before and after.
    ``run`` (a ``map``) takes the staircases of the grid and of each move."""
    k = fitted_part(rec)
    part = Record(rec.name, rec.t[:k], rec.u[:k], rec.y[:k], rec.dt)
    pred = predictor(st, part)

    def err(ex: list[float]) -> float:
        return rmse(pred(ex) - part.y)

    grid = staircases(st, levels)
    scored = list(run(err, [[]] + grid))
    before = scored[0]
    best: tuple[float, list[float]] = (before, [])
    for ex, e in zip(grid, scored[1:]):
        if e < best[0]:
            best = (e, ex)
    if not best[1]:
        return [], before, before
    lo, hi = st.model.u_range
    ex, after = refine(err, best[1], best[0], (hi - lo) / (levels - 1), run=run)
    return ex, before, after


def refine(err: Callable[[list[float]], float], ex: list[float], e: float, step: float,
           rounds: int = 4, run: Map = map) -> tuple[list[float], float]:
    """The staircase ``ex`` (error ``e``) moved by half the grid's ``step``: the best
    move of one extremum up or down, while ``err`` falls (at most four moves; the order
    ``m < M`` kept), then again with the step halved, ``rounds`` times (a pattern
    search). ``run`` (a ``map``) takes the moves of each step."""
    for _ in range(rounds):
        step /= 2
        for _move in range(4):
            trials = [[x + s if j == i else x for j, x in enumerate(ex)] for i in range(len(ex)) for s in (-step, step)]
            trials = [t for t in trials if len(t) == 1 or t[1] < t[0]]
            scored = list(zip(run(err, trials), trials))
            if not scored or min(scored)[0] >= e:
                break
            e, ex = min(scored)
    return ex, e


def own_start(st: FitState, rec: Record, err: NDArray[np.float64],
              est: Optional[Estimate] = None,
              run: Map = map) -> tuple[NDArray[np.float64], list[float]]:
    """The error ``err`` of chain ``st`` on ``rec`` with the starting staircase
    estimated on it (``est``, default ``estimate(st, rec)``), where the part before the
    sweep carries an error of its own (``concentrated``); returns the error and the
    staircase kept (empty: none). ``run`` (a ``map``) takes the chain's runs."""
    ex, before, after = est if est is not None else estimate(st, rec, run=run)
    k = fitted_part(rec)
    if not ex or not concentrated(before, after, rmse(err[k:]) if k < err.size else 0.0):
        return err, []
    from_ex, from_rest = run(predictor(st, rec), [ex, []])
    corrected: NDArray[np.float64] = err + from_ex - from_rest
    return corrected, ex


class Starts:
    """``estimate`` kept by chain (its JSON text: the same blocks) and record (its name),
    for the steps of one diagnosis that judge the same chain's starts; ``run`` (a ``map``)
    is the one ``estimate`` takes. Safe to call from several threads."""

    def __init__(self, run: Map = map) -> None:
        self.run = run
        self._kept: dict[tuple[str, str], Estimate] = {}
        self._lock = threading.Lock()

    def __call__(self, st: FitState, rec: Record) -> Estimate:
        key = (Chain(st.model, st.effects).to_json(), rec.name)
        with self._lock:
            got = self._kept.get(key)
        if got is None:
            got = estimate(st, rec, run=self.run)
            with self._lock:
                self._kept[key] = got
        return list(got[0]), got[1], got[2]
