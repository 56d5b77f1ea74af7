"""Sim-to-real gap diagnosis (`docs/method/diagnosis.md`).

``diagnose(train, holdouts)`` fits the baseline Preisach model on the training record
(exactly what ``preisach identify TRAIN`` produces), then reports

- **where** its residual lies on every record (time windows, after steps / at
  reversals / in dwells, input level, frequency band, input rate) and the noise floor
  estimated from the data;
- **which** unmodelled effect causes it: every candidate (``delay``, ``lowpass``,
  ``vibration``, ``creep``, ``drift``, ``rate``, ``discretization``) is added to the
  chain and fitted jointly with the masses on the training record, then scored on the
  holdout records; effects are added greedily while each one shrinks the holdout RMSE
  by at least ``min_shrink``; then a delay only the holdouts carry (cross-fitted on
  them) and each holdout's ``initial_state``; ``none`` when nothing helps;
- **how far** the gap shrinks: RMSE before (baseline) and after (augmented chain) on
  the holdouts, which were never used to fit anything.
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import numpy as np

from preisach.chain import Chain, load, sample_period
from preisach.diagnose.crossfit import consistent, holdout_delay
from preisach.diagnose.effects import CANDIDATES, FitState, Record, export_state, rate_branch, rmse
from preisach.diagnose.initial import concentrated, estimate, fitted_part, predict_from
from preisach.diagnose.ranges import CREEP_TAU_MIN, ends_at_bound
from preisach.diagnose.report import GapReport, evidence_text
from preisach.diagnose.search import Effects, Fitter, Trials, calibrate_slow
from preisach.diagnose.where import localize, noise_floor, repeatability_floor, signatures
from preisach.model import PreisachModel, PreisachWarning

__all__ = ["diagnose", "GapReport", "run_cli", "CANDIDATES"]

RecordLike = Union[str, "Path", dict, tuple, list]


#: Candidates in the order their fits are started: the slowest first (a mode's fit is the
#: longest; the quick ones fill the other thread), so the round ends with both busy.
SLOW_FIRST = ("vibration", "lowpass", "creep", "delay")


def _load(x: Any, name: str) -> Record:
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


def _same(a: Record, b: Record) -> bool:
    """The same record: the same input and output samples (a copy of one file)."""
    return a.u.size == b.u.size and bool(np.array_equal(a.u, b.u) and np.array_equal(a.y, b.y))


def _check_distinct(tr: Record, hos: list[Record]) -> None:
    """A holdout that is the training record again (or another holdout again) scores a
    chain on samples it was fitted on, or counts one record twice: an error naming it.
    (Repeated records of one experiment differ in their output and are welcome.)"""
    for i, h in enumerate(hos):
        if _same(h, tr):
            raise ValueError(f"{h.name}: the training record ({tr.name}) given again as a holdout "
                             f"(a holdout must be a record not used to fit)")
        for g in hos[:i]:
            if _same(h, g):
                raise ValueError(f"{h.name}: the same record as {g.name} (give each holdout once)")


def _refittable(b: Union[PreisachModel, Chain]) -> Optional[tuple[PreisachModel, dict[str, dict[str, Any]]]]:
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


def _reversals(u: np.ndarray) -> int:
    d = np.diff(u)
    s = np.sign(d[d != 0])
    return int(np.sum(s[1:] != s[:-1]))


def _say(progress: bool, msg: str) -> None:
    if progress:
        print(f"diagnose: {msg}", file=sys.stderr, flush=True)


def diagnose(train: RecordLike, holdouts: Sequence[RecordLike], n_h: int = 40,
             baseline: Optional[Union[str, Path, Chain, PreisachModel]] = None,
             candidates: Sequence[str] = CANDIDATES + ("discretization", "initial_state"), min_shrink: float = 0.10,
             fit_rate_hz: float = 25e3, progress: bool = True, workers: Optional[int] = None,
             search_rate_hz: float = 12.5e3) -> GapReport:
    """Diagnose the gap between the baseline model and the measurements.

    Parameters
    ----------
    train : path, dict (t, u, y) or (t, u, y) tuple
        Fits the baseline (``PreisachModel.fit(u, y, n_h)``) and every augmented chain.
    holdouts : list of records
        Score every chain; never used to fit. Any sample rate.
    n_h : int
        Discretization level of the baseline.
    baseline : model, chain or stage (a file or an object), optional
        A model, or a model followed by effects, is refitted with its effects and the
        candidates are added on top of it. Any other chain (a simulated stage) is scored
        as the "before" only; the search then starts from a model fitted on ``train``.
    candidates : effect names to try.
    min_shrink : float
        An effect is detected when adding it shrinks the holdout RMSE of the current
        chain by at least this fraction.
    fit_rate_hz : float
        The augmented chain found is finally polished and refitted on the training record
        averaged over windows down to about this rate (the effects of interest lie below
        2 kHz); scoring uses full-rate holdouts.
    search_rate_hz : float
        Candidate chains (the stepwise search) are fitted on the training record averaged
        down to about this rate. Averaging commutes with the dynamics, so this costs
        accuracy only through the finer details of the input between windows.
    workers : int, optional
        Candidate fits (and a search's independent trials, while a CPU would otherwise
        idle) run in this many threads (default: up to 2, the CPUs available).

    Returns
    -------
    GapReport
        Where the gap lies, which effect causes it, how far it shrinks.
    """
    if workers is None:
        workers = min(2, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))
    # Independent trials of one search (starting points, grids) may run in these threads;
    # they hold their own fit sessions, released with them.
    trials = Trials(workers)
    try:
        return _diagnose(train, holdouts, n_h, baseline, candidates, min_shrink, fit_rate_hz, progress,
                         search_rate_hz, trials)
    except KeyboardInterrupt:
        trials.cancel()  # Ctrl-C: nothing new starts; the solves in the core end on their own
        raise
    finally:
        trials.close()


def _diagnose(train: RecordLike, holdouts: Sequence[RecordLike], n_h: int,
              baseline: Optional[Union[str, Path, Chain, PreisachModel]], candidates: Sequence[str],
              min_shrink: float, fit_rate_hz: float, progress: bool, search_rate_hz: float,
              trials: Trials) -> GapReport:
    t_start = time.perf_counter()

    def say(msg: str) -> None:
        _say(progress, f"[{time.perf_counter() - t_start:5.1f} s] {msg}")

    if isinstance(holdouts, (str, Path, dict)) or (isinstance(holdouts, tuple) and len(holdouts) == 3
                                                    and not isinstance(holdouts[0], (str, Path, dict, tuple))):
        holdouts = [holdouts]  # type: ignore[list-item]
    if not holdouts:
        raise ValueError("holdouts: need at least one holdout record to score on")
    unknown = [c for c in candidates if c not in CANDIDATES + ("discretization", "initial_state")]
    if unknown:
        raise ValueError(f"candidates: unknown effect(s) {', '.join(unknown)}")
    tr = _load(train, "train")
    hos = [_load(h, f"holdout {i + 1}") for i, h in enumerate(holdouts)]
    _check_distinct(tr, hos)
    if _reversals(tr.u) < 2:
        raise ValueError(f"{tr.name}: the input has no reversals (a monotone input cannot identify hysteresis)")
    say(f"baseline fit on {tr.name} ({tr.u.size} samples, n_h={n_h})")

    # The baseline, exactly as `preisach identify` makes it, or the given one: a model, or
    # a model followed by effects, is refitted with its effects; any other chain (a
    # simulated stage) is the "before" only, and the search starts from a fitted model.
    base_effects: dict[str, dict[str, Any]] = {}
    given: Optional[dict[str, Any]] = None
    bch: Optional[Union[PreisachModel, Chain]] = None
    refit = None
    if baseline is not None:
        bch = baseline if isinstance(baseline, (Chain, PreisachModel)) else load(baseline)
        refit = _refittable(bch)
        kinds = ["hysteresis"] if isinstance(bch, PreisachModel) else bch.kinds()
        given = {"blocks": kinds, "refitted": refit is not None}
    if refit is not None:
        base_model, base_effects = refit
        n_h = base_model.n_h
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            base_model = PreisachModel.fit(tr.u, tr.y, n_h)

    def base_pred(r: Record) -> np.ndarray:
        if isinstance(bch, Chain):
            return bch.predict(r.t, r.u)
        return (bch or base_model).predict(r.u)

    recs = [tr] + hos
    base_res = {r.name: r.y - base_pred(r) for r in recs}
    base_rmse = {r.name: rmse(base_res[r.name]) for r in recs}

    halves = [(slice(0, h.y.size // 2), slice(h.y.size // 2, None)) for h in hos]

    def holdout_errors(st: FitState) -> list[np.ndarray]:
        """Errors on each holdout. A chain with drift or creep has them recalibrated across
        records for each half of the holdouts, from the training record and the other
        halves (cross-fitting; see ``calibrate_slow``)."""
        if "drift" not in st.effects and "creep" not in st.effects:
            return [st.predict(h) - h.y for h in hos]
        errs = [np.empty(h.y.size) for h in hos]
        outputs: dict[int, np.ndarray] = {}
        for k in (0, 1):
            cal = calibrate_slow(st, [(tr, slice(None))] + [(h, hv[1 - k]) for h, hv in zip(hos, halves)], outputs)
            for e, h, hv in zip(errs, hos, halves):
                e[hv[k]] = (cal.predict(h) - h.y)[hv[k]]
        return errs

    def score_parts(st: FitState) -> tuple[float, np.ndarray]:
        """Holdout RMSE overall and on each half of each holdout (the acceptance rule
        asks an effect to help on every part, not just on average)."""
        es = holdout_errors(st)
        parts = []
        for e, hv in zip(es, halves):
            parts += [rmse(e[hv[0]]), rmse(e[hv[1]])]
        return rmse(np.concatenate(es)), np.array(parts)

    def score(st: FitState) -> float:
        return score_parts(st)[0]

    t_all = np.concatenate([r.t for r in recs])
    t_span = float(t_all.max() - t_all.min())

    hold_before = rmse(np.concatenate([base_res[h.name] for h in hos]))

    # Chains are fitted on windows of the training record averaged down to about
    # search_rate_hz (the average commutes with the dynamics and keeps the timing of input
    # steps; point decimation would bias every timing), and the chain found once more at
    # about fit_rate_hz. Their model range is a little wider than the training input (5 %
    # of its span each side): no sample saturates the model, which otherwise biases the
    # effect parameters (creep most) that compensate the flat output beyond the range.
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

    def excess_floor(st: FitState) -> float:
        return noise_floor(fitter.y - fitter.predict(st)) ** 2

    cur_eff: Effects = {k: dict(v) for k, v in base_effects.items()}
    if cur_eff:
        cur_eff, _ = fitter.polish(cur_eff, list(cur_eff), sweeps=2)
        cur_eff = fitter.with_linear(cur_eff)
    ref = fitter.state(cur_eff)
    ref_score = score(ref)
    say(f"reference (interpolated) holdout RMSE {ref_score:.4g} (baseline {hold_before:.4g})")

    # What a finer hysteresis alone achieves (no effect added): an effect is detected only
    # when its chain beats it as well as the interpolated one.
    nh2 = min(2 * n_h, max(n_h, _reversals(tr.u) // 2), 120)
    hyst_alone = ref_score
    if nh2 > n_h:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PreisachWarning)
            hyst_alone = min(ref_score, score(fitter.state(cur_eff, n_h=nh2)))
        say(f"finer hysteresis alone (n_h={nh2}): holdout RMSE {hyst_alone:.4g}")

    # Noise floor and where.
    floors = [noise_floor(r.y - ref.predict(r)) for r in recs]
    floor = float(np.median(floors))
    floor_j = excess_floor(ref)
    levels = np.linspace(*base_model.u_range, n_h + 1)
    where = [localize(r.name, r.t, r.u, base_res[r.name], r.dt, levels) for r in recs]
    sig = {}
    for r in recs:
        h = ref.predict(r)
        sig[r.name] = signatures(r.t, r.u, h, r.y - h, r.dt)
    # The floor an effect must beat: the noise, or the difference between repeated records
    # where there are any (what no chain fitted on one record can come below).
    rep_floor = repeatability_floor([(r.u, r.y) for r in recs])
    floor_acc = max(floor, rep_floor or 0.0)
    say(f"where: noise floor {floor:.3g}, repeatability floor "
        f"{'(no repeated records)' if rep_floor is None else f'{rep_floor:.3g}'}, "
        f"residual localized on {len(recs)} records")

    min_delay = 2.0 * min(r.dt for r in recs)

    def trivial(name: str, p: dict[str, Any]) -> bool:
        """Parameters too small (or too large) to be a real effect of that kind."""
        if name == "delay":
            return p["delay_s"] < min_delay  # sub-sample timing, not a delay
        if name == "vibration":
            # A "mode" damped beyond 0.15 is a lag (the low-pass's business), not ringing.
            return p["damping"] > 0.15 or p["frequency_hz"] > 0.4 / fitter.dt
        if name == "lowpass":
            return p["cutoff_hz"] > 0.3 / fitter.dt
        if name == "creep":
            return float(sum(p["amplitudes"])) < 0.003 or min(p["taus_s"]) < 0.99 * CREEP_TAU_MIN
        if name == "drift":
            y_span = float(np.ptp(tr.y)) or 1.0
            return abs(p["gain_per_s"]) * t_span * y_span + abs(p["offset_per_s"]) * t_span < 3 * floor
        if name == "rate":
            # A rate-dependent loop worth the name changes the output by a visible part of
            # its span; a branch of a few 1e-4 of it corrects the timing of other effects.
            rt = rate_branch(p, tr.t, tr.u)
            return rmse(rt) < 2e-3 * (float(np.ptp(tr.y)) or 1.0)
        return False

    # Which and how far: stepwise selection scored on the holdouts.
    cur, cur_score = ref, ref_score
    cur_parts = score_parts(ref)[1]
    tried: dict[str, dict[str, Any]] = {}
    accepted: list[str] = []
    dyn = [c for c in candidates if c in CANDIDATES and c not in base_effects]
    for rnd in range(3):
        if cur_score <= 1.2 * floor_acc:
            say("residual at the noise (or repeatability) floor; stopping")
            break
        todo = [c for c in dyn if c not in accepted]
        if rnd >= 2:
            # A candidate that made the chain worse in the round before is not refitted:
            # one more accepted effect does not unmask it.
            skip = [c for c in todo if c in tried and tried[c]["round"] == rnd and tried[c]["score"] <= 0]
            for c in skip:
                say(f"round {rnd + 1}: {c} skipped (it worsened the chain in round {rnd})")
            todo = [c for c in todo if c not in skip]
        if not todo:
            break
        j_cur = fitter.J(cur.effects)

        def one(c: str, base: Effects = cur.effects) -> tuple[str, FitState, float, np.ndarray, float, float]:
            t0 = time.perf_counter()
            with trials.search():
                eff = fitter.add(base, c)
                st = fitter.state(eff)
            sc, parts = score_parts(st)
            return c, st, sc, parts, fitter.J(eff), time.perf_counter() - t0

        # Candidates are independent: two at a time (the core releases the GIL). The slow
        # ones first, so the pool stays busy.
        todo.sort(key=lambda c: SLOW_FIRST.index(c) if c in SLOW_FIRST else len(SLOW_FIRST))
        results: dict[str, tuple[FitState, float, np.ndarray, float]] = {}
        with warnings.catch_warnings(), trials.tasks(min(trials.workers, len(todo))) as ex:
            warnings.simplefilter("ignore", PreisachWarning)
            for c, st, sc, parts, jc, el in ex.map(one, todo):
                results[c] = (st, sc, parts, jc)
                tg = (j_cur - jc) / max(j_cur - floor_j, 1e-300)
                say(f"round {rnd + 1}: + {c:10s} holdout RMSE {sc:.4g}, training {math.sqrt(jc):.4g} "
                    f"({100 * tg:.0f} % of the excess) ({el:.1f} s)")
        results = {c: results[c] for c in dyn if c in results}
        for c, (st, sc, _, jc) in results.items():
            tried[c] = {"state": st, "rmse_after": sc, "rmse_current": cur_score,
                        "score": (cur_score - sc) / cur_score if cur_score > 0 else 0.0, "round": rnd + 1,
                        "train_gain": (j_cur - jc) / max(j_cur - floor_j, 1e-300)}
        # Acceptance: the best candidate that shrinks the holdout RMSE by min_shrink by more
        # than half the noise floor, fits the training record better (a chain that fits it
        # worse only trades errors between records), after the first round worsens no half
        # of a holdout by more than 5 %, and has non-trivial parameters.
        # Among the candidates that pass, one the training record strongly supports goes
        # first: the training record is where parameters are identified, and a slow effect
        # (drift, creep) is identified better once the fast ones are in the chain.
        passing = []
        for c in sorted(results, key=lambda c: results[c][1]):
            st, sc, parts, jc = results[c]
            gain = (cur_score - sc) / cur_score if cur_score > 0 else 0.0
            # A candidate that explains most of the training error above the noise also
            # counts with a smaller holdout gain, and may leave part of a holdout worse:
            # another unmodelled effect (a drift that grows over the holdouts' later times)
            # may dominate the holdout error, and the refit moves its error around.
            strong = tried[c]["train_gain"] >= 0.5
            if gain < min_shrink and not (strong and gain >= 0.25 * min_shrink):
                continue
            why = None
            if cur_score - sc < 0.5 * floor_acc:
                why = "improvement below half the noise (or repeatability) floor"
            elif sc >= hyst_alone:
                why = "no better than a finer hysteresis alone"
            elif tried[c]["train_gain"] <= 0:
                why = "it does not fit the training record better"
            elif rnd > 0 and not strong and np.any(parts > cur_parts * 1.05 + 1e-12) \
                    and not (c in ("drift", "creep") and gain >= 2 * min_shrink):
                # (A slow effect's parameters are calibrated on the holdouts' other halves,
                # which moves error between the halves; a large gain counts for it.)
                why = "worsens part of a holdout"
            elif trivial(c, st.effects[c]):
                why = "trivial parameters"
            elif ends_at_bound(c, st.effects[c], fitter.ranges):
                why = "at its search bound: " + "; ".join(ends_at_bound(c, st.effects[c], fitter.ranges))
            if why is None:
                passing.append((not strong, sc, c))
            else:
                tried[c]["refused"] = why
                say(f"round {rnd + 1}: {c} refused ({why})")
        best = min(passing)[2] if passing else None
        if best is None:
            break
        accepted.append(best)
        cur, cur_score, cur_parts = results[best][0], results[best][1], results[best][2]
        for x in cur.effects:
            if x not in accepted and x not in base_effects and not trivial(x, cur.effects[x]) \
                    and not ends_at_bound(x, cur.effects[x], fitter.ranges):
                # Fitted with it as a pair (a mode whose ringing needed a delay).
                accepted.append(x)
                tried[x] = dict(tried[best], score=tried.get(x, {}).get("score", tried[best]["score"]))
        say(f"round {rnd + 1}: accepted {best}: holdout RMSE {cur_score:.4g}")
        # Backward elimination: an effect accepted earlier that the new one makes redundant
        # (a delay that stood in for a low-pass's lag) is dropped when the chain without it,
        # re-polished, scores as well.
        for x in [k for k in accepted if k != best]:
            if len(accepted) < 2 or x not in cur.effects:
                continue
            e2 = fitter.without(cur.effects, x)
            st2 = fitter.state(e2)
            sc2, parts2 = score_parts(st2)
            say(f"round {rnd + 1}: without {x}: holdout RMSE {sc2:.4g}")
            if sc2 <= cur_score * 1.02:
                accepted.remove(x)
                tried[x]["refused"] = f"made redundant by {best}"
                cur, cur_score, cur_parts = st2, sc2, parts2
    # The chain found, polished and refitted on the finer average; the discretization
    # check (a finer grid with the effects found) runs beside it, on the chain before the
    # refit, and is redone on the refitted chain only when it passes.
    disc = "discretization" in candidates and nh2 > n_h

    def finer(st0: FitState) -> tuple[FitState, float, np.ndarray, float]:
        t0 = time.perf_counter()
        with warnings.catch_warnings(), trials.search():
            warnings.simplefilter("ignore", PreisachWarning)
            st = fine.state(st0.effects, n_h=nh2)
        sc, parts = score_parts(st)
        return st, sc, parts, time.perf_counter() - t0

    with trials.tasks(1) as ex:
        fut = ex.submit(finer, cur) if disc else None
        pre_score, pre_parts = cur_score, cur_parts
        if fine is not fitter and (accepted or base_effects):
            # (Local steps only: the valley between a delay and a low-pass was searched on the
            # coarser average. Creep is left as searched when the chain has a mode: each trial
            # of it is a solve behind the resonance at the finer average, and the mode's
            # timing is what this refit is for; the slow effects are recalibrated across the
            # records below.)
            names = [k for k in cur.effects if not (k == "creep" and "vibration" in cur.effects)]
            with trials.search():
                eff, _ = fine.polish(dict(cur.effects), names, sweeps=1, scale=0.5, refine=1, valley=False)
            pol = fine.state(eff)
            ps, pparts = score_parts(pol)
            say(f"refit at {1 / fine.dt:.0f} Hz: holdout RMSE {ps:.4g} (was {cur_score:.4g})")
            if ps < cur_score:
                cur, cur_score, cur_parts = pol, ps, pparts
        if fut is not None:
            st, sc, parts, el = fut.result()
            say(f"+ discretization (n_h={nh2}) holdout RMSE {sc:.4g} (without: {pre_score:.4g}) ({el:.1f} s)")
            g = (pre_score - sc) / pre_score if pre_score > 0 else 0.0
            why = None
            if g >= min_shrink and pre_score - sc < 0.5 * floor_acc:
                why = "improvement below half the noise (or repeatability) floor"
            elif g >= min_shrink and np.any(parts > pre_parts * 1.05 + 1e-12):
                why = "worsens part of a holdout"
            elif g >= min_shrink and pre_score > 1.2 * floor_acc and cur_score < pre_score:
                # It passed on the chain before the refit: the same on the refitted chain.
                st, sc, parts, _ = finer(cur)
                g = (cur_score - sc) / cur_score if cur_score > 0 else 0.0
                if g < min_shrink:
                    why = "no gain on the refitted chain"
            tried["discretization"] = {"state": st, "rmse_after": sc, "rmse_current": cur_score, "score": g,
                                       "round": len(accepted) + 1, "n_h": nh2}
            if why is not None:
                tried["discretization"]["refused"] = why
            elif g >= min_shrink and cur_score > 1.2 * floor_acc:
                accepted.append("discretization")
                cur, cur_score = st, sc

    # A delay only the holdouts carry (the loop reads another channel than the one the
    # model was identified on): fitted on some holdouts, scored on the others.
    cross_fit: dict[str, Any] = {}
    if "delay" in candidates and "delay" not in accepted and cur_score > 1.2 * floor_acc:
        xf = holdout_delay(cur, hos, holdout_errors, fitter.ranges["delay"]["delay_s"])
        parts_x = [p for e, hv in zip(xf["errors"], halves) for p in (rmse(e[hv[0]]), rmse(e[hv[1]]))]
        sc = rmse(np.concatenate(xf["errors"]))
        g = (cur_score - sc) / cur_score if cur_score > 0 else 0.0
        say(f"delay fitted on the holdouts (cross-fitted): holdout RMSE {sc:.4g} (without: {cur_score:.4g}); "
            + ", ".join(f"{1e3 * f['added_s']:.3g} ms on {'+'.join(f['fit'])}" for f in xf["folds"]))
        why = None
        if g < min_shrink or cur_score - sc < 0.5 * floor_acc or sc >= hyst_alone:
            why = "no gain on the holdouts cross-fitted"
        elif not consistent(xf["folds"], min_delay):
            why = "the holdouts disagree on the delay"
        elif ends_at_bound("delay", xf["state"].effects["delay"], fitter.ranges):
            why = "at its search bound: " + "; ".join(ends_at_bound("delay", xf["state"].effects["delay"],
                                                                     fitter.ranges))
        cross_fit["delay"] = {"folds": xf["folds"], "added_s": xf["added_s"],
                              "base_delay_s": float(cur.effects.get("delay", {}).get("delay_s", 0.0))}
        if why is None:
            tried["delay"] = {"state": xf["state"], "rmse_after": sc, "rmse_current": cur_score, "score": g,
                              "round": len(accepted) + 1, "fitted_on": "holdouts"}
            accepted.append("delay")
            cur, cur_score, cur_parts = xf["state"], sc, np.array(parts_x)
        else:
            cross_fit["delay"]["refused"] = why

    # The hysteresis memory at each holdout's start (history nobody recorded), estimated
    # on the part before its input swept the range, the chain fixed.
    if "initial_state" in candidates and cur_score > 1.2 * floor_acc:
        est = {h.name: estimate(cur, h) for h in hos}
        errs, own = [], []
        for e, ho in zip(holdout_errors(cur), hos):
            k = fitted_part(ho)
            own.append(concentrated(est[ho.name][1], est[ho.name][2], rmse(e[k:]) if k < e.size else 0.0))
            # Only a staircase whose part's error is its own is kept.
            errs.append(e + predict_from(cur, ho, est[ho.name][0]) - cur.predict(ho) if own[-1] else e)
        sc = rmse(np.concatenate(errs))
        g = (cur_score - sc) / cur_score if cur_score > 0 else 0.0
        say(f"initial state of each holdout: holdout RMSE {sc:.4g} (without: {cur_score:.4g})")
        first = max(hos, key=lambda h: est[h.name][1] - est[h.name][2])
        tried["initial_state"] = {
            "state": cur, "rmse_after": sc, "rmse_current": cur_score, "score": g, "round": len(accepted) + 1,
            "fitted_on": "each holdout's start, before its input swept the range",
            "params": {"extrema": est[first.name][0], "record_extrema": {h.name: est[h.name][0] for h in hos}}}
        if g < min_shrink or cur_score - sc < 0.5 * floor_acc or sc >= hyst_alone:
            tried["initial_state"]["refused"] = "no gain on the holdouts"
        else:
            accepted.append("initial_state")
            cur_score = sc

    # The saved chain's slow effects are calibrated on every record (the further records
    # the user checks it on come later still).
    cal = calibrate_slow(cur, [(r, slice(None)) for r in recs])
    final = export_state(cal)
    aug = Chain(final.model, final.effects)
    aug.sample_rate_hz = 1.0 / tr.dt  # the training record's: for per-sample runs (run_loop)
    timing = final.effects.get("delay", {}).get("delay_s", 0.0) if "delay" not in accepted else 0.0
    effects_out = []
    for c in accepted + sorted((c for c in tried if c not in accepted), key=lambda c: -tried[c]["score"]):
        d = tried[c]
        at_bound: list[str] = []
        if c == "discretization":
            params: dict[str, Any] = {"n_h_suggested": d["n_h"]}
        elif c == "initial_state":
            params = dict(d["params"])
        else:
            internal = cal if c in accepted and c in cal.effects else d["state"]
            at_bound = ends_at_bound(c, internal.effects[c], fitter.ranges)
            # A detected effect's parameters are those of the augmented chain (refitted
            # after it was accepted); a refused one's those of its own candidate fit.
            src = final if c in accepted and c in final.effects else export_state(d["state"])
            params = {k: v for k, v in src.effects[c].items() if not k.startswith("_")}
        effects_out.append({
            "name": c, "detected": c in accepted, "score": float(d["score"]),
            "evidence": evidence_text(c, sig, tr.name, [h.name for h in hos], floor, d),
            "params": params, "rmse_before": float(hold_before), "rmse_after": float(d["rmse_after"]),
            "shrink": float(1 - d["rmse_after"] / hold_before) if hold_before > 0 else 0.0,
            "rmse_current": float(d["rmse_current"]), "shrink_vs_current": float(d["score"]), "round": d["round"],
            "refused": d.get("refused"), "at_bound": at_bound, "fitted_on": d.get("fitted_on", "train"),
        })
    report = GapReport(
        # The detected effect that shrank its chain's holdout RMSE the most.
        dominant_effect=max(accepted, key=lambda c: tried[c]["score"]) if accepted else "none",
        noise_floor=floor,
        baseline={"n_h": n_h, "rmse": base_rmse, "holdout_rmse": hold_before,
                  "reference_interpolated_holdout_rmse": ref_score, "reference_finer_holdout_rmse": hyst_alone,
                  "repeatability_floor": rep_floor,
                  "effects": list(base_effects), **({"given": given} if given is not None else {})},
        where=where,
        split={"fit": f"{tr.name} (candidates: averages of {sstride} samples, {fitter.y.size} values; "
                      f"the chain found: averages of {stride}, {fine.y.size} values); drift and creep parameters "
                      f"are recalibrated across records, masses and other effects fixed, on {tr.name} and the "
                      f"other half of each holdout (two-fold cross-fitting), and for the saved chain on every "
                      f"record",
               "score": [h.name for h in hos],
               **({"cross_fit": cross_fit} if cross_fit else {}),
               "parts": [f"{h.name} {half} half" for h in hos for half in ("first", "second")],
               "note": "masses and effect parameters are fitted on the training record (the slow effects' "
                       "calibration across records, a delay only the holdouts carry (see cross_fit: fitted on "
                       "some holdouts, scored on the others) and each holdout's initial_state (fitted on the "
                       "part of it before its input swept the range, the one exception to the next rule) "
                       "excepted); every chain is scored on the holdouts, no sample with "
                       "parameters fitted on it. An effect is kept (stepwise) when it shrinks "
                       "the holdout RMSE by min_shrink and by more than half the noise floor, fits the training "
                       "record better, after the first effect worsens none of the parts "
                       "(each holdout's halves) by more than 5 %, and has non-trivial parameters; an effect made "
                       "redundant by a later one is dropped. The holdouts thus pick the effects, so confirm "
                       "on a further record"},
        effects=effects_out,
        augmented={"effects": list(aug.effects), "holdout_rmse": cur_score,
                   "shrink": float(1 - cur_score / hold_before) if hold_before > 0 else 0.0,
                   "timing_s": float(timing)},
        seconds=time.perf_counter() - t_start,
        search_ranges={n: {k: [b.lo, b.hi] for k, b in r.items()} for n, r in fitter.ranges.items()},
        chain=aug, baseline_model=base_model, records=recs, base_residuals=base_res,
    )
    say(f"done in {report.seconds:.1f} s: dominant effect {report.dominant_effect}")
    return report


def run_cli(args: argparse.Namespace) -> int:
    """``preisach diagnose TRAIN --holdout H ... --json REPORT.json [--save-model AUG.json]
    [--plots DIR] [--n-h N] [--baseline MODEL|CHAIN|STAGE.json]``. Prints a short summary; user
    errors are raised as ValueError (the CLI prints them without a traceback)."""
    hold = list(getattr(args, "holdout", None) or [])
    if not hold:
        raise ValueError("--holdout: give at least one holdout record")
    rep = diagnose(args.train, hold, n_h=getattr(args, "n_h", 40) or 40, baseline=getattr(args, "baseline", None))
    from preisach.io import write_text

    write_text(args.json, rep.to_json() + "\n")
    if getattr(args, "save_model", None):
        rep.chain.save(args.save_model)
    if getattr(args, "plots", None):
        rep.plot(args.plots)
    print(rep.summary())
    return 0
