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
  by at least ``min_shrink``; then a delay and the fast effects only the holdouts carry
  (cross-fitted on them) and each record's ``initial_state``; ``none`` when nothing
  helps;
- **how far** the gap shrinks: RMSE before (baseline) and after (augmented chain) on
  the holdouts, which were never used to fit anything.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Optional, Sequence, Union

from preisach.chain import Chain
from preisach.diagnose import steps
from preisach.diagnose.effects import CANDIDATES
from preisach.diagnose.outcome import build_report
from preisach.diagnose.records import RecordLike
from preisach.diagnose.records import check_distinct as _check_distinct  # noqa: F401 (tests)
from preisach.diagnose.records import load_record as _load  # noqa: F401 (tests)
from preisach.diagnose.report import GapReport
from preisach.diagnose.search import Trials
from preisach.model import PreisachModel

__all__ = ["diagnose", "GapReport", "run_cli", "CANDIDATES"]


def _say(progress: bool, msg: str) -> None:
    if progress:
        print(f"diagnose: {msg}", file=sys.stderr, flush=True)


def diagnose(train: RecordLike, holdouts: Sequence[RecordLike], n_h: int = 40,
             baseline: Optional[Union[str, Path, Chain, PreisachModel]] = None,
             candidates: Sequence[str] = CANDIDATES + ("discretization", "initial_state"), min_shrink: float = 0.10,
             fit_rate_hz: float = 25e3, progress: bool = True, workers: Optional[int] = None,
             search_rate_hz: float = 12.5e3, refit_masses: bool = False) -> GapReport:
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
        candidates are added on top of it. Any other chain (a simulated stage: "my
        simulator") is kept as it is, every block of it: the candidates are added behind
        it, and the gap found is the one between the simulator and the stage measured
        (``preisach.diagnose.kept``; the delay, low-pass, mode and drift candidates).
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
    refit_masses : bool
        With a kept simulator as ``baseline``: the masses of its hysteresis block are
        refitted on ``train`` first (``n_h`` levels; the blocks before it give its
        input, the series linear blocks after it are fitted behind), every other block
        kept as it is.
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
                         search_rate_hz, trials, refit_masses)
    except KeyboardInterrupt:
        trials.cancel()  # Ctrl-C: nothing new starts; the solves in the core end on their own
        raise
    finally:
        trials.close()


def _diagnose(train: RecordLike, holdouts: Sequence[RecordLike], n_h: int,
              baseline: Optional[Union[str, Path, Chain, PreisachModel]], candidates: Sequence[str],
              min_shrink: float, fit_rate_hz: float, progress: bool, search_rate_hz: float,
              trials: Trials, refit_masses: bool = False) -> GapReport:
    """The steps (``preisach.diagnose.steps``): prepare, reference, where, search, refine,
    the holdouts' own effects, report."""
    t_start = time.perf_counter()

    def say(msg: str) -> None:
        _say(progress, f"[{time.perf_counter() - t_start:5.1f} s] {msg}")

    tr, hos = steps.load_inputs(train, holdouts, candidates)
    say(f"baseline fit on {tr.name} ({tr.u.size} samples, n_h={n_h})")
    base = steps.fit_baseline(tr, hos, n_h, baseline)
    if base.given is not None and base.given["refitted"]:
        n_h = base.model.n_h
    if base.kept is not None:
        run = steps.kept_run(tr, hos, n_h, candidates, min_shrink, trials, say, base, fit_rate_hz, search_rate_hz,
                             refit_masses)
    else:
        fitter, fine, stride, sstride = steps.make_fitters(tr, n_h, fit_rate_hz, search_rate_hz, trials)
        run = steps.Run(tr, hos, n_h, tuple(candidates), min_shrink, trials, say, base, fitter, fine, stride,
                        sstride, search_rate_hz)
        steps.mark_rest(run)
    with trials.tasks(1) as ex:  # the finer hysteresis alone is fitted beside the reference, where and round 1
        found, alone, nh2 = steps.reference(run, ex)
        floors, where, sig = steps.where(run, found, alone, nh2)
        steps.search(run, found, floors)
    steps.refine(run, found, floors)
    steps.holdout_effects(run, found, floors)
    steps.session_offsets(run, found, floors)
    steps.initial_state(run, found, floors)
    where = steps.rest_where(run, found, where)
    report = build_report(run, found, floors, where, sig, time.perf_counter() - t_start)
    say(f"done in {report.seconds:.1f} s: dominant effect {report.dominant_effect}")
    return report


def run_cli(args: argparse.Namespace) -> int:
    """``preisach diagnose TRAIN --holdout H ... --json REPORT.json [--save-model AUG.json]
    [--plots DIR] [--n-h N] [--baseline MODEL|CHAIN|STAGE.json [--refit-masses]]``. Prints a short summary; user
    errors are raised as ValueError (the CLI prints them without a traceback)."""
    hold = list(getattr(args, "holdout", None) or [])
    if not hold:
        raise ValueError("--holdout: give at least one holdout record")
    if getattr(args, "refit_masses", False) and getattr(args, "baseline", None) is None:
        raise ValueError("--refit-masses: needs --baseline (a simulator whose output the masses map)")
    rep = diagnose(args.train, hold, n_h=getattr(args, "n_h", 40) or 40, baseline=getattr(args, "baseline", None),
                   refit_masses=bool(getattr(args, "refit_masses", False)))
    from preisach.io import write_text

    write_text(args.json, rep.to_json() + "\n")
    if getattr(args, "save_model", None):
        rep.chain.save(args.save_model)
    if getattr(args, "plots", None):
        rep.plot(args.plots)
    print(rep.summary())
    return 0
