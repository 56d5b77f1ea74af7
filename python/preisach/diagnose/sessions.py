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

from typing import Optional

import numpy as np
from numpy.typing import NDArray

from preisach.diagnose.effects import rmse
from preisach.diagnose.initial import swept


def record_offset(err: NDArray[np.float64], u: NDArray[np.float64], floor: float
                  ) -> Optional[tuple[float, NDArray[np.float64]]]:
    """The record's offset (measured minus chain; ``err`` is chain minus measured) and
    its error with the offset cross-fitted, or None when the evidence does not hold."""
    k = swept(u)
    part = err[k:]
    if part.size < 64:
        return None
    m = k + part.size // 2
    a, b = err[k:m], err[m:]
    oa, ob = -float(np.mean(a)), -float(np.mean(b))
    o = 0.5 * (oa + ob)
    if abs(oa - ob) > 0.25 * max(abs(oa), abs(ob)) or abs(o) <= floor:
        return None
    if rmse(b + oa) > 0.9 * rmse(b) or rmse(a + ob) > 0.9 * rmse(a):
        return None
    out = err + o
    out[k:m] = a + ob
    out[m:] = b + oa
    return o, out


def record_gain(err: NDArray[np.float64], y: NDArray[np.float64], u: NDArray[np.float64], floor: float,
                base: NDArray[np.float64]) -> Optional[tuple[float, float, NDArray[np.float64]]]:
    """The record's gain and offset (measured = gain * chain + offset, fitted on each half
    of the part after the sweep) and its error with them cross-fitted, or None when the
    gain's evidence does not hold. ``base`` is the error the gain must beat: both halves
    agree on the gain within a quarter of its distance from 1, each half's fit shrinks
    the other half's error by a tenth against ``base``, and the gain moves the output by
    more than the floor."""
    k = swept(u)
    c = err + y  # the chain's output
    if c.size - k < 64:
        return None
    m = k + (c.size - k) // 2
    fits = []
    for s in (slice(k, m), slice(m, None)):
        a = np.column_stack([c[s], np.ones(c[s].size)])
        fits.append(np.linalg.lstsq(a, y[s], rcond=None)[0])
    (ga, oa), (gb, ob) = fits
    g, o = 0.5 * (ga + gb), 0.5 * (oa + ob)
    if abs(ga - gb) > 0.25 * max(abs(ga - 1), abs(gb - 1)) or abs(g - 1) * float(np.std(c[k:])) <= floor:
        return None
    out = g * c + o - y
    out[k:m] = gb * c[k:m] + ob - y[k:m]
    out[m:] = ga * c[m:] + oa - y[m:]
    for s in (slice(k, m), slice(m, None)):
        if rmse(out[s]) > 0.9 * rmse(base[s]):
            return None
    return g, o, out


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
