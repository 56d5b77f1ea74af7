"""The diagnosis in steps (``docs/method/diagnosis.md``).

``prepare`` loads the records and fits the baseline and the fitters; ``reference`` the
chain the search starts from and what a finer hysteresis alone achieves; ``where`` the
floors and the residual's localization; ``search`` the stepwise rounds (``fit_round``
fits every candidate, ``accept`` picks one, ``eliminate`` drops one it made redundant);
``refine`` the chain found at the finer average and the discretization check; then the
effects fitted on the holdouts (``holdout_effects``, :mod:`preisach.diagnose.crossfit`)
and each record's ``initial_state``; :mod:`preisach.diagnose.reporting` writes the
report. Each step reads the :class:`Run` and moves the :class:`Found` chain.
"""
from __future__ import annotations

import functools
import math
import threading
import time
import warnings
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional, Sequence, Union

import numpy as np

from preisach.chain import Chain, load
from preisach.diagnose import crossfit as cf
from preisach.diagnose import kept, lag, rest, sessions, slowpair
from preisach.diagnose.crossfit import holdout_delay
from preisach.diagnose.effects import CANDIDATES, FitState, Record, rmse
from preisach.diagnose.initial import Starts, own_start
from preisach.diagnose.ranges import Ranges, ends_at_bound
from preisach.diagnose.records import RecordLike, check_distinct, holdout_list, load_record, reversals
from preisach.diagnose.registry import OWN_STEPS, REGISTRY, SLOW_FIRST, Scale, trivial
from preisach.diagnose.search import Effects, Fitter, Trials, calibrate_slow, less, slow_predict
from preisach.diagnose.where import localize, noise_floor, repeatability_floor, signatures
from preisach.model import PreisachModel, PreisachWarning

Errors = list[np.ndarray]
#: How many chains' holdout errors a run keeps.
ERRORS_KEPT = 4


@dataclass
class Baseline:
    """The "before": the model fitted on the training record (or the one given), the
    effects of a given chain that is refitted with them, and its errors."""

    model: PreisachModel
    effects: Effects
    given: Optional[dict[str, Any]]
    chain: Optional[Union[PreisachModel, Chain]]
    #: A simulator kept as it is (any chain that is not a model followed by effects).
    kept: Optional[Chain] = None
    residuals: dict[str, np.ndarray] = field(default_factory=dict)
    rmse: dict[str, float] = field(default_factory=dict)
    holdout_rmse: float = float("nan")

    def predict(self, r: Record) -> np.ndarray:
        if isinstance(self.chain, Chain):
            return self.chain.predict(r.t, r.u)
        return (self.chain or self.model).predict(r.u)


@dataclass
class Run:
    """What every step reads: the records, the baseline, the fitters (candidates on the
    coarser average, the chain found on the finer one) and the scoring on the holdouts."""

    tr: Record
    hos: list[Record]
    n_h: int
    candidates: Sequence[str]
    min_shrink: float
    trials: Trials
    say: Callable[[str], None]
    base: Baseline
    fitter: Fitter
    fine: Fitter
    stride: int
    sstride: int
    search_rate_hz: float = 12.5e3
    #: With a kept simulator: the records as given (``tr`` and ``hos`` then carry the
    #: simulator's output as their input), and how its masses were treated.
    original: Optional[list[Record]] = None
    masses: str = ""
    #: Each chain's starting staircase on each holdout, estimated once.
    starts: Starts = field(init=False)

    def __post_init__(self) -> None:
        self.starts = Starts(self.trials.map)
        #: The last chains' holdout errors, by the chain's JSON text (the steps after the
        #: search score the chain found several times).
        self._errors: dict[str, Errors] = {}
        self._lock = threading.Lock()

    @property
    def recs(self) -> list[Record]:
        return [self.tr] + self.hos

    @property
    def given_recs(self) -> list[Record]:
        return self.original if self.original is not None else self.recs

    @property
    def halves(self) -> list[tuple[slice, slice]]:
        return [cf.halves(h) for h in self.hos]

    @property
    def slow_folds(self) -> list[list[tuple[Record, slice]]]:
        """The two folds' data: the training record whole and one half of each holdout."""
        return [[(self.tr, slice(None))] + [(h, hv[k]) for h, hv in zip(self.hos, self.halves)] for k in (0, 1)]

    def on_every_record(self, st: FitState) -> FitState:
        """``st`` with its slow effects calibrated on every record whole (the saved chain's)."""
        return calibrate_slow(st, [(r, slice(None)) for r in self.recs])

    def at_bound(self, c: str, st: FitState) -> list[str]:
        """The parameters of effect ``c`` in ``st`` that ended at a search bound (none when
        ``st`` has no ``c``)."""
        return ends_at_bound(c, st.effects[c], self.fitter.ranges) if c in st.effects else []

    def holdout_errors(self, st: FitState) -> Errors:
        """Errors on each holdout. A chain with drift or creep has them recalibrated
        across records for each half of the holdouts, from the training record and the
        other halves (cross-fitting; see ``calibrate_slow``). The last chains' are kept
        (copies are returned)."""
        key = Chain(st.model, st.effects).to_json()
        with self._lock:
            got = self._errors.get(key)
        if got is None:
            got = self._holdout_errors(st)
            with self._lock:
                if len(self._errors) >= ERRORS_KEPT:
                    del self._errors[next(iter(self._errors))]
                self._errors[key] = got
        return [e.copy() for e in got]

    def _holdout_errors(self, st: FitState) -> Errors:
        if "drift" not in st.effects and "creep" not in st.effects:
            return self.rest_removed(st, [st.predict(h) - h.y for h in self.hos])
        errs = [np.empty(h.y.size) for h in self.hos]
        outputs: dict[Any, Any] = {}
        halves, folds = self.halves, self.slow_folds
        for k in (0, 1):
            cal = calibrate_slow(st, folds[1 - k], outputs)
            for e, h, hv in zip(errs, self.hos, halves):
                e[hv[k]] = (slow_predict(cal, h, outputs) - h.y)[hv[k]]
        return self.rest_removed(st, errs)

    def other_records_errors(self, st: FitState) -> Errors:
        """Errors on each holdout with the chain's slow effects calibrated on the other
        records only (the training record and the other holdouts, whole): what a trend
        through absolute time predicts for a record it never saw."""
        outputs: dict[int, np.ndarray] = {}
        errs = []
        for h in self.hos:
            others = [(r, slice(None)) for r in self.recs if r is not h]
            errs.append(slow_predict(calibrate_slow(st, others, outputs), h, outputs) - h.y)
        return self.rest_removed(st, errs)

    def rest_removed(self, st: FitState, errs: Errors) -> Errors:
        """A holdout that starts with a step from rest: the chain's transient removed
        (``preisach.diagnose.rest``)."""
        return [rest.remove(st, h, e)[0] for h, e in zip(self.hos, errs)]

    def parts_of(self, es: Errors) -> tuple[float, np.ndarray]:
        """RMSE overall and on each half of each holdout."""
        parts = []
        for e, hv in zip(es, self.halves):
            parts += [rmse(e[hv[0]]), rmse(e[hv[1]])]
        return rmse(np.concatenate(es)), np.array(parts)

    def score_parts(self, st: FitState) -> tuple[float, np.ndarray]:
        """Holdout RMSE overall and on each half of each holdout (the acceptance rule
        asks an effect to help on every part, not just on average)."""
        return self.parts_of(self.holdout_errors(st))

    def score(self, st: FitState) -> float:
        return self.score_parts(st)[0]


@dataclass
class Floors:
    """The bar an effect must beat: the noise floor (on the records, and on the fit's
    averaged training record), the repeatability floor, what a finer hysteresis alone
    achieves (``hyst_alone``, at ``nh2``), and the interpolated reference's score."""

    noise: float
    noise_fit: float
    repeatability: Optional[float]
    ref_score: float
    #: ``hyst_alone``'s fit, waited for when first needed (it runs beside the first round).
    alone: Callable[[], float]
    nh2: int
    scale: Scale

    @property
    def accept(self) -> float:
        return max(self.noise, self.repeatability or 0.0)

    @property
    def hyst_alone(self) -> float:
        return self.alone()


@dataclass
class Found:
    """The chain as the search moves it: its state, holdout score and parts, every
    candidate tried (``tried``: name -> what the report needs) and the effects kept."""

    cur: FitState
    score: float
    parts: np.ndarray
    tried: dict[str, dict[str, Any]] = field(default_factory=dict)
    accepted: list[str] = field(default_factory=list)
    cross_fit: dict[str, Any] = field(default_factory=dict)
    #: Per holdout: its session's output offset (``drift``'s ``record_offsets``).
    record_offsets: dict[str, float] = field(default_factory=dict)
    #: Per holdout: its session's output gain against the training record's, where one shows.
    record_gains: dict[str, float] = field(default_factory=dict)
    #: Per record that starts with a step from rest: ``rest_input`` and ``rest_step``.
    rests: dict[str, dict[str, float]] = field(default_factory=dict)

    def move(self, st: FitState, score: float, parts: np.ndarray) -> None:
        self.cur, self.score, self.parts = st, score, parts


def gain(before: float, after: float) -> float:
    """The fraction of ``before`` that ``after`` removes."""
    return (before - after) / before if before > 0 else 0.0


# -- prepare ---------------------------------------------------------------------------
def _refittable(b: Union[PreisachModel, Chain]) -> Optional[tuple[PreisachModel, Effects]]:
    """A baseline's model and effects when it is an identified model followed by effects
    the search knows (else None: it can only be the "before")."""
    if isinstance(b, PreisachModel):
        return b, {}
    model = b.model
    if model is None or b.kinds()[0] != "hysteresis" or b.initial_input is not None:
        return None
    try:
        effects = b.effects
    except ValueError:
        return None
    if any(k not in CANDIDATES or "modes" in p for k, p in effects.items()):
        return None
    return model, {k: dict(v) for k, v in effects.items()}


def load_inputs(train: RecordLike, holdouts: Sequence[RecordLike],
                candidates: Sequence[str]) -> tuple[Record, list[Record]]:
    """The records, checked: known candidates, distinct holdouts, a training input with
    reversals."""
    holdouts = holdout_list(holdouts)
    unknown = [c for c in candidates if c not in CANDIDATES + OWN_STEPS]
    if unknown:
        raise ValueError(f"candidates: unknown effect(s) {', '.join(unknown)}")
    tr = load_record(train, "train")
    hos = [load_record(h, f"holdout {i + 1}") for i, h in enumerate(holdouts)]
    check_distinct(tr, hos)
    if reversals(tr.u) < 2:
        raise ValueError(f"{tr.name}: the input has no reversals (a monotone input cannot identify hysteresis)")
    return tr, hos


def fit_baseline(tr: Record, hos: list[Record], n_h: int,
                 baseline: Optional[Union[str, Path, Chain, PreisachModel]]) -> Baseline:
    """The baseline, exactly as ``preisach identify`` makes it, or the given one: a
    model, or a model followed by effects, is refitted with its effects; any other chain
    (a simulated stage) is the "before" only, and the search starts from a fitted model."""
    given: Optional[dict[str, Any]] = None
    bch: Optional[Union[PreisachModel, Chain]] = None
    refit = None
    if baseline is not None:
        bch = baseline if isinstance(baseline, (Chain, PreisachModel)) else load(baseline)
        refit = _refittable(bch)
        kinds = ["hysteresis"] if isinstance(bch, PreisachModel) else bch.kinds()
        given = {"blocks": kinds, "refitted": refit is not None}
    if refit is not None:
        model, effects = refit
    else:
        effects = {}
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = PreisachModel.fit(tr.u, tr.y, n_h)
    b = Baseline(model, effects, given, bch, bch if isinstance(bch, Chain) and refit is None else None)
    for r in [tr] + hos:
        b.residuals[r.name] = r.y - b.predict(r)
        b.rmse[r.name] = rmse(b.residuals[r.name])
    b.holdout_rmse = rmse(np.concatenate([b.residuals[h.name] for h in hos]))
    return b


def make_fitters(tr: Record, n_h: int, fit_rate_hz: float, search_rate_hz: float,
                 trials: Trials) -> tuple[Fitter, Fitter, int, int]:
    """The fitters of the candidate chains (windows averaged down to about
    ``search_rate_hz``) and of the chain found (about ``fit_rate_hz``).

    The average commutes with the dynamics and keeps the timing of input steps (point
    decimation would bias every timing). The model range is a little wider than the
    training input (5 % of its span each side): no sample saturates the model, which
    otherwise biases the effect parameters (creep most) that compensate the flat output
    beyond the range."""
    u_lo, u_hi = float(np.min(tr.u)), float(np.max(tr.u))
    pad = 0.05 * (u_hi - u_lo)
    rng = (u_lo - pad, u_hi + pad)
    stride = max(1, int(round(1.0 / (tr.dt * fit_rate_hz))))
    sstride = max(stride, int(round(1.0 / (tr.dt * min(search_rate_hz, fit_rate_hz)))))
    fitter = Fitter(tr, n_h, rng, sstride, trials=trials)
    fine = Fitter(tr, n_h, rng, stride, trials=trials) if stride != sstride else fitter
    if tr.u.size // (4 * sstride) >= 4000:
        # The slow effects' own searches on windows 4x longer (about 3 kHz).
        fitter.slow = Fitter(tr, n_h, rng, 4 * sstride, trials=trials)
    return fitter, fine, stride, sstride


def kept_run(tr: Record, hos: list[Record], n_h: int, candidates: Sequence[str], min_shrink: float,
             trials: Trials, say: Callable[[str], None], base: Baseline, fit_rate_hz: float,
             search_rate_hz: float, refit_masses: bool) -> Run:
    """The run behind a kept simulator (``preisach.diagnose.kept``): the records with its
    output as input, an identity hysteresis fixed in front of the candidates, the
    candidates its chain can carry. With ``refit_masses`` the simulator's hysteresis
    masses are refitted on the training record first."""
    assert base.kept is not None
    masses = "as given"
    if refit_masses:
        base.kept = kept.refitted(base.kept, tr, n_h, fit_rate_hz)
        masses = "refitted on the training record (every other block as given)"
    recs, (lo, hi) = kept.through(base.kept, [tr] + hos)
    ident = kept.identity(lo, hi, n_h)
    stride = max(1, int(round(1.0 / (tr.dt * fit_rate_hz))))
    sstride = max(stride, int(round(1.0 / (tr.dt * min(search_rate_hz, fit_rate_hz)))))
    fitter = kept.KeptFitter(recs[0], ident, sstride, trials)
    fine = kept.KeptFitter(recs[0], ident, stride, trials) if stride != sstride else fitter
    names = [c for c in candidates if c in kept.KEPT_CANDIDATES]
    say(f"the given chain ({' -> '.join(base.kept.kinds())}) kept as it is; masses {masses}")
    return Run(recs[0], recs[1:], n_h, tuple(names), min_shrink, trials, say, base, fitter, fine, stride, sstride,
               search_rate_hz, [tr] + hos, masses)


# -- reference and where ---------------------------------------------------------------
def reference(run: Run, ex: Executor) -> tuple[Found, Callable[[], float], int]:
    """The chain the search starts from (the interpolated model, with a given chain's
    effects polished), its score, and what a finer hysteresis alone achieves (an effect
    is detected only when its chain beats it as well as the interpolated one): fitted on
    a fitter of its own in ``ex`` beside the reference and what follows; its score is the
    function returned (it waits for the fit)."""
    fitter = run.fitter
    cur_eff: Effects = {k: dict(v) for k, v in run.base.effects.items()}
    if cur_eff:
        cur_eff, _ = fitter.polish(cur_eff, list(cur_eff), sweeps=2)
        cur_eff = fitter.with_linear(cur_eff)
    nh2 = min(2 * run.n_h, max(run.n_h, reversals(run.tr.u) // 2), 120)
    fut = ex.submit(_alone, run, cur_eff, nh2) if nh2 > run.n_h else None
    ref = fitter.state(cur_eff)
    ref_score, ref_parts = run.score_parts(ref)
    run.say(f"reference (interpolated) holdout RMSE {ref_score:.4g} (baseline {run.base.holdout_rmse:.4g})")

    @functools.cache
    def alone() -> float:
        if fut is None:
            return ref_score
        hyst_alone = min(ref_score, fut.result())
        run.say(f"finer hysteresis alone (n_h={nh2}): holdout RMSE {hyst_alone:.4g}")
        return hyst_alone
    return Found(ref, ref_score, ref_parts), alone, nh2


def _alone(run: Run, eff: Effects, nh2: int) -> float:
    """The holdout score of the chain with effects ``eff`` and a finer hysteresis (``nh2``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PreisachWarning)
        return run.score(run.fitter.state(eff, n_h=nh2))


def where(run: Run, found: Found, alone: Callable[[], float],
          nh2: int) -> tuple[Floors, list[dict[str, Any]], dict[str, Any]]:
    """The floors, the residual's localization on every record and its signatures
    (``alone``: what a finer hysteresis alone achieves, waited for when first needed)."""
    ref, recs = found.cur, run.recs
    outs = [ref.predict(r) for r in recs]
    floor = float(np.median([noise_floor(r.y - h) for r, h in zip(recs, outs)]))
    floor_j = noise_floor(run.fitter.y - run.fitter.predict(ref)) ** 2
    loc = _localized(run, {})
    sig = {r.name: signatures(r.t, r.u, h, r.y - h, r.dt) for r, h in zip(recs, outs)}
    # The floor an effect must beat: the noise, or the difference between repeated records
    # where there are any (what no chain fitted on one record can come below).
    rep_floor = repeatability_floor([(r.u, r.y) for r in recs])
    run.say(f"where: noise floor {floor:.3g}, repeatability floor "
            f"{'(no repeated records)' if rep_floor is None else f'{rep_floor:.3g}'}, "
            f"residual localized on {len(recs)} records")
    t_all = np.concatenate([r.t for r in recs])
    scale = Scale(2.0 * min(r.dt for r in recs), run.fitter.dt, run.tr, float(t_all.max() - t_all.min()), floor)
    for f in (run.fitter, run.fine, run.fitter.slow):
        if f is not None:
            f.min_delay = scale.min_delay  # the record's timing fits below it (``Fitter.timing``)
    return Floors(floor, floor_j, rep_floor, found.score, alone, nh2, scale), loc, sig


# -- search ----------------------------------------------------------------------------
Result = tuple[FitState, float, np.ndarray, float]


def fit_round(run: Run, found: Found, fl: Floors, todo: list[str], rnd: int) -> dict[str, Result]:
    """Every candidate in ``todo`` added to the current chain and fitted on the training
    record, two at a time (the core releases the GIL), the slow ones first; recorded in
    ``found.tried``."""
    fitter, trials = run.fitter, run.trials
    j_cur = fitter.J(found.cur.effects)

    plain: dict[str, tuple[float, np.ndarray]] = {}

    def one(c: str, base: Effects = found.cur.effects) -> tuple[str, FitState, float, np.ndarray, float, float]:
        t0 = time.perf_counter()
        held = Held(run, fitter)
        with trials.search():
            eff = REGISTRY[c].fit(fitter, base, held=held)
            if run.hos and slowpair.applies(base, c):
                eff, held = slow_pair(run, fl, c, eff, j_cur)
            st = fitter.state(eff)
        sc, parts = run.score_parts(st)
        if held.seen:
            # The search chose on the holdouts: judged by the chains chosen on the other halves.
            plain[c] = (sc, parts)
            sc, parts = held.cross_fitted()
        return c, st, sc, parts, fitter.J(eff), time.perf_counter() - t0

    todo = sorted(todo, key=lambda c: SLOW_FIRST.index(c) if c in SLOW_FIRST else len(SLOW_FIRST))
    results: dict[str, Result] = {}
    with warnings.catch_warnings(), trials.tasks(min(trials.workers, len(todo))) as ex:
        warnings.simplefilter("ignore", PreisachWarning)
        for c, st, sc, parts, jc, el in ex.map(one, todo):
            results[c] = (st, sc, parts, jc)
            tg = (j_cur - jc) / max(j_cur - fl.noise_fit, 1e-300)
            run.say(f"round {rnd + 1}: + {c:10s} holdout RMSE {sc:.4g}, training {math.sqrt(jc):.4g} "
                    f"({100 * tg:.0f} % of the excess) ({el:.1f} s)")
    results = {c: results[c] for c in run.candidates if c in results}
    for c, (st, sc, _, jc) in results.items():
        found.tried[c] = {"state": st, "rmse_after": sc, "rmse_current": found.score,
                          "score": gain(found.score, sc), "round": rnd + 1,
                          "train_gain": (j_cur - jc) / max(j_cur - fl.noise_fit, 1e-300)}
        if c in plain:
            found.tried[c]["plain"] = plain[c]
    return results


def slow_pair(run: Run, fl: Floors, c: str, eff: Effects, j_cur: float) -> tuple[Effects, Held]:
    """Candidate ``c`` (its own fit ``eff``) completing creep beside a drift: the pair
    fitted across records (:mod:`preisach.diagnose.slowpair`) among the chains that fit
    the training record within ``slowpair.TRAIN_SLACK`` of the chain's (MSE ``j_cur``),
    judged among its own chains (not the probes of creep's grid)."""
    fitter = run.fitter
    held = Held(run, fitter)
    j_max = j_cur + slowpair.TRAIN_SLACK * max(j_cur - fl.noise_fit, 0.0)
    eff = slowpair.best(fitter, eff, c, run.slow_folds, held, lambda e: run.score(fitter.state(e)),
                        run.trials, j_max, run.min_shrink)
    return eff, held


class Held:
    """A chain's holdout RMSE, for a search that chooses among chains on the holdouts
    (creep's time constant); it remembers every chain's parts (each half of each holdout)
    so that the choice is judged cross-fitted: each half scored by the chain chosen on the
    other halves."""

    def __init__(self, run: Run, fitter: Fitter) -> None:
        self.run, self.fitter = run, fitter
        self.seen: list[np.ndarray] = []
        n = [(len(range(*a.indices(h.y.size))), len(range(*b.indices(h.y.size))))
             for h, (a, b) in zip(run.hos, run.halves)]
        self.sizes = np.array([k for pair in n for k in pair], dtype=np.float64)

    def __call__(self, eff: Effects) -> float:
        sc, parts = self.run.score_parts(self.fitter.state(eff))
        self.seen.append(parts)
        return sc

    def _rmse(self, parts: np.ndarray, sel: slice) -> float:
        w = self.sizes[sel]
        return float(np.sqrt(np.sum(w * parts[sel] ** 2) / np.sum(w)))

    def cross_fitted(self) -> tuple[float, np.ndarray]:
        """The holdout RMSE and parts when the first halves are scored by the chain that
        scored best on the second halves, and the other way round."""
        seen = np.array(self.seen)
        on_first = int(np.argmin([self._rmse(p, slice(0, None, 2)) for p in seen]))
        on_second = int(np.argmin([self._rmse(p, slice(1, None, 2)) for p in seen]))
        parts = seen[on_first].copy()
        parts[0::2] = seen[on_second][0::2]
        return self._rmse(parts, slice(None)), parts


def passes(run: Run, fl: Floors, before: float, after: float) -> bool:
    """The rule every candidate's gain meets: ``after`` shrinks ``before`` by
    ``min_shrink`` and by more than half the floor (noise or repeatability)."""
    return gain(before, after) >= run.min_shrink and before - after >= 0.5 * fl.accept


def beats_floors(run: Run, fl: Floors, before: float, after: float) -> bool:
    """``passes``, and ``after`` below what the finer hysteresis alone achieves: the rule
    of the effects judged on the holdouts after the search."""
    return passes(run, fl, before, after) and after < fl.hyst_alone


def held_out_evidence(run: Run, found: Found, fl: Floors, c: str, st: FitState, sc: float,
                      rival: Optional[float]) -> Optional[str]:
    """Why candidate ``c`` fails the held-out evidence of its kind (``registry``), or
    None: a trend across records (``across_records``) must shrink each holdout's error
    when calibrated on the other records only; an effect that acts as a lag
    (``beats_delay``) must beat the chain with a delay in its place by the candidates'
    rule (``rival``: the holdout RMSE of the round's delay)."""
    e = REGISTRY[c]
    if e.across_records:
        sc_o = rmse(np.concatenate(run.other_records_errors(st)))
        run.say(f"{c} calibrated on the other records: holdout RMSE {sc_o:.4g} (without: {found.score:.4g})")
        if not passes(run, fl, found.score, sc_o):
            return "no gain on a record it was not calibrated on (the other records' trend)"
    if e.beats_delay and rival is not None and not passes(run, fl, rival, sc):
        return f"no better than a delay in its place (holdout RMSE {rival:.4g})"
    return None


def refusal(run: Run, found: Found, fl: Floors, c: str, res: Result, rnd: int,
            rival: Optional[float] = None) -> Optional[str]:
    """Why candidate ``c`` (its chain fitted in round ``rnd``) is not accepted, or None."""
    st, sc, parts, _ = res
    g = gain(found.score, sc)
    strong = found.tried[c]["train_gain"] >= 0.5
    if found.score - sc < 0.5 * fl.accept:
        return "improvement below half the noise (or repeatability) floor"
    if sc >= fl.hyst_alone:
        return "no better than a finer hysteresis alone"
    pair = slowpair.applies(found.cur.effects, c)
    if found.tried[c]["train_gain"] <= (-slowpair.TRAIN_SLACK if pair else 0.0):
        return "it does not fit the training record better"
    if rnd > 0 and not strong and np.any(parts > found.parts * 1.05 + 1e-12) \
            and not (REGISTRY[c].slow and g >= 2 * run.min_shrink):
        # (A slow effect's parameters are calibrated on the holdouts' other halves,
        # which moves error between the halves; a large gain counts for it.)
        return "worsens part of a holdout"
    if trivial(c, st.effects[c], fl.scale):
        return "trivial parameters"
    if bounds := run.at_bound(c, st):
        return "at its search bound: " + "; ".join(bounds)
    if pair and (bounds := run.at_bound(c, run.on_every_record(st))):
        # The pair is chosen across records and saved calibrated on every record, so it
        # must hold within its ranges there too (a creep of ten record lengths at the
        # largest amplitude stands in for the records' own levels, a session's offset).
        return "at its search bound once calibrated on every record: " + "; ".join(bounds)
    if c == "lowpass" and lag.is_timing(run.score, st, sc, run.min_shrink, fl.accept, fl.scale.min_delay):
        return lag.TIMING
    return held_out_evidence(run, found, fl, c, st, sc, rival)


def accept(run: Run, found: Found, fl: Floors, results: dict[str, Result], rnd: int) -> Optional[str]:
    """The candidate accepted in round ``rnd``, or None; moves the chain to it.

    The best candidate that shrinks the holdout RMSE by ``min_shrink`` and by more than
    half the floor, fits the training record better (a chain that fits it worse only
    trades errors between records), after the first round worsens no half of a holdout
    by more than 5 %, and has non-trivial parameters. A candidate that explains most of
    the training error above the noise (``strong``) also counts with a smaller holdout
    gain, and goes first: the training record is where parameters are identified, and a
    slow effect (drift, creep) is identified better once the fast ones are in the chain."""
    passing = []
    for c in sorted(results, key=lambda c: results[c][1]):
        sc = results[c][1]
        g = gain(found.score, sc)
        strong = found.tried[c]["train_gain"] >= 0.5
        if g < run.min_shrink and not (strong and g >= 0.25 * run.min_shrink):
            continue
        why = refusal(run, found, fl, c, results[c], rnd, results["delay"][1] if "delay" in results else None)
        if why is None:
            passing.append((not strong, sc, c))
        else:
            found.tried[c]["refused"] = why
            run.say(f"round {rnd + 1}: {c} refused ({why})")
    if not passing:
        return None
    best = min(passing)[2]
    found.accepted.append(best)
    found.move(*results[best][:3])
    if "plain" in found.tried[best]:
        # Judged cross-fitted; the chain goes on with its own score (what later
        # candidates, added to it, are scored like).
        found.score, found.parts = found.tried[best]["plain"]
    accept_pairs(run, found, fl, best)
    run.say(f"round {rnd + 1}: accepted {best}: holdout RMSE {found.score:.4g}")
    return best


def accept_pairs(run: Run, found: Found, fl: Floors, best: str) -> None:
    """The effects fitted with ``best`` as a pair (a mode whose ringing needed a delay)
    that are real ones of their kind are accepted with it; an accepted effect its fit
    replaced (a low-pass that stood in for the lag a mode's fit gave to a delay), or left
    trivial (a delay whose lag a low-pass took), is dropped. A low-pass fitted with it
    that is not accepted (at a search bound, or the record's timing) is replaced by a
    delay of its lag: the chain saved holds the effects the report names, and the
    record's timing as a delay."""
    for x in [k for k in found.accepted if k != best and k in REGISTRY and (
            k not in found.cur.effects or trivial(k, found.cur.effects[k], fl.scale))]:
        found.accepted.remove(x)
        found.tried[x]["refused"] = f"replaced in the fit of {best}"
    for x in found.cur.effects:
        if x not in found.accepted and x not in run.base.effects and not trivial(x, found.cur.effects[x], fl.scale) \
                and not run.at_bound(x, found.cur) \
                and not (x == "lowpass" and lag.is_timing(run.score, found.cur, found.score, run.min_shrink,
                                                          fl.accept, fl.scale.min_delay)):
            found.accepted.append(x)
            found.tried[x] = dict(found.tried[best],
                                  score=found.tried.get(x, {}).get("score", found.tried[best]["score"]))
    if "lowpass" in found.cur.effects and "lowpass" not in found.accepted and "lowpass" not in run.base.effects:
        # A low-pass the fit brought that is not one (at a bound, or the record's timing)
        # leaves the chain: its lag goes to the delay (what the chain saved then names).
        st = FitState(found.cur.model, lag.delay_equivalent(found.cur.effects), found.cur.train_rmse)
        sc, parts = run.score_parts(st)
        run.say(f"the low-pass fitted with {best} is not one: its lag given to the delay (holdout RMSE {sc:.4g})")
        found.move(st, sc, parts)


def eliminate(run: Run, found: Found, best: str, rnd: int) -> None:
    """Backward elimination: an effect accepted earlier that ``best`` makes redundant (a
    delay that stood in for a low-pass's lag) is dropped when the chain without it,
    re-polished, scores as well."""
    for x in [k for k in found.accepted if k != best]:
        if len(found.accepted) < 2 or x not in found.cur.effects:
            continue
        _drop_if_as_good(run, found, x, run.fitter.state(run.fitter.without(found.cur.effects, x)), best,
                         f"round {rnd + 1}: ")


def _drop_if_as_good(run: Run, found: Found, x: str, st2: FitState, best: str, prefix: str = "") -> None:
    """Effect ``x`` dropped, the chain moved to ``st2`` (the chain without it), when that
    scores within 2 % of the chain with it: ``best`` made it redundant."""
    sc2, parts2 = run.score_parts(st2)
    run.say(f"{prefix}without {x}: holdout RMSE {sc2:.4g}")
    if sc2 <= found.score * 1.02:
        found.accepted.remove(x)
        found.tried[x]["refused"] = f"made redundant by {best}"
        found.move(st2, sc2, parts2)


def record_timing(run: Run, found: Found, fl: Floors) -> None:
    """The record's timing in the chain the search starts from: a capture lags its
    command by a sample or two (the ADC's latency, the DAC's hold, an anti-aliasing
    filter), which on steps is most of the hysteresis' holdout error and which any
    effect that acts as a lag would otherwise take (rate, creep, drift). A delay fitted
    on the training record that is no longer than two samples (no effect: the sampling's
    own timing, ``augmented.timing_s``; searched up to just below two samples: a longer
    lag is the candidates' to explain) is kept when it lowers the holdout RMSE; every
    candidate is then judged against the chain with it."""
    if ("delay" not in run.candidates or "delay" in found.cur.effects or run.base.kept is not None
            or found.score <= 1.2 * fl.accept):
        return
    with warnings.catch_warnings(), run.trials.search():
        warnings.simplefilter("ignore", PreisachWarning)
        eff = run.fitter.timing(found.cur.effects)
        if "delay" not in eff:
            return
        st = run.fitter.state(eff)
    sc, parts = run.score_parts(st)
    run.say(f"the record's timing ({1e3 * eff['delay']['delay_s']:.3g} ms): holdout RMSE {sc:.4g} "
            f"(without: {found.score:.4g}){'' if sc < found.score else '; not kept'}")
    if sc < found.score:
        found.move(st, sc, parts)


def search(run: Run, found: Found, fl: Floors) -> None:
    """Stepwise selection scored on the holdouts, from the chain with the record's
    timing: up to three rounds of fit, accept, eliminate."""
    record_timing(run, found, fl)
    dyn = [c for c in run.candidates if c in CANDIDATES and c not in run.base.effects]
    for rnd in range(3):
        if found.score <= 1.2 * fl.accept:
            run.say("residual at the noise (or repeatability) floor; stopping")
            return
        todo = [c for c in dyn if c not in found.accepted]
        if rnd >= 2:
            # A candidate that made the chain worse in the round before is not refitted:
            # one more accepted effect does not unmask it.
            skip = [c for c in todo if c in found.tried and found.tried[c]["round"] == rnd
                    and found.tried[c]["score"] <= 0]
            for c in skip:
                run.say(f"round {rnd + 1}: {c} skipped (it worsened the chain in round {rnd})")
            todo = [c for c in todo if c not in skip]
        if not todo:
            return
        best = accept(run, found, fl, fit_round(run, found, fl, todo, rnd), rnd)
        if best is None:
            return
        eliminate(run, found, best, rnd)


# -- refine ----------------------------------------------------------------------------
def _refitted(run: Run, found: Found) -> bool:
    """Whether the chain found is refitted at the finer average (it has effects to polish;
    a chain with none stays as the search fitted it)."""
    return bool(found.accepted or run.base.effects)


def _finer(run: Run, fl: Floors, st0: FitState, fitter: Fitter) -> tuple[FitState, float, np.ndarray, float]:
    """The chain ``st0`` on the finer grid, fitted by ``fitter`` (at the average the chain
    itself is fitted at: the grid is all that changes), and its score."""
    t0 = time.perf_counter()
    with warnings.catch_warnings(), run.trials.search():
        warnings.simplefilter("ignore", PreisachWarning)
        st = fitter.state(st0.effects, n_h=fl.nh2)
    sc, parts = run.score_parts(st)
    return st, sc, parts, time.perf_counter() - t0


def _polish_fine(run: Run, found: Found) -> None:
    """The chain found, polished and refitted on the finer average (local steps only: the
    valley between a delay and a low-pass was searched on the coarser average). Creep is
    left as searched when the chain has a mode: each trial of it is a solve behind the
    resonance at the finer average, and the mode's timing is what this refit is for; the
    slow effects are recalibrated across the records later."""
    if not _refitted(run, found):
        return
    names = [k for k in found.cur.effects if not (k == "creep" and "vibration" in found.cur.effects)]
    with run.trials.search():
        eff, _ = run.fine.polish(dict(found.cur.effects), names, sweeps=1, scale=0.5, refine=1, valley=False)
    pol = run.fine.state(eff)
    ps, pparts = run.score_parts(pol)
    run.say(f"refit at {1 / run.fine.dt:.0f} Hz: holdout RMSE {ps:.4g} (was {found.score:.4g})")
    if ps < found.score:
        found.move(pol, ps, pparts)


def refine(run: Run, found: Found, fl: Floors) -> None:
    """The chain found, refitted on the finer average; the discretization check (a finer
    grid with the effects found) runs beside it on the chain before the refit, and is
    redone on the refitted chain only when it passes. A chain with no effects is not
    refitted, and its check is fitted at the search's average (the finer hysteresis
    alone, fitted already, when the chain is the reference)."""
    disc = "discretization" in run.candidates and fl.nh2 > run.n_h
    own = run.fine if _refitted(run, found) else run.fitter
    with run.trials.tasks(1) as ex:
        fut = ex.submit(_finer, run, fl, found.cur, own) if disc else None
        pre_score, pre_parts = found.score, found.parts
        _polish_fine(run, found)
        if fut is None:
            return
        st, sc, parts, el = fut.result()
    run.say(f"+ discretization (n_h={fl.nh2}) holdout RMSE {sc:.4g} (without: {pre_score:.4g}) ({el:.1f} s)")
    g = gain(pre_score, sc)
    why = None
    if g >= run.min_shrink and pre_score - sc < 0.5 * fl.accept:
        why = "improvement below half the noise (or repeatability) floor"
    elif g >= run.min_shrink and np.any(parts > pre_parts * 1.05 + 1e-12):
        why = "worsens part of a holdout"
    elif g >= run.min_shrink and pre_score > 1.2 * fl.accept and found.score < pre_score:
        # It passed on the chain before the refit: the same on the refitted chain.
        st, sc, parts, _ = _finer(run, fl, found.cur, own)
        g = gain(found.score, sc)
        if g < run.min_shrink:
            why = "no gain on the refitted chain"
    found.tried["discretization"] = {"state": st, "rmse_after": sc, "rmse_current": found.score, "score": g,
                                     "round": len(found.accepted) + 1, "n_h": fl.nh2}
    if why is not None:
        found.tried["discretization"]["refused"] = why
    elif g >= run.min_shrink and found.score > 1.2 * fl.accept:
        found.accepted.append("discretization")
        found.cur, found.score = st, sc


# -- the holdouts ----------------------------------------------------------------------
def _halves_refusal(run: Run, found: Found, fl: Floors, c: str, xf: dict[str, Any], sc: float,
                    parts: np.ndarray) -> Optional[str]:
    """Why effect ``c`` cross-fitted on the holdouts' halves is not accepted, or None."""
    if not beats_floors(run, fl, found.score, sc):
        return "no gain on the holdouts cross-fitted"
    # (As in the search: an effect that explains most of the error on the parts it was
    # fitted on may leave part of a holdout worse; another effect may dominate there.)
    strong = min(f["_gain"] for f in xf["folds"]) >= 0.5
    if not strong and np.any(parts > found.parts * 1.05 + 1e-12):
        return "worsens part of a holdout"
    flaws = [w for f in xf["folds"] if (w := _fold_flaw(fl, c, f["_state"].effects[c], f["_ranges"]))]
    if flaws:
        return flaws[0]
    if not cf.agree(c, [f["params"] for f in xf["folds"]]):
        return f"the folds disagree on {REGISTRY[c].agree[0]}"
    if c == "lowpass":
        # The record's timing, as in the search: a fold's chain against its delay equivalent.
        st = xf["folds"][0]["_state"]
        sc_st = run.score(st)
        if lag.is_timing(run.score, st, sc_st, run.min_shrink, fl.accept, fl.scale.min_delay):
            return lag.TIMING
        # A low-pass must beat a delay of its lag on the holdouts (the same masses) by the
        # candidates' rule.
        sc_d = run.score(FitState(st.model, lag.delay_equivalent(st.effects), st.train_rmse))
        if not passes(run, fl, sc_d, sc_st):
            return f"no better than a delay of its lag (holdout RMSE {sc_d:.4g})"
    return None


def _fold_flaw(fl: Floors, c: str, p: dict[str, Any], ranges: Ranges) -> Optional[str]:
    """Why a fold's parameters ``p`` of effect ``c`` cannot be detected (trivial, or at a
    bound of the ``ranges`` it searched), or None."""
    if trivial(c, p, fl.scale):
        return "trivial parameters"
    bounds = ends_at_bound(c, p, ranges)
    return "at its search bound: " + "; ".join(bounds) if bounds else None


def _refused_on_halves(found: Found, c: str, why: str, folds: list[dict[str, Any]], st: FitState,
                       sc: float, **extra: Any) -> None:
    """Record effect ``c`` refused on the holdouts' halves: its folds and why (the report's
    ``split.cross_fit``), and the chain with it among the candidates tried (unless the
    training record's search tried it), at holdout RMSE ``sc``."""
    found.cross_fit[c] = {"folds": [{k: v for k, v in f.items() if not k.startswith("_")} for f in folds],
                          **extra, "refused": why}
    if c not in found.tried:
        found.tried[c] = {"state": st, "rmse_after": sc, "rmse_current": found.score, "score": gain(found.score, sc),
                          "round": len(found.accepted) + 1, "fitted_on": "holdouts' halves (see split.cross_fit)",
                          "refused": why}


def _first_halves_refusal(run: Run, found: Found, fl: Floors, c: str, fits: cf.HalfFits) -> bool:
    """Effect ``c``'s fold on the first halves (the fit on the first half it explains most
    of) is trivial or at its search bound (``_fold_flaw``): refused whatever the second
    halves give (every fold must be neither); recorded as refused. Returns whether it was."""
    on = [fits[(c, 0, i)] for i in range(len(run.hos))]
    i = int(np.argmax([g for _, _, g in on]))
    eff, rg, g = on[i]
    flaw = _fold_flaw(fl, c, eff[c], rg)
    if flaw is None:
        return False
    why = f"{flaw}, on the first halves"
    run.say(f"{c} fitted on the holdouts' first halves: refused ({why})")
    st = FitState(found.cur.model, dict(found.cur.effects, **{c: eff[c]}), found.cur.train_rmse)
    _refused_on_halves(found, c, why, [{"fit": cf.half(run.hos[i], 0).name, "score": [], "params": {
        k: v for k, v in eff[c].items() if not k.startswith("_")}, "masses": "the training record's",
        "explained_on_fit": g}], st, found.score)
    return True


def _first_fold_refusal(run: Run, found: Found, fl: Floors, c: str,
                        first: tuple[dict[str, Any], list[np.ndarray]]) -> bool:
    """Effect ``c``'s fold on the first halves (``crossfit.fold``) already leaves no gain
    with the errors it gives the second halves alone: the cross-fitted RMSE of both folds
    is at least what those errors give over every holdout's samples (and the rule,
    ``beats_floors``, fails for any RMSE above one it fails for), so the effect is refused
    whatever the second halves give; recorded as refused. Returns whether it was."""
    fold, scored = first
    least = math.sqrt(sum(float(np.sum(np.square(e))) for e in scored) / sum(h.y.size for h in run.hos))
    if beats_floors(run, fl, found.score, least):
        return False
    why = "no gain on the holdouts cross-fitted, from the first halves' fold alone"
    run.say(f"{c} fitted on the holdouts' first halves: holdout RMSE at least {least:.4g} (without: "
            f"{found.score:.4g}); refused ({why})")
    _refused_on_halves(found, c, why, [fold], fold["_state"], least, rmse_after_at_least=least)
    return True


def holdout_halves(run: Run, found: Found, fl: Floors) -> None:
    """The fast effects the training record does not show (a mode the slow
    identification sine does not excite), each fitted on half of a holdout and scored on
    the other halves (``crossfit.holdout_halves``); the best that passes is kept, fitted
    once more on the whole holdout it shows most on."""
    names = [c for c in run.candidates if c in REGISTRY and REGISTRY[c].cross_fit == "halves"
             and c not in found.accepted]
    if not names or found.score <= 1.2 * fl.accept:
        return

    # A holdout that starts with a step from rest: its first half is fitted with the
    # transient (the mode rings there most).
    rests = [rest.starts_with_step(run.base.residuals[h.name], h.dt) for h in run.hos]
    passing = []
    with warnings.catch_warnings(), run.trials.tasks(run.trials.workers) as ex:
        warnings.simplefilter("ignore", PreisachWarning)
        # The fits on the halves, every effect's on every half side by side (the slowest
        # first: the threads end together), then each effect's folds scored. An effect
        # whose fold on the first halves cannot pass is not fitted on the second.
        order = sorted(names, key=lambda c: SLOW_FIRST.index(c) if c in SLOW_FIRST else len(SLOW_FIRST))
        fits = cf.half_fits(found.cur, order, run.hos, run.fitter.u_range, run.search_rate_hz, run.trials, ex.map,
                            rests, halves=(0,))
        order = [c for c in order if not _first_halves_refusal(run, found, fl, c, fits)]
        firsts = dict(zip(order, ex.map(lambda c: cf.fold(found.cur, c, run.hos, run.holdout_errors, run.fitter,
                                                          fits, 0), order)))
        order = [c for c in order if not _first_fold_refusal(run, found, fl, c, firsts[c])]
        fits.update(cf.half_fits(found.cur, order, run.hos, run.fitter.u_range, run.search_rate_hz, run.trials,
                                 ex.map, rests, halves=(1,)))
        order = [c for c in names if c in order]
        for c, xf in zip(order, ex.map(lambda c: cf.holdout_halves(
                found.cur, c, run.hos, run.holdout_errors, run.fitter, run.search_rate_hz, run.trials, fits, rests,
                firsts[c]), order)):
            sc, parts = run.parts_of(xf["errors"])
            why = _halves_refusal(run, found, fl, c, xf, sc, parts)
            run.say(f"{c} fitted on the holdouts' halves (cross-fitted): holdout RMSE {sc:.4g} "
                    f"(without: {found.score:.4g}){'' if why is None else f'; refused ({why})'}")
            if why is None:
                found.cross_fit[c] = {"folds": [{k: v for k, v in f.items() if not k.startswith("_")}
                                                for f in xf["folds"]], "rmse_after": sc}
                passing.append((sc, c, parts, xf))
            else:
                _refused_on_halves(found, c, why, xf["folds"], xf["folds"][0]["_state"], sc, rmse_after=sc)
    if not passing:
        return
    sc, c, parts, xf = min(passing, key=lambda p: p[0])
    st, masses = cf.saved_fit(found.cur, c, xf["target"], run.fitter, run.search_rate_hz, run.trials,
                              rests[run.hos.index(xf["target"])])
    found.cross_fit[c]["saved"] = {"fit": xf["target"].name, "masses": masses}
    found.tried[c] = {"state": st, "rmse_after": sc, "rmse_current": found.score, "score": gain(found.score, sc),
                      "round": len(found.accepted) + 1, "fitted_on": "holdouts' halves (see split.cross_fit)"}
    found.accepted.append(c)
    found.move(st, sc, parts)
    accept_pairs(run, found, fl, c)
    run.say(f"accepted {c} (cross-fitted on the holdouts): holdout RMSE {sc:.4g}; the chain's effects "
            f"{', '.join(found.accepted)}")
    drop_redundant(run, found, c)


def drop_redundant(run: Run, found: Found, best: str) -> None:
    """Backward elimination without a refit (the chain's effects were fitted on the
    holdouts): an effect accepted earlier that the chain without scores as well on is
    dropped (a low-pass that stood in for a mode's lag)."""
    for x in [k for k in found.accepted if k != best and k in REGISTRY and not REGISTRY[k].slow]:
        if x not in found.cur.effects or (x == "delay" and any(k in found.cur.effects for k in ("vibration",
                                                                                              "lowpass"))):
            continue
        _drop_if_as_good(run, found, x, FitState(found.cur.model, {k: v for k, v in found.cur.effects.items()
                                                                   if k != x}, found.cur.train_rmse), best)


def holdout_effects(run: Run, found: Found, fl: Floors) -> None:
    """Effects only the holdouts carry: a delay added to the chain found (the simplest
    explanation of a lag only they show), then the fast effects on the holdouts' halves."""
    before = list(found.accepted)
    holdout_delay_step(run, found, fl)
    holdout_halves(run, found, fl)
    if any(k not in before for k in found.accepted):
        drop_standins(run, found, fl, searched=before)


def timing_chain(run: Run, cur: FitState) -> FitState:
    """The chain ``cur`` with the training record's own timing (a delay shorter than the
    sampling explains, not reported) as a delay block, the masses refitted with it: without
    it the masses absorb that lag as wider loops, which act as a lag on slow inputs but not
    at steps, and a further delay the holdouts carry would come out different on each."""
    if "delay" in cur.effects:
        return cur
    with warnings.catch_warnings(), run.trials.search():
        warnings.simplefilter("ignore", PreisachWarning)
        eff = run.fitter.timing(cur.effects)
        return run.fine.state(eff) if "delay" in eff else cur


def holdout_delay_step(run: Run, found: Found, fl: Floors) -> None:
    """A delay only the holdouts carry (the loop reads another channel than the one the
    model was identified on): added to the chain with the training record's timing,
    fitted on some holdouts, scored on the others; each holdout's start with its own
    staircase on both sides of the comparison (an error at the start alone is the
    initial state's, judged next)."""
    if "delay" not in run.candidates or "delay" in found.accepted or found.score <= 1.2 * fl.accept:
        return
    base = timing_chain(run, found.cur)
    xf = holdout_delay(base, run.hos, run.holdout_errors, run.fitter.ranges["delay"]["delay_s"], run.trials.map,
                       run.starts, fl.scale.min_delay)
    found.cross_fit["delay"] = {"folds": xf["folds"], "added_s": xf["added_s"],
                                "base_delay_s": float(base.effects.get("delay", {}).get("delay_s", 0.0))}
    added = ", ".join(f"{1e3 * f['added_s']:.3g} ms on {'+'.join(f['fit'])}" for f in xf["folds"])
    if xf["errors"] is None:
        # (Not scored: the folds' delays alone refuse it.)
        found.cross_fit["delay"]["refused"] = "the holdouts disagree on the delay"
        run.say(f"delay fitted on the holdouts (cross-fitted): {added}; refused (the holdouts disagree on the delay)")
        return
    e0 = run.holdout_errors(base)
    sc0, _ = run.parts_of([own_start(base, h, e, run.starts(base, h), run.trials.map)[0]
                           for h, e in zip(run.hos, e0)])
    sc, _ = run.parts_of(xf["errors"])
    sc_plain, parts_x = run.parts_of(xf["plain"])
    g = gain(sc0, sc)
    run.say(f"delay fitted on the holdouts (cross-fitted): holdout RMSE {sc:.4g} (without: {sc0:.4g}; each holdout's "
            f"start with its own staircase); {added}")
    why = None
    if not passes(run, fl, sc0, sc) or sc_plain >= fl.hyst_alone:
        why = "no gain on the holdouts cross-fitted"
    elif bounds := run.at_bound("delay", xf["state"]):
        why = "at its search bound: " + "; ".join(bounds)
    if why is None:
        found.tried["delay"] = {"state": xf["state"], "rmse_after": sc, "rmse_current": sc0, "score": g,
                                "round": len(found.accepted) + 1, "fitted_on": "holdouts"}
        found.accepted.append("delay")
        found.move(xf["state"], sc_plain, parts_x)
    else:
        found.cross_fit["delay"]["refused"] = why


def _without(run: Run, found: Found, x: str) -> tuple[FitState, float, np.ndarray, Optional[dict[str, Any]]]:
    """The chain without effect ``x`` (a low-pass's lag given to the delay:
    ``search.less``), its masses refitted on the training record with the other
    effects (as a candidate's search fits them), a delay only the holdouts carry
    cross-fitted again on it (as its step does); its state, score, parts and that delay's
    cross-fit record (None without one)."""
    eff = {k: dict(v) for k, v in found.cur.effects.items()}
    held = "delay" in found.accepted and found.tried.get("delay", {}).get("fitted_on") == "holdouts"
    if held:
        d0 = float(found.cross_fit["delay"]["base_delay_s"])
        eff.pop("delay")
        if d0 > 0:
            eff["delay"] = {"delay_s": d0}
    eff = less(eff, x)
    with warnings.catch_warnings(), run.trials.search():
        warnings.simplefilter("ignore", PreisachWarning)
        st = run.fine.state(eff, n_h=found.cur.model.n_h)
    if not held:
        sc, parts = run.score_parts(st)
        return st, sc, parts, None
    base = timing_chain(run, st)
    xf = holdout_delay(base, run.hos, run.holdout_errors, run.fitter.ranges["delay"]["delay_s"], run.trials.map,
                       run.starts)
    sc, parts = run.parts_of(xf["plain"])
    rec = {"folds": xf["folds"], "added_s": xf["added_s"],
           "base_delay_s": float(base.effects.get("delay", {}).get("delay_s", 0.0))}
    return xf["state"], sc, parts, rec


def _standins(found: Found, levels: bool, searched: Optional[list[str]]) -> list[str]:
    """The accepted effects ``drop_standins`` tests again (see there)."""
    def tested(k: str) -> bool:
        e = REGISTRY.get(k)
        if e is None or k not in found.cur.effects or (searched is not None and k not in searched):
            return False
        return (e.slow and not (levels and k == "drift")) or (e.acts_as_lag and not levels)
    return [k for k in found.accepted if tested(k)]


def drop_standins(run: Run, found: Found, fl: Floors, levels: bool = False,
                  searched: Optional[list[str]] = None) -> None:
    """Backward elimination of the effects that may have stood in for one only the
    holdouts carry, once such effects are in the chain: an effect accepted in the search
    on its holdout score may have taken part of it there (creep's lag, or a low-pass's, for
    a channel's delay: the effects ``slow`` or ``acts_as_lag`` in the registry; with ``levels``,
    only a slow one: a creep far beyond the records for the records' own levels,
    ``session_offsets``, which are then fitted on the chain without it too, drift itself
    not re-tested). Each is kept only when it still meets the rule it was accepted by
    against the chain without it (``_without``): it shrinks that chain's holdout RMSE by
    ``min_shrink`` (a quarter of it when it explains most of the training error) and by
    more than half the floor; else it is dropped. ``searched``: only these (the effects
    the search accepted; one accepted on the holdouts' halves was judged against the chain
    without it there)."""
    for x in _standins(found, levels, searched):
        st2, sc2, parts2, delay_fit = _without(run, found, x)
        if levels:
            offs, gains, es = sessions.offsets(run.holdout_errors(st2), [h.y for h in run.hos],
                                               [h.u for h in run.hos], [h.name for h in run.hos], fl.accept)
            sc2 = rmse(np.concatenate(es))
        g = gain(sc2, found.score)
        strong = found.tried.get(x, {}).get("train_gain", 0.0) >= 0.5
        keep = sc2 - found.score >= 0.5 * fl.accept and (g >= run.min_shrink or (strong and g >= 0.25 * run.min_shrink))
        after = "with the records' levels" if levels else "after the holdout effects"
        run.say(f"without {x} ({after}): holdout RMSE {sc2:.4g} (with: {found.score:.4g})"
                f"{'' if keep else f'; {x} dropped'}")
        if keep:
            continue
        found.accepted.remove(x)
        what = "the records' own levels" if levels else "the effects only the holdouts carry"
        found.tried[x]["refused"] = f"no gain once {what} are in the chain"
        if levels:
            found.cur, found.score, found.record_offsets, found.record_gains = st2, sc2, offs, gains
        else:
            found.move(st2, sc2, parts2)
        if delay_fit is not None:
            found.cross_fit["delay"] = delay_fit
            found.tried["delay"]["state"] = st2


def training_start(run: Run, cur: FitState) -> tuple[list[float], FitState]:
    """The training record's own starting staircase (estimated as a holdout's is) and
    chain ``cur`` with its masses refitted after it, on the fit's windows. Twice: masses
    fitted from rest absorb part of a start's error, so the first estimate is refined on
    the masses refitted after it. None where the masses are kept (a given baseline)."""
    if type(run.fine) is not Fitter:
        return [], cur
    st = cur
    ex: list[float] = []
    for _ in range(2):
        e = run.starts(st, run.tr)[0]
        if not e or e == ex:
            break
        ex = e
        st = run.fine.other(cur.model.n_h, ex).state(cur.effects)
    return ex, st


def _with_starts(run: Run, st: FitState) -> tuple[float, float, dict[str, list[float]], list[str], str]:
    """Chain ``st``'s holdout RMSE without and with each holdout's own starting
    staircase (kept only where its part's error is its own, ``own_start``), the
    staircase estimated on each, the holdouts that keep theirs, and the holdout whose
    staircase helps most on its part."""
    est = {h.name: run.starts(st, h) for h in run.hos}
    plain = run.holdout_errors(st)
    kept = [own_start(st, ho, e, est[ho.name], run.trials.map) for e, ho in zip(plain, run.hos)]
    best = max(run.hos, key=lambda h: est[h.name][1] - est[h.name][2]).name
    return (rmse(np.concatenate(plain)), rmse(np.concatenate([e for e, _ in kept])),
            {h.name: est[h.name][0] for h in run.hos}, [h.name for h, (_, ex) in zip(run.hos, kept) if ex], best)


def initial_state(run: Run, found: Found, fl: Floors) -> None:
    """The hysteresis memory at each record's start (history nobody recorded), estimated
    on the part before its input swept the range, the chain fixed: each holdout's; and
    the training record's, with the masses refitted after it, kept when the holdouts
    (never used to estimate it) fit better with it."""
    if "initial_state" not in run.candidates or found.score <= 1.2 * fl.accept:
        return
    cur = found.cur
    # The gain is against the chain's errors without any staircase (``found.score`` may
    # be a cross-fitted score, whose difference from these errors is no start's).
    sc0, sc, recs, named, best = _with_starts(run, cur)
    tr_ex, started = training_start(run, cur)
    if tr_ex:
        _, sc_t, recs_t, named_t, _ = _with_starts(run, started)
        if sc_t < sc:
            cur, sc, recs, named = started, sc_t, dict(recs_t, train=tr_ex), ["train"] + named_t
    run.say(f"initial state of each record: holdout RMSE {sc:.4g} (without: {sc0:.4g}) on "
            f"{', '.join(named) or 'no record'}")
    found.tried["initial_state"] = {
        "state": cur, "rmse_after": sc, "rmse_current": sc0, "score": gain(sc0, sc), "round": len(found.accepted) + 1,
        "fitted_on": ("each record's start, before its input swept the range (the training record's with the "
                      "masses refitted after it, kept for the holdouts' gain)" if "train" in recs else
                      "each holdout's start, before its input swept the range"),
        "params": {"extrema": recs.get("train") or recs[best], "record_extrema": recs}}
    if not beats_floors(run, fl, sc0, sc):
        found.tried["initial_state"]["refused"] = "no gain on the holdouts"
    else:
        found.accepted.append("initial_state")
        found.cur = cur
        found.score *= sc / sc0  # the holdout RMSE with the staircases' share removed


def mark_rest(run: Run) -> None:
    """A training record that starts with a step from rest: its transient is fitted with
    the masses in every chain (``preisach.diagnose.rest``)."""
    flag = rest.starts_with_step(run.base.residuals[run.tr.name], run.tr.dt)
    for f in (run.fitter, run.fine, run.fitter.slow):
        if f is not None:
            f.rest = flag


def session_offsets(run: Run, found: Found, fl: Floors) -> None:
    """An output offset or gain that differs between records (sessions), under drift: per
    holdout, on evidence that separates it from history and creep
    (``preisach.diagnose.sessions``). Where the search kept a drift, the records' levels
    are also tried instead of its trend (a trend fitted through records of different
    sessions is wrong inside each), and the better cross-fitted score is kept."""
    if "drift" not in run.candidates or found.score <= 1.2 * fl.accept:
        return
    before = rmse(np.concatenate(run.holdout_errors(found.cur)))
    bases = [found.cur]
    if "drift" in found.cur.effects:
        eff = {k: v for k, v in found.cur.effects.items() if k != "drift"}
        bases.append(run.fine.state(eff, n_h=found.cur.model.n_h))  # the masses refitted without it
    best: Optional[tuple[float, FitState, dict[str, float], dict[str, float]]] = None
    for st in bases:
        offsets, gains, es = sessions.offsets(run.holdout_errors(st), [h.y for h in run.hos],
                                              [h.u for h in run.hos], [h.name for h in run.hos], fl.accept)
        sc = rmse(np.concatenate(es))
        if offsets and (best is None or sc < best[0]):
            best = (sc, st, offsets, gains)
    if best is None:
        run.say("an offset per holdout (sessions): on no holdout")
        return
    sc, st, offsets, gains = best
    trend = "" if st is found.cur else ", instead of the drift's trend"
    run.say(f"an offset per holdout (sessions{trend}): holdout RMSE {sc:.4g} (without: {before:.4g}) on "
            f"{', '.join(offsets)}" + (f"; a gain on {', '.join(gains)}" if gains else ""))
    if not beats_floors(run, fl, before, sc):
        return
    if "drift" not in found.accepted or st is not found.cur:
        zero = {"gain_per_s": 0.0, "offset": 0.0, "offset_per_s": 0.0}
        found.tried["drift"] = {
            "state": FitState(st.model, dict(st.effects, drift=zero), st.train_rmse), "rmse_after": sc,
            "rmse_current": before, "score": gain(before, sc),
            "round": found.tried.get("drift", {}).get("round", len(found.accepted) + 1),
            "fitted_on": "each holdout, after its input swept the range (cross-fitted halves)"}
        if "drift" not in found.accepted:
            found.accepted.append("drift")
        found.cur = st
    found.record_offsets = offsets
    found.record_gains = gains
    found.score = sc
    drop_standins(run, found, fl, levels=True)


def rest_where(run: Run, found: Found, where: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The rest input before each record that starts with a step from rest (the chain's
    transient explains its start), and the residual localized again with that start
    counted as after a step."""
    u_lo, u_hi = float(np.min(run.tr.u)), float(np.max(run.tr.u))
    found.rests = rest.rest_inputs(found.cur, run.recs, (u_lo, u_hi))
    if not found.rests:
        return where
    return _localized(run, found.rests)


def _localized(run: Run, rests: dict[str, dict[str, float]]) -> list[dict[str, Any]]:
    """The baseline's residual localized on every record (``rests``: the rest input of
    each record that starts with a step from rest)."""
    levels = np.linspace(*run.base.model.u_range, run.n_h + 1)
    return [localize(r.name, r.t, r.u, run.base.residuals[r.name], r.dt, levels,
                     rests.get(r.name, {}).get("rest_input")) for r in run.given_recs]
