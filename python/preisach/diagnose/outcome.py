"""The last step of the diagnosis: the chain found, calibrated on every record and saved
as a :class:`~preisach.chain.Chain`, and the :class:`GapReport` of the steps' results
(every effect tried, ranked; what was fitted on what; the floors)."""
from __future__ import annotations

from typing import Any

from preisach.chain import Chain
from preisach.diagnose.effects import FitState, export_state
from preisach.diagnose.kept import saved_chain
from preisach.diagnose.report import GapReport, evidence_text
from preisach.diagnose.steps import Floors, Found, Run

#: How the holdouts score the chains (the ``split`` report's ``note``).
SPLIT_NOTE = (
    "masses and effect parameters are fitted on the training record (the slow effects' calibration across "
    "records, the fast effects only the holdouts carry (see cross_fit: a mode, a low-pass or a rate effect "
    "fitted on half of a holdout and scored on the other halves of every holdout, the masses the training "
    "record's; a delay fitted on some holdouts and scored on the others; creep's time constant chosen on the "
    "holdouts, judged with each half scored by the choice made on the other halves) and each holdout's "
    "initial_state "
    "(fitted on the part of it before its input swept the range, the one exception to the next rule) "
    "excepted); every chain is scored on the holdouts, no sample with parameters fitted on it. An effect is "
    "kept (stepwise) when it shrinks the holdout RMSE by min_shrink and by more than half the noise floor, "
    "fits the training record better, after the first effect worsens none of the parts (each holdout's "
    "halves) by more than 5 %, and has non-trivial parameters; an effect made redundant by a later one is "
    "dropped. The holdouts thus pick the effects, so confirm on a further record")


def dominance(d: dict[str, Any], name: str, baseline: float) -> float:
    """How much effect ``name`` (its ``tried`` entry ``d``) explains, for the dominant
    effect: the shrink of the holdout RMSE of the chain it was added to. The starting
    staircase is judged last, against a chain the other effects already shrank, and only
    where each record starts: it counts by the share of the baseline's holdout RMSE it
    removes."""
    if name == "initial_state":
        return (d["rmse_current"] - d["rmse_after"]) / baseline if baseline > 0 else 0.0
    return float(d["score"])


def effect_entry(run: Run, found: Found, fl: Floors, c: str, cal: FitState, final: FitState,
                 sig: dict[str, Any]) -> dict[str, Any]:
    """The report's entry for effect ``c`` (tried, detected or not)."""
    d = found.tried[c]
    detected = c in found.accepted
    at_bound: list[str] = []
    if c == "discretization":
        params: dict[str, Any] = {"n_h_suggested": d["n_h"]}
    elif c == "initial_state":
        params = dict(d["params"])
    else:
        internal = cal if detected and c in cal.effects else d["state"]
        at_bound = run.at_bound(c, internal)
        # A detected effect's parameters are those of the augmented chain (refitted after
        # it was accepted); a refused one's those of its own candidate fit.
        src = final if detected and c in final.effects else export_state(d["state"])
        params = {k: v for k, v in src.effects[c].items() if not k.startswith("_")}
        if c == "drift" and found.record_offsets:
            params["record_offsets"] = dict(found.record_offsets)  # by holdout: its session's offset
        if c == "drift" and found.record_gains:
            params["record_gains"] = dict(found.record_gains)  # by holdout: its session's gain
        if detected and found.rests and c in ("vibration", "lowpass"):
            # The step from rest at each record's start that its transient explains.
            params["rest_input"] = {n: v["rest_input"] for n, v in found.rests.items()}
            params["rest_step"] = {n: v["rest_step"] for n, v in found.rests.items()}
    before = run.base.holdout_rmse
    return {
        "name": c, "detected": detected, "score": float(d["score"]),
        "evidence": evidence_text(c, sig, run.tr.name, [h.name for h in run.hos], fl.noise, d),
        "params": params, "rmse_before": float(before), "rmse_after": float(d["rmse_after"]),
        "shrink": float(1 - d["rmse_after"] / before) if before > 0 else 0.0,
        "rmse_current": float(d["rmse_current"]), "shrink_vs_current": float(d["score"]), "round": d["round"],
        "refused": d.get("refused"), "at_bound": at_bound, "fitted_on": d.get("fitted_on", "train"),
    }


def split(run: Run, found: Found) -> dict[str, Any]:
    """What was fitted on what, and what scored."""
    tr, fitter, fine = run.tr, run.fitter, run.fine
    return {"fit": f"{tr.name} (candidates: averages of {run.sstride} samples, {fitter.y.size} values; "
                   f"the chain found: averages of {run.stride}, {fine.y.size} values); drift and creep parameters "
                   f"are recalibrated across records, masses and other effects fixed, on {tr.name} and the "
                   f"other half of each holdout (two-fold cross-fitting), and for the saved chain on every "
                   f"record",
            "score": [h.name for h in run.hos],
            **({"cross_fit": found.cross_fit} if found.cross_fit else {}),
            "parts": [f"{h.name} {half} half" for h in run.hos for half in ("first", "second")],
            "note": SPLIT_NOTE}


def build_report(run: Run, found: Found, fl: Floors, where: list[dict[str, Any]], sig: dict[str, Any],
                 seconds: float) -> GapReport:
    """The saved chain's slow effects calibrated on every record (the further records the
    user checks it on come later still), and the report. A calibration that leaves a
    detected effect at a search bound is not kept (an effect at a bound is not called
    detected, and this one was accepted inside its ranges): the chain is saved as
    accepted."""
    cal = run.on_every_record(found.cur)
    if any(run.at_bound(c, cal) for c in found.accepted):
        cal = found.cur
    final = export_state(cal)
    aug = Chain(final.model, final.effects) if run.base.kept is None else saved_chain(run.base.kept, cal)
    aug.sample_rate_hz = 1.0 / run.tr.dt  # the training record's: for per-sample runs (run_loop)
    accepted, tried = found.accepted, found.tried
    timing = final.effects.get("delay", {}).get("delay_s", 0.0) if "delay" not in accepted else 0.0
    order = accepted + sorted((c for c in tried if c not in accepted), key=lambda c: -tried[c]["score"])
    base, before = run.base, run.base.holdout_rmse
    return GapReport(
        dominant_effect=max(accepted, key=lambda c: dominance(tried[c], c, before)) if accepted else "none",
        noise_floor=fl.noise,
        baseline={"n_h": run.n_h, "rmse": base.rmse, "holdout_rmse": before,
                  "reference_interpolated_holdout_rmse": fl.ref_score,
                  "reference_finer_holdout_rmse": fl.hyst_alone, "repeatability_floor": fl.repeatability,
                  "effects": list(base.effects), **({"given": base.given} if base.given is not None else {}),
                  **({"kept": {"blocks": base.kept.kinds(), "masses": run.masses}} if base.kept is not None else {})},
        where=where,
        split=split(run, found),
        effects=[effect_entry(run, found, fl, c, cal, final, sig) for c in order],
        augmented={"effects": list(aug.effects) if base.kept is None else list(final.effects),
                   "holdout_rmse": found.score,
                   "rest_input": {n: v["rest_input"] for n, v in found.rests.items()},
                   "shrink": float(1 - found.score / before) if before > 0 else 0.0, "timing_s": float(timing)},
        seconds=seconds,
        search_ranges={n: {k: [b.lo, b.hi] for k, b in r.items()} for n, r in run.fitter.ranges.items()},
        chain=aug, baseline_model=base.model, records=run.given_recs, base_residuals=base.residuals,
    )
