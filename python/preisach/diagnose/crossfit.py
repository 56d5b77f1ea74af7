"""Cross-fitting on the holdouts: an effect that only the holdouts carry.

The stepwise search fits effects on the training record, so an effect the training
record does not carry (the model identified on a clean sensor channel, the loop reading
a delayed one; a mode the slow identification sine does not excite) is not found there.
Here the effect is fitted on part of the holdouts and scored on the rest; no scored
sample was used to fit the parameters it is scored with:

- a delay (``holdout_delay``): only the delay added to the chain found (masses and
  effects fixed; the chain carries the training record's own timing), fitted on the
  other holdouts (leave one out) or, with a single holdout, one half against the other,
  jointly with each fitted record's starting staircase (the memory of unrecorded
  history shows only at a record's start; a delay shifts all of it);
- any other fast effect (``holdout_halves``): its own search on half of a holdout (the
  masses profiled there; the second half from the memory and the dynamics' state the
  first leaves), then the chain found with it, masses from the training record,
  scores the other halves of every holdout; the other half likewise.
"""
from __future__ import annotations

import math
from typing import Any, Callable, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from preisach.diagnose.effects import FitState, Record, _grid_then_parabola
from preisach.diagnose.initial import Map, Start, estimate, own_memory, own_start, predictor, staircases
from preisach.diagnose.ranges import Bound, Ranges, delay_grid, search_ranges
from preisach.diagnose.registry import REGISTRY
from preisach.diagnose.search import Effects, Fitter, Trials

Errors = Callable[[FitState], list[NDArray[np.float64]]]


def _with_delay(st: FitState, extra: float) -> FitState:
    """The chain with ``extra`` seconds added to its delay (its timing delay, if any)."""
    eff = {k: dict(v) for k, v in st.effects.items()}
    d0 = float(eff.get("delay", {}).get("delay_s", 0.0))
    eff["delay"] = {"delay_s": d0 + extra}
    return FitState(st.model, eff, st.train_rmse)


def shifted(y: NDArray[np.float64], samples: float) -> NDArray[np.float64]:
    """Rows of ``y`` delayed by ``samples`` (linear interpolation, the first value held
    before the start): the chain's delay block."""
    k, f = int(math.floor(samples)), samples - math.floor(samples)
    pad = np.concatenate([np.repeat(y[:, :1], k + 1, axis=1), y], axis=1)
    n = y.shape[1]
    out: NDArray[np.float64] = (1 - f) * pad[:, 1:n + 1] + f * pad[:, :n]
    return out


def profiles(st: FitState, rec: Record, run: Map = map) -> NDArray[np.float64]:
    """The chain's output on ``rec`` without its delay: from rest (the first row) and
    from each starting staircase (``initial.staircases``; the memory of unrecorded
    history, which only the part before the input swept its range shows) that leaves a
    memory of its own at the first sample (``initial.own_memory``; the others would
    repeat an earlier row). ``run`` (a ``map``) takes the rows."""
    e = {k: v for k, v in st.effects.items() if k != "delay"}
    bare = FitState(st.model, e, st.train_rmse)
    starts = [ex for ex in staircases(bare) if own_memory(ex, float(rec.u[0]))]
    return np.array(list(run(predictor(bare, rec), [None] + starts)))


def distinct(rows: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rows without repeats, in their order (starting staircases that leave a record's
    output the same: the least error over the rows is the same)."""
    seen: set[bytes] = set()
    keep = []
    for i, r in enumerate(rows):
        b = r.tobytes()
        if b not in seen:
            seen.add(b)
            keep.append(i)
    return rows if len(keep) == rows.shape[0] else rows[keep]


def shifted_sse(rows: NDArray[np.float64], y: NDArray[np.float64], samples: float,
                sl: slice) -> NDArray[np.float64]:
    """Per row, the sum of squares of ``shifted(rows, samples)[:, sl] - y[sl]``, without
    building the shifted rows (the columns before the shift hold the first value)."""
    a, b, _ = sl.indices(y.size)
    k, f = int(math.floor(samples)), samples - math.floor(samples)
    h = min(max(k + 1, a), b)
    total = np.zeros(rows.shape[0])
    if h > a:
        e = rows[:, :1] - y[a:h]
        total += np.einsum("ij,ij->i", e, e)
    if b > h:
        cur = rows[:, h - k:b - k]
        e = cur - y[h:b]
        e += f * (rows[:, h - k - 1:b - k - 1] - cur)
        total += np.einsum("ij,ij->i", e, e)
    return total


Memo = dict[tuple[int, Optional[int], Optional[int], float], float]


def _fit_delay(st: FitState, parts: list[tuple[Record, slice]], bound: Bound,
               outs: dict[str, NDArray[np.float64]], memo: Optional[Memo] = None) -> float:
    """The added delay that fits the parts best (masses and the other effects fixed), a
    part that holds its record's start with its best starting staircase (``outs``: the
    ``profiles`` of each record; a delay shifts the whole record, the staircase only its
    start, so the two are fitted jointly): a grid (``delay_grid``) up to the bound, then
    parabolic steps. ``memo``: each part's error by record (its identity), part and
    delay, shared by fits on the same profiles (the folds of ``holdout_delay`` try the
    same grid)."""
    d0 = float(st.effects.get("delay", {}).get("delay_s", 0.0))
    hi = max(bound.hi - d0, 0.0)
    dt = min(r.dt for r, _ in parts)
    if hi <= dt:
        return 0.0
    grid = delay_grid(dt, hi)
    memo = {} if memo is None else memo

    def part_sse(r: Record, sl: slice, d: float) -> float:
        key = (id(r), sl.start, sl.stop, d)
        if key not in memo:
            start = sl.start in (None, 0)
            rows = outs[r.name] if start else outs[r.name][:1]
            memo[key] = float(np.min(shifted_sse(rows, r.y, (d0 + d) / r.dt, sl)))
        return memo[key]

    def sse(d: float) -> float:
        return sum(part_sse(r, sl, max(d, 0.0)) for r, sl in parts)

    d, _ = _grid_then_parabola(sse, grid)
    return float(min(max(d, 0.0), hi))


def holdout_delay(st: FitState, hos: list[Record], errors: Errors, bound: Bound, run: Map = map,
                  start: Optional[Start] = None, min_delay: Optional[float] = None) -> dict[str, Any]:
    """A delay only the holdouts carry, cross-fitted: the added delay fitted on the other
    holdouts (or the other half of a single one) and each holdout (half) scored with it,
    with its own starting staircase where its start carries an error of its own
    (``initial.own_start``: the start is judged apart from the delay).

    Returns ``folds`` (what was fitted on what, and the delay found), ``added_s`` (the
    delay fitted on every holdout, for the saved chain), ``state`` (the chain with it),
    ``errors`` (per holdout, cross-fitted, as ``errors`` computes them for a chain, the
    staircases applied) and ``plain`` (the same without them); with ``min_delay``, the
    last two are None when the folds are not ``consistent`` with it (no delay can be
    accepted then, and scoring the folds costs most). ``run`` (a ``map``) takes the
    chain's runs; ``start``: a chain's starting staircase on a record (default
    ``initial.estimate``)."""
    start = start or (lambda s, r: estimate(s, r, run=run))
    outs = {h.name: distinct(profiles(st, h, run)) for h in hos}
    memo: Memo = {}
    # Per fold: the parts fitted, the holdout scored, the samples of it scored, and their names.
    if len(hos) >= 2:
        plan = [([(g, slice(None)) for g in hos if g is not h], i, slice(None), [g.name for g in hos if g is not h],
                 h.name) for i, h in enumerate(hos)]
    else:
        h, hv = hos[0], halves(hos[0])
        plan = [([(h, hv[k])], 0, hv[1 - k], [half_name(h, k)], half_name(h, 1 - k)) for k in (0, 1)]
    folds: list[dict[str, Any]] = [{"fit": fit, "score": score, "added_s": _fit_delay(st, parts, bound, outs, memo)}
                                   for parts, _, _, fit, score in plan]
    added = _fit_delay(st, [(h, slice(None)) for h in hos], bound, outs, memo)
    out: dict[str, Any] = {"folds": folds, "added_s": added, "state": _with_delay(st, added), "errors": None,
                           "plain": None}
    if min_delay is not None and not consistent(folds, min_delay):
        return out
    out["errors"] = [np.empty(h.y.size) for h in hos]
    out["plain"] = [np.empty(h.y.size) for h in hos]
    for (_, i, sl, _, _), f in zip(plan, folds):
        sd = _with_delay(st, f["added_s"])
        e = errors(sd)[i]
        out["plain"][i][sl] = e[sl]
        out["errors"][i][sl] = own_start(sd, hos[i], e, start(sd, hos[i]), run)[0][sl]
    return out


def consistent(folds: list[dict[str, Any]], min_delay: float) -> bool:
    """Every fold found a delay longer than ``min_delay``, within 25 % of each other (a
    channel's delay is the same on every record it reads)."""
    ds = [float(f["added_s"]) for f in folds]
    return min(ds) > min_delay and max(ds) <= 1.25 * min(ds)


# -- any effect, on halves of the holdouts ----------------------------------------------
HALF = ("first", "second")


def halves(rec: Record) -> tuple[slice, slice]:
    """The samples of a record's first and second halves."""
    m = rec.y.size // 2
    return slice(0, m), slice(m, None)


def half_name(rec: Record, k: int) -> str:
    """The name of a record's first (``k`` = 0) or second half."""
    return f"{rec.name} {HALF[k]} half"


def half(rec: Record, k: int) -> Record:
    """The first (``k`` = 0) or second half of a record, as a record of its own."""
    sl = halves(rec)[k]
    return Record(half_name(rec, k), rec.t[sl], rec.u[sl], rec.y[sl], rec.dt)


def fit_on(rec: Record, st: FitState, name: str, u_range: tuple[float, float], search_rate_hz: float,
           trials: Trials, k: Optional[int] = None, rest: bool = False) -> tuple[Effects, Ranges, float]:
    """The chain ``st`` plus effect ``name``, searched on ``rec`` (window averages down to
    about ``search_rate_hz``; the masses profiled on it, a mode's band fit behind the
    chain's own masses), the ranges searched (from the part fitted) and the share of the
    profiled error there the effect removes (how clearly it shows it). ``k``: on that half
    of ``rec`` only (``half``; the second run on from the hysteresis memory and the
    dynamics' state the first leaves, not from rest). ``rest``: ``rec`` starts with a step
    from rest (its transient fitted with the masses, ``preisach.diagnose.rest``)."""
    stride = max(1, int(round(1.0 / (rec.dt * search_rate_hz))))
    part = rec if k is None else half(rec, k)
    ranges = search_ranges(part.u, rec.dt, float(part.t[-1] - part.t[0]), rec.dt * stride)
    f = Fitter(rec if k == 1 else part, st.model.n_h, u_range, stride, trials=trials, ranges=ranges,
               start=halves(rec)[1].start if k == 1 else 0)
    f.rest = rest and k != 1
    with trials.search():
        eff = REGISTRY[name].fit(f, st.effects, f.hysteresis(st.model, {}))
        j0 = f.J(st.effects)
    return eff, f.ranges, (j0 - f.J(eff)) / j0 if j0 > 0 else 0.0


def with_effect(train: Fitter, st: FitState, eff: Effects) -> tuple[FitState, str]:
    """The chain ``st`` with the fast effects of ``eff`` (fitted elsewhere) and its own
    slow ones: the training masses kept, or refitted on the training record with the
    effects fixed when that fits it better (the masses absorb the effect there too).
    Returns the chain and which masses it has."""
    e = {k: dict(v) for k, v in eff.items() if not (k in REGISTRY and REGISTRY[k].slow)}
    e.update({k: dict(v) for k, v in st.effects.items() if k in REGISTRY and REGISTRY[k].slow})
    if train.J(e) < train.J(st.effects):
        return train.state(e, n_h=st.model.n_h), "refitted on the training record with the effect fixed"
    return FitState(st.model, e, st.train_rmse), "the training record's"


def agree(name: str, params: list[dict[str, Any]]) -> bool:
    """The folds found the same effect: its leading scalar within the registry's
    tolerance of each other."""
    key, tol = REGISTRY[name].agree
    v = [float(p[key]) for p in params]
    return min(v) > 0 and max(v) <= (1 + tol) * min(v)


HalfFits = dict[tuple[str, int, int], tuple[Effects, Ranges, float]]


def half_fits(st: FitState, names: list[str], hos: list[Record], u_range: tuple[float, float],
              search_rate_hz: float, trials: Trials, run: Callable[..., Any] = map,
              rests: Sequence[bool] = (), halves: Sequence[int] = (0, 1)) -> HalfFits:
    """Every effect of ``names`` fitted on every half of every holdout (``fit_on``), by
    (effect, half, holdout); the fits are independent, and ``run`` (a ``map``: a thread
    pool's runs them side by side) takes them in the order of ``names``. ``rests``: per
    holdout, whether it starts with a step from rest (its first half is fitted with the
    transient). ``halves``: which (0: the first, 1: the second)."""
    keys = [(c, k, i) for c in names for k in halves for i in range(len(hos))]
    fits = run(lambda key: fit_on(hos[key[2]], st, key[0], u_range, search_rate_hz, trials, key[1],
                                  key[2] < len(rests) and rests[key[2]]), keys)
    return dict(zip(keys, fits))


def fold(st: FitState, name: str, hos: list[Record], errors: Errors, train: Fitter, fits: HalfFits,
         k: int) -> tuple[dict[str, Any], list[NDArray[np.float64]]]:
    """Effect ``name``'s fold on the holdouts' ``k``-th halves (0: first, 1: second): the
    fit (``half_fits``) on the one it explains most of (where the effect shows), the chain
    found with it (``with_effect``), and that chain's errors on every holdout's other
    half (never on a sample it was fitted on). Returns the fold (what was fitted on what,
    the parameters found and the masses used; ``_state``, ``_ranges``, ``_gain``,
    ``_record`` internal) and the errors, per holdout."""
    on = [fits[(name, k, i)] for i in range(len(hos))]
    i = int(np.argmax([g for _, _, g in on]))
    eff, rg, g = on[i]
    sk, masses = with_effect(train, st, eff)
    scored = [e[halves(h)[1 - k]] for e, h in zip(errors(sk), hos)]
    return ({"fit": half_name(hos[i], k), "score": [half_name(h, 1 - k) for h in hos],
             "params": {kk: v for kk, v in sk.effects[name].items() if not kk.startswith("_")},
             "masses": masses, "explained_on_fit": g, "_state": sk, "_ranges": rg, "_gain": g, "_record": hos[i]},
            scored)


def holdout_halves(st: FitState, name: str, hos: list[Record], errors: Errors, train: Fitter,
                   search_rate_hz: float, trials: Trials, fits: Optional[HalfFits] = None,
                   rests: Sequence[bool] = (), first: Optional[tuple[dict[str, Any], list[Any]]] = None
                   ) -> dict[str, Any]:
    """Effect ``name`` cross-fitted on the holdouts' halves: its fold on the first halves
    and its fold on the second (``fold``), each scoring every holdout's other half.

    Returns ``errors`` (per holdout, each half scored with the effect fitted on a first
    or second half: never on itself), ``folds`` (``fold``'s) and ``target`` (the holdout
    the effect shows most on). ``fits``: the fits on the halves (``half_fits``, with
    ``rests``), made here when not given; ``first``: the fold on the first halves, when
    already made."""
    if fits is None or any((name, k, 0) not in fits for k in (0, 1)):
        fits = half_fits(st, [name], hos, train.u_range, search_rate_hz, trials, rests=rests)
    folds = [first if first is not None else fold(st, name, hos, errors, train, fits, 0),
             fold(st, name, hos, errors, train, fits, 1)]
    # The first halves' fold scored the second halves, and the other way round.
    out = [np.concatenate([e1, e0]) for e0, e1 in zip(folds[0][1], folds[1][1])]
    target = max(folds, key=lambda f: f[0]["_gain"])[0]["_record"]
    return {"errors": out, "folds": [f for f, _ in folds], "target": target}


def saved_fit(st: FitState, name: str, rec: Record, train: Fitter, search_rate_hz: float,
              trials: Trials, rest: bool = False) -> tuple[FitState, str]:
    """The chain to keep: effect ``name`` fitted on the whole of ``rec`` (``rest``: it
    starts with a step from rest)."""
    eff, _, _ = fit_on(rec, st, name, train.u_range, search_rate_hz, trials, rest=rest)
    return with_effect(train, st, eff)
