"""Blind validation of ``preisach.diagnose``.

Draws simulated stages with one effect, two effects or none (random parameters in
realistic ranges), runs the diagnoser on a training record and holdouts without
telling it the answer, then scores the augmented chain it saved on a further record
it never saw. Prints Markdown: confusion matrix, false alarms on ``none`` stages,
parameter recovery and realised shrink.

The ground truth is simulated independently of the project's blocks
(``tests/independent_stage.py``: a fine-grid interpolated Preisach model, SciPy filters,
a linear-interpolation delay, drift in absolute time and white sensor noise).

The stage classes of real captures are drawn by a second simulator (``tests/rig.py``:
play-operator hysteresis, analog dynamics, unrecorded history, session offsets, delayed
channels, repeatability wander; see its ``CLASSES``): the paper's identification
protocol with steps and a faster sine as holdouts, effects only the holdouts carry,
records that start with a step from rest or after unknown history, a sensor offset that
differs between sessions, repeated records with nothing to find.

Usage: python benches/blind_validation.py [--stages N] [--seed S] [--fs HZ]
       python benches/blind_validation.py --rig N [--seed S]  (N stages per rig class;
       prints the per-class table)
       python benches/blind_validation.py --timing EFFECT[+EFFECT]  (6 s of 100 kHz data:
       2 s train + two 2 s holdouts; prints the per-candidate times and the total;
       --input-noise F adds white noise of F times the input's range to every input)
"""
from __future__ import annotations

import argparse
import itertools
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from preisach import PreisachModel

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import rig  # noqa: E402
from independent_stage import EFFECTS, delay_seen, make_stage  # noqa: E402

CANDIDATES_ALL = ("delay", "lowpass", "vibration", "creep", "drift", "rate", "discretization")


# ----------------------------------------------------------------------------- runner
def run(n_per_class: int = 3, seed: int = 1, fs: float = 50e3, verbose: bool = True,
        n_per_pair: int | None = None) -> dict[str, Any]:
    """Run the validation (``n_per_class`` stages per single effect and for none,
    ``n_per_pair`` per pair, default a third of it); returns the raw results (used by
    the pytest smoke test)."""
    from preisach.chain import Chain
    from preisach.diagnose import diagnose

    classes: list[tuple[str, ...]] = [()] + [(e,) for e in EFFECTS]
    classes += [p for p in itertools.combinations(EFFECTS, 2)]
    results = []
    k = 0
    for cls in classes:
        reps = n_per_class if len(cls) < 2 else (n_per_pair if n_per_pair is not None else max(1, n_per_class // 3))
        for r in range(reps):
            st = make_stage(seed * 1000 + k, cls, fs=fs)
            k += 1
            t0 = time.perf_counter()
            rep = diagnose(st["train"], [{kk: h[kk] for kk in "tuy"} for h in st["holdouts"]], progress=False)
            el = time.perf_counter() - t0
            b = st["blind"]
            chain = Chain.from_dict(rep.augmented_chain_dict())
            base = PreisachModel.from_dict(rep.baseline_model_dict())
            rb = float(np.sqrt(np.mean((base.predict(b["u"]) - b["y"]) ** 2)))
            ra = float(np.sqrt(np.mean((chain.predict(b["t"], b["u"]) - b["y"]) ** 2)))
            ref = _reference(st["train"]["u"], st["train"]["y"])
            rr = float(np.sqrt(np.mean((ref.predict(b["u"]) - b["y"]) ** 2)))
            found = [e["name"] for e in rep.effects if e["detected"]]
            # (The delay a chain needs: the stage's, plus the half sample its zero-order-hold mode lags.)
            true_delay = delay_seen(st["params"], fs) if "delay" in st["params"] else None
            results.append({"blind_ref": rr, "truth": cls, "params": st["params"], "true_delay_s": true_delay,
                            "found": found, "dominant": rep.dominant_effect,
                            "at_bound": {e["name"]: e["at_bound"] for e in rep.effects if e["at_bound"]},
                            "found_params": {e["name"]: e["params"] for e in rep.effects if e["detected"]},
                            "blind_before": rb, "blind_after": ra, "seconds": el})
            if verbose:
                print(f"<!-- stage {k}: truth={cls or ('none',)} found={found} blind {rb:.4g}->{ra:.4g} ({el:.1f}s)"
                      f"{_detected_at_bound(results[-1])} -->", file=sys.stderr, flush=True)
    return summarize(results, verbose)


def _detected_at_bound(r: dict[str, Any]) -> str:
    """The per-stage line's note of detected effects at a search bound (none should be)."""
    hit = {k: v for k, v in r["at_bound"].items() if k in r["found"]}
    return f" detected at a bound: {hit}" if hit else ""


def summarize(results: list[dict[str, Any]], verbose: bool = True) -> dict[str, Any]:
    """Markdown tables and the headline numbers."""
    labels = ("none",) + EFFECTS + ("discretization", "rate")
    singles = [r for r in results if len(r["truth"]) == 1]
    nones = [r for r in results if len(r["truth"]) == 0]
    pairs = [r for r in results if len(r["truth"]) == 2]
    conf = {a: {b: 0 for b in labels} for a in ("none",) + EFFECTS}
    for r in singles + nones:
        truth = r["truth"][0] if r["truth"] else "none"
        conf[truth][r["dominant"] if r["dominant"] in labels else "none"] += 1
    top1 = sum(r["dominant"] == r["truth"][0] for r in singles) / max(1, len(singles))
    both = sum(set(r["truth"]) <= set(r["found"]) for r in pairs) / max(1, len(pairs))
    false_alarms = sum(bool(r["found"]) for r in nones)
    delay_err, freq_err = [], []
    for r in results:
        if "delay" in r["truth"] and "delay" in r["found_params"]:
            delay_err.append(abs(r["found_params"]["delay"]["delay_s"] / r["true_delay_s"] - 1))
        if "vibration" in r["truth"] and "vibration" in r["found_params"]:
            freq_err.append(abs(r["found_params"]["vibration"]["frequency_hz"] / r["params"]["vibration"]["frequency_hz"] - 1))
    shrink = [1 - r["blind_after"] / r["blind_before"] for r in results if r["truth"]]
    shrink_ref = [1 - r["blind_after"] / r["blind_ref"] for r in results if r["truth"] and "blind_ref" in r]
    shrink_ref_none = [1 - r["blind_after"] / r["blind_ref"] for r in nones if "blind_ref" in r]
    out = {"median_shrink_vs_interpolated": float(np.median(shrink_ref)) if shrink_ref else float("nan"),
           "top1": top1, "both": both, "false_alarms": false_alarms, "n_none": len(nones),
           "delay_err": delay_err, "freq_err": freq_err, "median_shrink": float(np.median(shrink)) if shrink else float("nan"),
           "results": results}
    if verbose:
        print("## Blind validation of `preisach diagnose`\n")
        print(f"{len(results)} stages: {len(nones)} none, {len(singles)} single effect, {len(pairs)} pairs.\n")
        print("### Confusion matrix (true effect → dominant effect reported)\n")
        print("| true \\ found | " + " | ".join(labels) + " |")
        print("|---" * (len(labels) + 1) + "|")
        for a in conf:
            print(f"| {a} | " + " | ".join(str(conf[a][b]) for b in labels) + " |")
        print(f"\n- top-1 on single effects: **{top1:.0%}** (goal ≥ 95 %)")
        print(f"- both effects found in pairs: **{both:.0%}** (goal ≥ 90 %)")
        print(f"- false alarms on `none` stages: **{false_alarms} / {len(nones)}** (goal 0)")
        if delay_err:
            print(f"- delay error: median {np.median(delay_err):.1%}, max {max(delay_err):.1%}; within 10 %: "
                  f"{np.mean(np.array(delay_err) <= 0.10):.0%}")
        if freq_err:
            print(f"- mode frequency error: median {np.median(freq_err):.2%}, max {max(freq_err):.2%}; within 3 %: "
                  f"{np.mean(np.array(freq_err) <= 0.03):.0%}")
        print(f"- realised shrink on the unseen record (stages with effects): median **{out['median_shrink']:.0%}** (goal ≥ 70 %)")
        if shrink_ref:
            print(f"- the same against a fairer before (the interpolated model refitted with no effect): median "
                  f"**{out['median_shrink_vs_interpolated']:.0%}** on stages with effects"
                  + (f", {np.median(shrink_ref_none):.0%} on `none` stages" if shrink_ref_none else ""))
        secs = [r["seconds"] for r in results]
        print(f"- diagnosis time per stage: median {np.median(secs):.1f} s, max {max(secs):.1f} s\n")
        print("### Per stage\n")
        print("| truth | found | blind RMSE before → after | shrink | interpolated refit → after | parameters (found / true) |")
        print("|---|---|---|---|---|---|")
        for r in results:
            s = 1 - r["blind_after"] / r["blind_before"]
            ref = f"{r['blind_ref']:.4g} → {r['blind_after']:.4g}" if "blind_ref" in r else "—"
            par = []
            fp, tp = r["found_params"], r["params"]
            if "delay" in fp and "delay" in tp:
                par.append(f"delay {fp['delay']['delay_s'] * 1e3:.3g} / {r['true_delay_s'] * 1e3:.3g} ms")
            if "vibration" in fp and "vibration" in tp:
                par.append(f"mode {fp['vibration']['frequency_hz']:.4g} / {tp['vibration']['frequency_hz']:.4g} Hz")
            if "lowpass" in fp and "lowpass" in tp:
                par.append(f"low-pass {fp['lowpass']['cutoff_hz']:.4g} / {tp['lowpass']['cutoff_hz']:.4g} Hz")
            print(f"| {'+'.join(r['truth']) or 'none'} | {', '.join(r['found']) or 'none'} | "
                  f"{r['blind_before']:.4g} → {r['blind_after']:.4g} | {s:.0%} | {ref} | {'; '.join(par)} |")
    return out


def _reference(u: np.ndarray, y: np.ndarray) -> PreisachModel:
    """A fairer "before" than the baseline: the same model class the augmented chain uses
    (interpolated output, range 5 % wider than the training input), refitted with no
    effect, keeping only the masses the training record identifies (the chain's own rule,
    ``preisach.diagnose.identified``: the others would show as an offset on a record
    that starts elsewhere)."""
    from preisach.diagnose.identified import identified

    pad = 0.05 * float(np.ptp(u))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = PreisachModel.fit(u, y, 40, u_range=(float(u.min()) - pad, float(u.max()) + pad),
                                output="interpolated")
    return identified(ref, u)


def _rmse(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x)))


def run_rig(n_per_class: int = 2, seed: int = 1, verbose: bool = True,
            classes: tuple[str, ...] = tuple(rig.CLASSES)) -> list[dict[str, Any]]:
    """The rig's classes (``tests/rig.py``), ``n_per_class`` stages each: the diagnosis
    on the training record and two holdouts, its saved chain scored on a further record
    it never saw (against the interpolated model refitted with no effect, the fairer
    before). Prints the per-class table; returns the raw results."""
    from preisach.chain import Chain
    from preisach.diagnose import diagnose

    results = []
    for c, name in enumerate(rig.CLASSES):
        if name not in classes:
            continue
        for i in range(n_per_class):
            # (The same stages whichever classes run.)
            case = rig.make_case(name, seed * 1000 + 37 * i + c * n_per_class + i)
            tr, hos = rig.records(case)
            truth = case["truth"]
            t0 = time.perf_counter()
            rep = diagnose(tr, hos, progress=False)
            el = time.perf_counter() - t0
            b = case["blind"]
            ch = Chain.from_dict(rep.augmented_chain_dict())
            ref = _reference(tr["u"], tr["y"])
            found = {e["name"]: e["params"] for e in rep.effects if e["detected"]}
            r = {"class": name, "truth": tuple(truth["effects"]), "dominant": rep.dominant_effect,
                 "found": list(found), "params": found, "seconds": el,
                 "blind_ref": _rmse(ref.predict(b["u"]) - b["y"]), "blind_after": _rmse(ch.predict(b["t"], b["u"]) - b["y"]),
                 "at_bound": {e["name"]: e["at_bound"] for e in rep.effects if e.get("at_bound")}}
            if "delay" in found and truth["delay_s"]:
                r["delay_err"] = abs(found["delay"]["delay_s"] / (truth["delay_s"] + truth["timing_s"]) - 1)
            if "vibration" in found and truth["modes"]:
                r["freq_err"] = abs(found["vibration"]["frequency_hz"] / truth["modes"][0][0] - 1)
            results.append(r)
            if verbose:
                print(f"<!-- rig {name} #{i}: truth={r['truth'] or ('none',)} found={r['found']} "
                      f"blind {r['blind_ref']:.4g}->{r['blind_after']:.4g} ({el:.1f}s){_detected_at_bound(r)} -->",
                      file=sys.stderr, flush=True)
    if verbose:
        summarize_rig(results)
    return results


def summarize_rig(results: list[dict[str, Any]]) -> None:
    """The per-class Markdown table."""
    print("| class | truth | right dominant | all true effects found | false alarms | delay within 10 % | "
          "mode within 3 % | unseen record: interpolated refit → chain (median) | time (median) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in rig.CLASSES:
        rs = [r for r in results if r["class"] == name]
        if not rs:
            continue
        truth = rs[0]["truth"]
        right = sum(r["dominant"] == (truth[0] if truth else "none") for r in rs)
        allf = sum(set(truth) <= set(r["found"]) for r in rs)
        fa = sum(bool(set(r["found"]) - set(truth) - {"discretization"}) for r in rs)
        de = [r["delay_err"] for r in rs if "delay_err" in r]
        fe = [r["freq_err"] for r in rs if "freq_err" in r]
        n = len(rs)
        print(f"| {name} | {'+'.join(truth) or 'none'} | {right} / {n} | {allf} / {n} | {fa} / {n} | "
              f"{sum(x <= 0.1 for x in de)} / {len(de)} | {sum(x <= 0.03 for x in fe)} / {len(fe)} | "
              f"{np.median([r['blind_ref'] for r in rs]):.3g} → {np.median([r['blind_after'] for r in rs]):.3g} | "
              f"{np.median([r['seconds'] for r in rs]):.1f} s |")
    tot = len(results)
    right = sum(r["dominant"] == (r["truth"][0] if r["truth"] else "none") for r in results)
    print(f"\n- right dominant effect over all rig classes: **{right} / {tot}** (goal ≥ 95 %)")
    print("\n| class | found (dominant first) | parameters | at a search bound |")
    print("|---|---|---|---|")
    for r in results:
        par = []
        if "delay" in r["params"]:
            par.append(f"delay {1e3 * r['params']['delay']['delay_s']:.3g} ms")
        if "vibration" in r["params"]:
            par.append(f"mode {r['params']['vibration']['frequency_hz']:.4g} Hz")
        print(f"| {r['class']} | {', '.join(r['found']) or 'none'} | {'; '.join(par)} | "
              f"{'; '.join(f'{k}: {v}' for k, v in r['at_bound'].items())} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stages", type=int, default=3, help="stages per single-effect class and for none")
    ap.add_argument("--pairs", type=int, default=None, help="stages per pair of effects (default: a third of --stages)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--fs", type=float, default=50e3)
    ap.add_argument("--rig", type=int, default=None, help="stages per class of the rig (tests/rig.py) instead")
    ap.add_argument("--classes", default=None, help="with --rig: only these classes (comma-separated)")
    ap.add_argument("--timing", default=None, help="time one 100 kHz stage with these effects ('none' or e.g. delay+creep)")
    ap.add_argument("--input-noise", type=float, default=0.0,
                    help="with --timing: white noise on every record's input, as a fraction of its range "
                         "(a measured drive voltage rather than the command)")
    a = ap.parse_args()
    if a.timing is not None:
        from preisach.diagnose import diagnose

        names = () if a.timing in ("", "none") else tuple(a.timing.split("+"))
        unknown = [x for x in names if x not in EFFECTS]
        if unknown:
            ap.error(f"--timing: unknown effect {', '.join(unknown)} (one of none, {', '.join(EFFECTS)})")
        if not (np.isfinite(a.input_noise) and a.input_noise >= 0):
            ap.error(f"--input-noise: expected a fraction >= 0, got {a.input_noise}")
        st = make_stage(7, names, fs=100e3, dur=2.0)
        noise = np.random.default_rng(5)

        def measured(r: dict[str, Any]) -> dict[str, Any]:
            u = np.asarray(r["u"], dtype=np.float64)
            return {"t": r["t"], "u": u + a.input_noise * np.ptp(u) * noise.standard_normal(u.size), "y": r["y"]}

        t0 = time.perf_counter()
        rep = diagnose(measured(st["train"]), [measured(h) for h in st["holdouts"]], progress=True)
        el = time.perf_counter() - t0
        found = [e["name"] for e in rep.effects if e["detected"]]
        print(f"truth {names or ('none',)}: found {found or ['none']} in {el:.1f} s "
              f"(6 s of 100 kHz data, {len(CANDIDATES_ALL)} candidates)")
        return 0
    if a.rig is not None:
        names = tuple(a.classes.split(",")) if a.classes else tuple(rig.CLASSES)
        unknown = [x for x in names if x not in rig.CLASSES]
        if unknown:
            ap.error(f"--classes: unknown class {', '.join(unknown)} (one of {', '.join(rig.CLASSES)})")
        run_rig(a.rig, a.seed, classes=names)
        return 0
    run(a.stages, a.seed, a.fs, n_per_pair=a.pairs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
