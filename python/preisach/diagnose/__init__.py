"""Sim-to-real gap diagnosis (DESIGN.md, "Sim-to-real gap diagnosis"; GitHub issue 5).

``diagnose(train, holdouts)`` fits the baseline Preisach model on the training record
(exactly what ``preisach identify TRAIN`` produces), then reports

- **where** its residual lies on every record (time windows, after steps / at
  reversals / in dwells, input level, frequency band, input rate) and the noise floor
  estimated from the data;
- **which** unmodelled effect causes it: every candidate (``delay``, ``lowpass``,
  ``vibration``, ``creep``, ``drift``, ``rate``, ``discretization``) is added to the
  chain and fitted jointly with the masses on the training record, then scored on the
  holdout records; effects are added greedily while each one shrinks the holdout RMSE
  by at least ``min_shrink``; ``none`` when nothing does;
- **how far** the gap shrinks: RMSE before (baseline) and after (augmented chain) on
  the holdouts, which were never used to fit anything.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Optional, Sequence, Union

import numpy as np

from preisach.chain import Chain, sample_period
from preisach.diagnose.effects import CANDIDATES, ChainFitter, FitState, Record, export_state, rmse
from preisach.diagnose.report import GapReport, evidence_text
from preisach.diagnose.where import localize, noise_floor, signatures
from preisach.model import PreisachModel, PreisachWarning

__all__ = ["diagnose", "GapReport", "run_cli", "CANDIDATES"]

RecordLike = Union[str, "Path", dict, tuple, list]


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


def _reversals(u: np.ndarray) -> int:
    d = np.diff(u)
    s = np.sign(d[d != 0])
    return int(np.sum(s[1:] != s[:-1]))


def _say(progress: bool, msg: str) -> None:
    if progress:
        print(f"diagnose: {msg}", file=sys.stderr, flush=True)


def diagnose(train: RecordLike, holdouts: Sequence[RecordLike], n_h: int = 40,
             baseline: Optional[Union[str, Path, Chain]] = None,
             candidates: Sequence[str] = CANDIDATES + ("discretization",), min_shrink: float = 0.10,
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
    baseline : chain file or :class:`~preisach.chain.Chain`, optional
        A chain that already models some effects; candidates are added on top of it.
    candidates : effect names to try.
    min_shrink : float
        An effect is detected when adding it shrinks the holdout RMSE of the current
        chain by at least this fraction.
    fit_rate_hz : float
        The augmented chain found is finally refitted on the training record
        point-decimated to about this rate (the effects of interest lie below 2 kHz);
        scoring uses full-rate holdouts.
    search_rate_hz : float
        Candidate chains (the greedy search) are fitted on the training record decimated
        to about this rate (a mass fit costs about half as much as at 25 kHz); the delay
        and low-pass of the chain found are then profiled again at ``fit_rate_hz``.
    workers : int, optional
        Candidate fits run in this many threads (default: up to 2, the CPUs available).

    Returns a :class:`GapReport`.
    """
    t_start = time.perf_counter()

    def say(msg: str) -> None:
        _say(progress, f"[{time.perf_counter() - t_start:5.1f} s] {msg}")

    if workers is None:
        workers = min(2, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))
    if isinstance(holdouts, (str, Path, dict)) or (isinstance(holdouts, tuple) and len(holdouts) == 3
                                                    and not isinstance(holdouts[0], (str, Path, dict, tuple))):
        holdouts = [holdouts]  # type: ignore[list-item]
    if not holdouts:
        raise ValueError("holdouts: need at least one holdout record to score on")
    unknown = [c for c in candidates if c not in CANDIDATES + ("discretization",)]
    if unknown:
        raise ValueError(f"candidates: unknown effect(s) {', '.join(unknown)}")
    tr = _load(train, "train")
    hos = [_load(h, f"holdout {i + 1}") for i, h in enumerate(holdouts)]
    if _reversals(tr.u) < 2:
        raise ValueError(f"{tr.name}: the input has no reversals (a monotone input cannot identify hysteresis)")
    say(f"baseline fit on {tr.name} ({tr.u.size} samples, n_h={n_h})")

    # The baseline, exactly as `preisach identify` makes it (or the given chain).

    base_effects: dict[str, dict[str, Any]] = {}
    if baseline is not None:
        bch = baseline if isinstance(baseline, Chain) else Chain.load(baseline)
        base_model = bch.model
        base_effects = {k: dict(v) for k, v in bch.effects.items()}
        n_h = base_model.n_h

        def base_pred(r: Record) -> np.ndarray:
            return bch.predict(r.t, r.u)
    else:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            base_model = PreisachModel.fit(tr.u, tr.y, n_h)

        def base_pred(r: Record) -> np.ndarray:
            return base_model.predict(r.u)

    recs = [tr] + hos
    base_res = {r.name: r.y - base_pred(r) for r in recs}
    base_rmse = {r.name: rmse(base_res[r.name]) for r in recs}

    def score_parts(st: FitState) -> tuple[float, np.ndarray]:
        """Holdout RMSE overall and on each half of each holdout (the acceptance rule
        asks an effect to help on every part, not just on average)."""
        es = [st.predict(h) - h.y for h in hos]
        parts = []
        for e in es:
            m = e.size // 2
            parts += [rmse(e[:m]), rmse(e[m:])]
        return rmse(np.concatenate(es)), np.array(parts)

    def score(st: FitState) -> float:
        return score_parts(st)[0]

    t_all = np.concatenate([r.t for r in recs])
    t_span = float(t_all.max() - t_all.min())

    def trivial(name: str, p: dict[str, Any], floor: float) -> bool:
        """Parameters too small (or too large) to be a real effect of that kind."""
        if name == "delay":
            return p["delay_s"] < 0.5 * fit_rec.dt
        if name == "vibration":
            return p["damping"] > 0.3
        if name == "lowpass":
            return p["cutoff_hz"] > 0.3 / fit_rec.dt
        if name == "creep":
            return float(sum(p["amplitudes"])) < 0.003
        if name == "drift":
            y_span = float(np.ptp(tr.y)) or 1.0
            return abs(p["gain_per_s"]) * t_span * y_span + abs(p["offset_per_s"]) * t_span < 3 * floor
        return False

    hold_before = rmse(np.concatenate([base_res[h.name] for h in hos]))

    # Reference: the same model class with a continuous (interpolated) output, refitted.
    stride = max(1, int(round(1.0 / (tr.dt * fit_rate_hz))))
    fit_rec = tr.decimated(stride)
    # Augmented chains use a model range a little wider than the training input (5 % of
    # its span each side): no sample saturates the model, which otherwise biases the
    # effect parameters (creep most) that compensate the flat output beyond the range.
    u_lo, u_hi = float(np.min(tr.u)), float(np.max(tr.u))
    pad = 0.05 * (u_hi - u_lo)
    fine = ChainFitter(fit_rec, n_h, (u_lo - pad, u_hi + pad))
    sstride = max(stride, int(round(1.0 / (tr.dt * min(search_rate_hz, fit_rate_hz)))))
    search_rec = tr.decimated(sstride)
    fitter = ChainFitter(search_rec, n_h, (u_lo - pad, u_hi + pad)) if sstride != stride else fine
    ref = fine.fit(base_effects, None, iters=2 if base_effects else 0)
    ref_score = score(ref)
    say(f"reference (interpolated) holdout RMSE {ref_score:.4g} (baseline {hold_before:.4g})")

    # Noise floor and where.
    floors = [noise_floor(r.y - ref.predict(r)) for r in recs]
    floor = float(np.median(floors))
    levels = np.linspace(*base_model.u_range, n_h + 1)
    where = [localize(r.name, r.t, r.u, base_res[r.name], r.dt, levels) for r in recs]
    sig = {}
    for r in recs:
        h = ref.predict(r)
        sig[r.name] = signatures(r.t, r.u, h, r.y - h, r.dt)
    say(f"where: noise floor {floor:.3g}, residual localized on {len(recs)} records")

    # Which and how far: greedy forward selection scored on the holdouts.
    cur, cur_score = ref, ref_score
    cur_parts = score_parts(ref)[1]
    tried: dict[str, dict[str, Any]] = {}
    accepted: list[str] = []
    coarse_fitted: set[str] = set()
    dyn = [c for c in candidates if c in CANDIDATES and c not in base_effects]
    for rnd in range(3):
        if cur_score <= 1.2 * floor:
            say("residual at the noise floor; stopping")
            break
        results = {}
        todo = [c for c in dyn if c not in accepted]
        if rnd >= 2:
            # From the third round on, a candidate that made the chain worse in the round
            # before (with the first effect already in) is not refitted: one more accepted
            # effect does not unmask it (masking by the first effect is what round 2 is for).
            skip = [c for c in todo if c in tried and tried[c]["round"] == rnd and tried[c]["score"] <= 0]
            for c in skip:
                say(f"round {rnd + 1}: {c} skipped (it worsened the chain in round {rnd})")
            todo = [c for c in todo if c not in skip]
        if not todo:
            break
        if len([c for c in accepted if c != "discretization"]) > 1:
            # Polish the accepted chain (all kept effects refitted jointly with the masses,
            # then each effect's main scalar profiled) so this round credits a new effect
            # only with its own improvement, not with further convergence of the effects
            # kept. Only when there is a candidate left to try (the chain found is refitted
            # at the end anyway).
            pol = fitter.fit(cur.effects, None, iters=1, start=cur.model)
            eff, model = dict(pol.effects), pol.model
            for c in accepted:
                eff, model = fitter.profile(c, eff, model, narrow=True)
            pol = FitState(model, eff)
            ps, pparts = score_parts(pol)
            say(f"round {rnd + 1}: polished {' + '.join(accepted)}: holdout RMSE {ps:.4g} (was {cur_score:.4g})")
            if ps < cur_score:
                cur, cur_score, cur_parts = pol, ps, pparts

        def one(c: str, cur: FitState = cur) -> tuple[str, FitState, float, np.ndarray, float]:
            t0 = time.perf_counter()
            # A mode is searched at the fitting rate: in the coarse record the folded
            # noise and step harmonics bury a well-damped peak.
            st = (fine if c == "vibration" else fitter).clone().fit(cur.effects, c, iters=2, start=cur.model,
                                                                       only_new=True)
            sc, parts = score_parts(st)
            return c, st, sc, parts, time.perf_counter() - t0

        # Candidates are independent: two at a time (the core and NumPy's large-array
        # kernels release the GIL). The slow ones first, so the pool stays busy.
        todo.sort(key=lambda c: c not in ("delay", "lowpass", "creep", "drift"))
        with warnings.catch_warnings(), ThreadPoolExecutor(max_workers=max(1, min(workers, len(todo)))) as ex:
            warnings.simplefilter("ignore", PreisachWarning)
            for c, st, sc, parts, el in ex.map(lambda c: one(c), todo):
                results[c] = (st, sc, parts)
                say(f"round {rnd + 1}: + {c:10s} holdout RMSE {sc:.4g} ({el:.1f} s)")
        results = {c: results[c] for c in dyn if c in results}
        if not results:
            break
        for c, (st, sc, _) in results.items():
            tried[c] = {"state": st, "rmse_after": sc, "rmse_current": cur_score,
                        "score": (cur_score - sc) / cur_score if cur_score > 0 else 0.0, "round": rnd + 1}
        # Acceptance: the best candidate that shrinks the holdout RMSE by min_shrink, (after
        # the first round) does not worsen any half of any holdout by more than 5 %, and has non-trivial parameters (a tag-along
        # effect that trades errors between records or fits nothing real is refused).
        best = None
        for c in sorted(results, key=lambda c: results[c][1]):
            st, sc, parts = results[c]
            gain = (cur_score - sc) / cur_score if cur_score > 0 else 0.0
            if gain < min_shrink:
                break
            why = None
            extra = [k for k in st.effects if k not in cur.effects and k != c]
            if any(x in results and (results[x][1] - sc) < min_shrink * results[x][1] for x in extra):
                why = f"no better than {', '.join(extra)} alone"
            elif cur_score - sc < 0.5 * floor:
                why = "improvement below half the noise floor"
            elif rnd > 0 and np.any(parts > cur_parts * 1.05 + 1e-12):
                why = "worsens part of a holdout"
            elif any(trivial(x, st.effects[x], floor) for x in [c] + extra):
                why = "trivial parameters"
            if why is None:
                best = c
                break
            tried[c]["refused"] = why
            say(f"round {rnd + 1}: {c} refused ({why})")
        if best is None and rnd == 0 and len(results) > 1:
            # Look-ahead for a masked pair: a slow effect (drift, creep) fitted on the
            # training record is biased by an unmodelled fast one, and the fast one alone
            # gains little while the slow one dominates the holdouts. Add the slow effect
            # on top of the best fast candidate; accept both when the pair passes the rule.
            fast = [c for c in results if c not in ("drift", "creep")]
            if fast:
                f1 = min(fast, key=lambda c: results[c][1])
                for slow in ("drift", "creep"):
                    if slow not in dyn or f1 == slow:
                        continue
                    st2 = fitter.fit(results[f1][0].effects, slow, iters=2, start=results[f1][0].model, only_new=True)
                    sc2, parts2 = score_parts(st2)
                    say(f"round 1: + {f1} + {slow} holdout RMSE {sc2:.4g}")
                    g2 = (cur_score - sc2) / cur_score if cur_score > 0 else 0.0
                    g1 = (results[f1][1] - sc2) / results[f1][1] if results[f1][1] > 0 else 0.0
                    if g2 >= min_shrink and g1 >= min_shrink and cur_score - sc2 >= 0.5 * floor \
                            and not trivial(f1, st2.effects[f1], floor) and not trivial(slow, st2.effects[slow], floor):
                        accepted.append(f1)
                        if fitter is not fine and f1 != "vibration":
                            coarse_fitted.add(f1)
                        tried[slow] = {"state": st2, "rmse_after": sc2, "rmse_current": results[f1][1],
                                       "score": g1, "round": 2}
                        results = {slow: (st2, sc2, parts2)}
                        best = slow
                        break
        if best is None:
            break
        accepted.append(best)
        if fitter is not fine and best != "vibration":
            coarse_fitted.add(best)
        cur, cur_score, cur_parts = results[best]
        if best == "vibration":
            # A lightly damped mode in the chain needs the fitting rate from here on (its
            # ringing after the coarse record's steps is modelled worse, so every further
            # candidate would look worse than the chain it extends).
            fitter = fine
        for x in cur.effects:
            if x not in accepted and x not in base_effects:
                # Fitted with it as a pair (a mode whose ringing needed a delay).
                accepted.append(x)
                tried[x] = dict(tried[best], score=tried.get(x, {}).get("score", tried[best]["score"]))
    # The chain found, refitted at the fitting rate: masses, then the delay's and the
    # low-pass's profiles (narrow: the search placed them already).
    if any(c in coarse_fitted for c in cur.effects if c in ("delay", "lowpass") and c not in base_effects):
        eff, model = dict(cur.effects), fine.masses(cur.effects, cur.model)
        for c in accepted:
            if c == "lowpass" and c in coarse_fitted and int(eff["lowpass"]["order"]) in (1, 2):
                eff, model = fine.profile_lowpass_orders(eff, model)
            elif c == "delay" and c in coarse_fitted:
                eff, model = fine.profile(c, eff, model, narrow=True)
        pol = FitState(model, eff)
        ps, pparts = score_parts(pol)
        say(f"refit at {1 / fit_rec.dt:.0f} Hz: holdout RMSE {ps:.4g} (was {cur_score:.4g})")
        if ps < cur_score:
            cur, cur_score, cur_parts = pol, ps, pparts
    # Discretization: a finer grid (with the effects found).
    if "discretization" in candidates:
        nh2 = min(2 * n_h, max(n_h, _reversals(tr.u) // 2), 120)
        if nh2 > n_h:
            t0 = time.perf_counter()
            st = FitState(fine.masses(cur.effects, cur.model, n_h=nh2), dict(cur.effects))
            sc, parts = score_parts(st)
            say(f"+ discretization (n_h={nh2}) holdout RMSE {sc:.4g} ({time.perf_counter() - t0:.1f} s)")
            g = (cur_score - sc) / cur_score if cur_score > 0 else 0.0
            tried["discretization"] = {"state": st, "rmse_after": sc, "rmse_current": cur_score, "score": g,
                                       "round": len(accepted) + 1, "n_h": nh2}
            if g >= min_shrink and cur_score - sc < 0.5 * floor:
                tried["discretization"]["refused"] = "improvement below half the noise floor"
            elif g >= min_shrink and np.any(parts > cur_parts * 1.05 + 1e-12):
                tried["discretization"]["refused"] = "worsens part of a holdout"
            elif g >= min_shrink and cur_score > 1.2 * floor:
                accepted.append("discretization")
                cur, cur_score = st, sc

    final = export_state(cur)
    aug = Chain(final.model, final.effects)
    effects_out = []
    for c in accepted + sorted((c for c in tried if c not in accepted), key=lambda c: -tried[c]["score"]):
        d = tried[c]
        if c == "discretization":
            params: dict[str, Any] = {"n_h_suggested": d["n_h"]}
        else:
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
            "refused": d.get("refused"),
        })
    report = GapReport(
        dominant_effect=accepted[0] if accepted else "none",
        noise_floor=floor,
        baseline={"n_h": n_h, "rmse": base_rmse, "holdout_rmse": hold_before,
                  "reference_interpolated_holdout_rmse": ref_score,
                  "effects": list(base_effects)},
        where=where,
        split={"fit": f"{tr.name} only (candidates: {search_rec.u.size} samples after point decimation by "
                      f"{sstride}; the chain found: {fit_rec.u.size} samples, decimation by {stride})",
               "score": [h.name for h in hos],
               "parts": [f"{h.name} {half} half" for h in hos for half in ("first", "second")],
               "note": "masses and effect parameters are fitted on the training record only; every chain "
                       "is scored on the holdouts (never fitted). An effect is kept (greedy) when it shrinks "
                       "the holdout RMSE by min_shrink, after the first effect worsens none of the parts (each holdout's halves) by more than 5 % "
                       "and has non-trivial parameters, and the RMSE drop exceeds half the noise floor; the holdouts thus pick the effects, so confirm "
                       "on a further record"},
        effects=effects_out,
        augmented={"effects": list(aug.effects), "holdout_rmse": cur_score,
                   "shrink": float(1 - cur_score / hold_before) if hold_before > 0 else 0.0},
        seconds=time.perf_counter() - t_start,
        chain=aug, baseline_model=base_model, records=recs, base_residuals=base_res,
    )
    say(f"done in {report.seconds:.1f} s: dominant effect {report.dominant_effect}")
    return report


def run_cli(args: argparse.Namespace) -> int:
    """``preisach diagnose TRAIN --holdout H ... --json REPORT.json [--save-model AUG.json]
    [--plots DIR] [--n-h N] [--baseline CHAIN.json]``. Prints a short summary; user
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
