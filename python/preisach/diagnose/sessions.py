"""An output offset or gain that differs between records (sessions: a sensor's offset
or calibration moves between power cycles), under ``drift``, with values per record.

Per-record offsets are easily taken for other effects' leftovers: unrecorded history
leaves an offset that fades once the input has swept the range, creep restarts with
every record and leaves a trend, and a slow wander is the repeatability floor. So a
holdout's offset (measured minus chain) is accepted only on evidence that separates it
from them: on the part of the record after its input swept its range (history wiped
out), the offsets of that part's two halves agree within a quarter (constant, not a
trend), each half's offset shrinks the other half's RMSE by a tenth (a held-out check),
and the offset exceeds the floor (noise or repeatability). Scored cross-fitted: the
first half of that part with the second's offset and the reverse, the samples before it
with their mean.

A gain per record (measured = gain x chain + offset) is tried on top of the offset, or
alone, by the same rules: the halves agree on it, each half's fit shrinks the other's
error by a tenth beyond what the offset alone did, and it moves the output by more than
the floor. Model error does not pass: the hysteresis model's error depends on the input,
which differs between the halves, while a sensor's gain does not.
"""
from __future__ import annotations

from typing import Callable, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.diagnose.effects import rmse
from preisach.diagnose.initial import swept

Params = tuple[float, ...]


def _halves(u: NDArray[np.float64]) -> Optional[tuple[slice, slice]]:
    """The two halves of the record's part after its input swept its range (history
    wiped out), or None when that part is too short to tell anything."""
    k = swept(u)
    if u.size - k < 64:
        return None
    m = k + (u.size - k) // 2
    return slice(k, m), slice(m, None)


def _cross_fitted(fit: Callable[[slice], Params], error: Callable[[Params, slice], NDArray[np.float64]],
                  halves: tuple[slice, slice]) -> tuple[Params, Params, NDArray[np.float64]]:
    """The parameters ``fit`` finds on each half, and the record's error (``error``)
    with them cross-fitted: each half with the other's, the samples before the halves
    with their mean."""
    a, b = halves
    pa, pb = fit(a), fit(b)
    out = error(tuple(0.5 * (x + y) for x, y in zip(pa, pb)), slice(None))
    out[a] = error(pb, a)
    out[b] = error(pa, b)
    return pa, pb, out


def _each_half_shrinks(out: NDArray[np.float64], base: NDArray[np.float64], halves: tuple[slice, slice]) -> bool:
    """Each half's error with the other half's fit is a tenth below ``base``'s."""
    return all(rmse(out[s]) <= 0.9 * rmse(base[s]) for s in halves)


def record_offset(err: NDArray[np.float64], u: NDArray[np.float64], floor: float
                  ) -> Optional[tuple[float, NDArray[np.float64]]]:
    """The record's offset (measured minus chain; ``err`` is chain minus measured) and
    its error with the offset cross-fitted, or None when the evidence does not hold."""
    halves = _halves(u)
    if halves is None:
        return None
    (oa,), (ob,), out = _cross_fitted(lambda s: (-float(np.mean(err[s])),), lambda p, s: err[s] + p[0], halves)
    o = 0.5 * (oa + ob)
    if abs(oa - ob) > 0.25 * max(abs(oa), abs(ob)) or abs(o) <= floor:
        return None
    return (o, out) if _each_half_shrinks(out, err, halves) else None


def record_gain(err: NDArray[np.float64], y: NDArray[np.float64], u: NDArray[np.float64], floor: float,
                base: NDArray[np.float64]) -> Optional[tuple[float, float, NDArray[np.float64]]]:
    """The record's gain and offset (measured = gain * chain + offset, fitted on each half
    of the part after the sweep) and its error with them cross-fitted, or None when the
    gain's evidence does not hold. ``base`` is the error the gain must beat: both halves
    agree on the gain within a quarter of its distance from 1, each half's fit shrinks
    the other half's error by a tenth against ``base``, and the gain moves the output by
    more than the floor."""
    halves = _halves(u)
    if halves is None:
        return None
    c = err + y  # the chain's output

    def fit(s: slice) -> Params:
        g, o = np.linalg.lstsq(np.column_stack([c[s], np.ones(c[s].size)]), y[s], rcond=None)[0]
        return float(g), float(o)

    (ga, oa), (gb, ob), out = _cross_fitted(fit, lambda p, s: p[0] * c[s] + p[1] - y[s], halves)
    g, o = 0.5 * (ga + gb), 0.5 * (oa + ob)
    if abs(ga - gb) > 0.25 * max(abs(ga - 1), abs(gb - 1)) or abs(g - 1) * float(np.std(c[halves[0].start:])) <= floor:
        return None
    return (g, o, out) if _each_half_shrinks(out, base, halves) else None


def offsets(errs: list[NDArray[np.float64]], outputs: list[NDArray[np.float64]],
            inputs: list[NDArray[np.float64]], names: list[str], floor: float
            ) -> tuple[dict[str, float], dict[str, float], list[NDArray[np.float64]]]:
    """Per-record offsets and gains (by name, only where the evidence holds; a gain with
    its offset is kept where it scores better than the offset alone) and every record's error with them cross-fitted
    (unchanged where none was accepted). ``outputs`` are the measured outputs."""
    found: dict[str, float] = {}
    gains: dict[str, float] = {}
    out = []
    for e, y, u, n in zip(errs, outputs, inputs, names):
        got = record_offset(e, u, floor)
        with_gain = record_gain(e, y, u, floor, e)
        if with_gain is not None and (got is None or rmse(with_gain[2]) < rmse(got[1])):
            gains[n], found[n] = with_gain[0], with_gain[1]
            out.append(with_gain[2])
        elif got is not None:
            found[n] = got[0]
            out.append(got[1])
        else:
            out.append(e)
    return found, gains, out
