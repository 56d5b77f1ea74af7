"""The diagnosis's input records: loading (a path, a dict or a tuple), checks that name
the record at fault, and the number of input reversals."""
from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence, Union

import numpy as np
from numpy.typing import NDArray

from preisach.chain import sample_period
from preisach.diagnose.effects import Record

RecordLike = Union[str, Path, dict, tuple, list]


def load_record(x: Any, name: str) -> Record:
    """A record from a path, a dict with t, u, y or a (t, u, y) tuple; errors name it."""
    if isinstance(x, (str, Path)):
        from preisach.io import read_record

        d = read_record(x, ["t", "u", "y"])
        name = str(x)
        t, u, y = d["t"], d["u"], d["y"]
    elif isinstance(x, dict):
        missing = [k for k in "tuy" if k not in x]
        if missing:
            raise ValueError(f"{name}: missing {', '.join(missing)} (need t, u, y)")
        t, u, y = x["t"], x["u"], x["y"]
        name = str(x.get("name", name))
    elif isinstance(x, (tuple, list)) and len(x) == 3:
        t, u, y = x
    else:
        raise ValueError(f"{name}: expected a path, a dict with t, u, y or a (t, u, y) tuple")
    try:
        t, u, y = (np.asarray(v, dtype=np.float64).ravel() for v in (t, u, y))
    except (TypeError, ValueError):
        raise ValueError(f"{name}: t, u, y must be numeric arrays") from None
    if not (t.size == u.size == y.size):
        raise ValueError(f"{name}: mismatched lengths t={t.size}, u={u.size}, y={y.size}")
    if t.size < 16:
        raise ValueError(f"{name}: too short ({t.size} samples; need at least 16)")
    for k, v in (("t", t), ("u", u), ("y", y)):
        bad = ~np.isfinite(v)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"{name}: {'NaN' if np.isnan(v[i]) else 'inf'} in {k} at sample {i}")
    dt = sample_period(t, f"{name}: t")
    return Record(name, t, u, y, dt)


def holdout_list(holdouts: Any) -> Sequence[RecordLike]:
    """``holdouts`` as a list (a single record given alone is one holdout); an error when
    there is none."""
    if isinstance(holdouts, (str, Path, dict)) or (isinstance(holdouts, tuple) and len(holdouts) == 3
                                                    and not isinstance(holdouts[0], (str, Path, dict, tuple))):
        holdouts = [holdouts]
    if not holdouts:
        raise ValueError("holdouts: need at least one holdout record to score on")
    return list(holdouts)


def same(a: Record, b: Record) -> bool:
    """The same record: the same input and output samples (a copy of one file)."""
    return a.u.size == b.u.size and bool(np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y))


def check_distinct(tr: Record, hos: list[Record]) -> None:
    """A holdout that is the training record again (or another holdout again) scores a
    chain on samples it was fitted on, or counts one record twice: an error naming it.
    (Repeated records of one experiment differ in their output and are welcome.)"""
    for i, h in enumerate(hos):
        if same(h, tr):
            raise ValueError(f"{h.name}: the training record ({tr.name}) given again as a holdout "
                             f"(a holdout must be a record not used to fit)")
        for g in hos[:i]:
            if same(h, g):
                raise ValueError(f"{h.name}: the same record as {g.name} (give each holdout once)")


def reversals(u: NDArray[np.float64]) -> int:
    """The number of direction changes of ``u``."""
    d = np.diff(u)
    s = np.sign(d[d != 0])
    return int(np.sum(s[1:] != s[:-1]))
