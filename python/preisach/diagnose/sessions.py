"""An output offset that differs between records (sessions: a sensor's offset moves
between power cycles), under ``drift``, with a value per record.

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


def offsets(errs: list[NDArray[np.float64]], inputs: list[NDArray[np.float64]], names: list[str],
            floor: float) -> tuple[dict[str, float], list[NDArray[np.float64]]]:
    """Per-record offsets (by name, only where the evidence holds) and every record's
    error with them cross-fitted (unchanged where none was accepted)."""
    found: dict[str, float] = {}
    out = []
    for e, u, n in zip(errs, inputs, names):
        got = record_offset(e, u, floor)
        if got is None:
            out.append(e)
        else:
            found[n] = got[0]
            out.append(got[1])
    return found, out
