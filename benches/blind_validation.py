"""Blind validation of ``preisach.diagnose``.

Draws simulated stages with one effect, two effects or none (random parameters in
realistic ranges), runs the diagnoser on a training record and holdouts without
telling it the answer, then scores the augmented chain it saved on a further record
it never saw. Prints Markdown: confusion matrix, false alarms on ``none`` stages,
parameter recovery and realised shrink.

The ground truth here is simulated independently of ``preisach.chain``: a fine-grid
(n_h = 120) interpolated Preisach model with a smooth random density, SciPy filters
(bilinear Butterworth low-pass, zero-order-hold modes, exact first-order creep
elements, integer + linear-interpolation delay), drift in absolute time and white
sensor noise. SciPy is a test/bench dependency only.

Usage: python benches/blind_validation.py [--stages N] [--seed S] [--fs HZ]
       python benches/blind_validation.py --timing EFFECT[+EFFECT]  (6 s of 100 kHz data:
       2 s train + two 2 s holdouts; prints the per-candidate times and the total)
"""
from __future__ import annotations

import argparse
import itertools
import math
import sys
import time
import warnings
from typing import Any

import numpy as np
from scipy import signal

from preisach import PreisachModel

EFFECTS = ("delay", "lowpass", "vibration", "creep", "drift")
CANDIDATES_ALL = ("delay", "lowpass", "vibration", "creep", "drift", "rate", "discretization")
U_LO, U_HI = 0.0, 100.0


# ----------------------------------------------------------------------------- truth
def true_hysteresis(rng: np.random.Generator, n_h: int = 120) -> PreisachModel:
    """A smooth random Preisach density (a bump along the diagonal plus a broad part),
    scaled so the output spans about 15 µm."""
    lv = np.linspace(U_LO, U_HI, n_h + 1)
    c = (lv[:-1] + lv[1:]) / 2
    B, A = np.meshgrid(c, c, indexing="ij")
    width = rng.uniform(8, 25)
    centre = rng.uniform(35, 65)
    spread = rng.uniform(25, 60)
    w = np.exp(-((A - B) / width) ** 2) * np.exp(-(((A + B) / 2 - centre) / spread) ** 2)
    w += 0.2 * np.exp(-((A - B) / (2 * width)) ** 2)
    w = np.where(A >= B, w, 0.0)
    w *= 15.0 / (2 * w.sum())
    return PreisachModel(w, (U_LO, U_HI), rng.uniform(-1, 1), "interpolated")


def draw_effects(rng: np.random.Generator, names: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """Random parameters in the issue's realistic ranges."""
    out: dict[str, dict[str, Any]] = {}
    for n in names:
        if n == "delay":
            out[n] = {"delay_s": rng.uniform(1e-4, 1e-3)}
        elif n == "lowpass":
            out[n] = {"cutoff_hz": rng.uniform(300, 1500), "order": int(rng.integers(1, 3))}
        elif n == "vibration":
            out[n] = {"frequency_hz": rng.uniform(500, 2000), "damping": math.exp(rng.uniform(math.log(0.005), math.log(0.05)))}
        elif n == "creep":
            tau = math.exp(rng.uniform(math.log(0.01), math.log(10)))
            out[n] = {"taus_s": [tau], "amplitudes": [rng.uniform(0.01, 0.10)]}
        elif n == "drift":
            out[n] = {"gain_per_s": rng.choice([-1, 1]) * rng.uniform(0.005, 0.02),
                      "offset": rng.uniform(-0.3, 0.3), "offset_per_s": rng.uniform(-0.05, 0.05)}
    return out


def simulate(h_model: PreisachModel, eff: dict[str, dict[str, Any]], t: np.ndarray, u: np.ndarray,
             noise: float, rng: np.random.Generator) -> np.ndarray:
    """The true stage: hysteresis -> creep -> mode -> low-pass -> delay -> drift -> noise."""
    fs = 1.0 / float(np.median(np.diff(t)))
    x = h_model.predict(u)

    def filt(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
        zi = signal.lfilter_zi(b, a) * x[0]
        return signal.lfilter(b, a, x, zi=zi)[0]

    if "creep" in eff:
        p = eff["creep"]
        y = x.copy()
        for tau, c in zip(p["taus_s"], p["amplitudes"]):
            a = math.exp(-1 / (fs * tau))
            y += c * filt(np.array([1 - a]), np.array([1.0, -a]), x)
        x = y
    if "vibration" in eff:
        p = eff["vibration"]
        w = 2 * math.pi * p["frequency_hz"]
        b, a, _ = signal.cont2discrete(([w * w], [1, 2 * p["damping"] * w, w * w]), 1 / fs, method="zoh")
        x = filt(np.ravel(b), np.ravel(a), x)
    if "lowpass" in eff:
        p = eff["lowpass"]
        b, a = signal.butter(p["order"], p["cutoff_hz"], fs=fs)
        x = filt(b, a, x)
    if "delay" in eff:
        D = eff["delay"]["delay_s"] * fs
        k = int(math.floor(D))
        f = D - k
        xp = np.concatenate([np.full(k + 1, x[0]), x])
        x = (1 - f) * xp[1:x.size + 1] + f * xp[0:x.size]
    if "drift" in eff:
        p = eff["drift"]
        x = x * (1 + p["gain_per_s"] * t) + p["offset"] + p["offset_per_s"] * t
    return x + noise * rng.standard_normal(x.size)


def waveform(kind: str, fs: float, dur: float, rng: np.random.Generator) -> np.ndarray:
    """Input signals: a reversal-rich training sweep, sines, triangles, steps with dwell."""
    t = np.arange(int(round(dur * fs))) / fs
    mid, amp = 50.0, 45.0
    if kind == "train":
        # Decaying multi-tone: many nested reversals, several rates, plus a few steps.
        # Two decaying bursts: large loops early and late, so a slow drift in time is not
        # confounded with the input level.
        # The first 7 Hz cycle of each burst keeps the full amplitude, and 63 Hz = 9 x 7 Hz
        # puts the top of the sweep at the top of the range: the training record covers
        # the holdouts' input range (otherwise the gap is extrapolation, not an effect).
        env = 0.15 + 0.85 * np.exp(-np.maximum(0.0, (t % (dur / 2)) - 1 / 7) / (dur / 6))
        # Starts at rest at the bottom; the first cycles span the whole range.
        s = 0.8 * np.cos(2 * np.pi * 7 * t) + 0.2 * np.cos(2 * np.pi * 63 * t)
        u = mid - amp * env * s
        steps = np.zeros_like(t)
        for k, tk in enumerate(np.arange(0.6, dur, dur / 5)):
            steps += (t >= tk) * (6.0 if k % 2 == 0 else -6.0)
        u = u + steps * (t > 0.5)
    elif kind == "sine":
        f = rng.uniform(20, 60)
        u = mid + amp * 0.9 * np.sin(2 * np.pi * f * t - np.pi / 2) * np.minimum(1, t / 0.05)
    elif kind == "triangle":
        f = rng.uniform(10, 40)
        ph = (t * f) % 1.0
        u = mid - amp * 0.9 + 2 * amp * 0.9 * np.where(ph < 0.5, 2 * ph, 2 - 2 * ph)
    elif kind == "steps":
        levels = rng.uniform(mid - 0.9 * amp, mid + 0.9 * amp, size=8)
        edges = np.linspace(0, dur, 9)[:-1]
        u = np.full_like(t, mid - 0.9 * amp)
        for e, lv in zip(edges[1:], levels):
            u[t >= e] = lv
    elif kind == "reversals":
        pts = mid + 0.9 * amp * np.array([-1, 1, -0.6, 0.7, -0.3, 0.4, 0.0, 0.9, -0.9, 0.2, -0.5, 0.6])
        u = np.interp(t, np.linspace(0, dur, pts.size), pts)
    else:
        raise ValueError(kind)
    return np.clip(u, U_LO, U_HI)


def make_stage(seed: int, names: tuple[str, ...], fs: float = 50e3, dur: float = 1.5,
               noise: float = 0.003) -> dict[str, Any]:
    """One stage: truth + records (train, two holdouts, one further blind record).
    Absolute time runs on across records."""
    rng = np.random.default_rng(seed)
    hm = true_hysteresis(rng)
    eff = draw_effects(rng, names)
    recs = []
    t0 = 0.0
    for kind in ("train", "triangle", "steps", rng.choice(["sine", "reversals", "steps"])):
        u = waveform(str(kind), fs, dur, rng)
        t = t0 + np.arange(u.size) / fs
        y = simulate(hm, eff, t, u, noise, rng)
        recs.append({"t": t, "u": u, "y": y, "kind": str(kind)})
        t0 = t[-1] + 1.0 / fs
    return {"seed": seed, "truth": names, "params": eff, "train": recs[0], "holdouts": recs[1:3], "blind": recs[3]}


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
            # A fairer "before": the same model class the augmented chain uses (interpolated
            # output, range 5 % wider than the training input), refitted here with no effect.
            tu, ty = st["train"]["u"], st["train"]["y"]
            pad = 0.05 * float(np.ptp(tu))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ref = PreisachModel.fit(tu, ty, 40, u_range=(float(tu.min()) - pad, float(tu.max()) + pad),
                                        output="interpolated")
            rr = float(np.sqrt(np.mean((ref.predict(b["u"]) - b["y"]) ** 2)))
            found = [e["name"] for e in rep.effects if e["detected"]]
            results.append({"blind_ref": rr, "truth": cls, "params": st["params"], "found": found, "dominant": rep.dominant_effect,
                            "found_params": {e["name"]: e["params"] for e in rep.effects if e["detected"]},
                            "blind_before": rb, "blind_after": ra, "seconds": el})
            if verbose:
                print(f"<!-- stage {k}: truth={cls or ('none',)} found={found} blind {rb:.4g}->{ra:.4g} ({el:.1f}s) -->",
                      file=sys.stderr, flush=True)
    return summarize(results, verbose)


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
            delay_err.append(abs(r["found_params"]["delay"]["delay_s"] / r["params"]["delay"]["delay_s"] - 1))
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
                  f"**{out['median_shrink_vs_interpolated']:.0%}** on stages with effects, "
                  f"{np.median(shrink_ref_none):.0%} on `none` stages")
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
                par.append(f"delay {fp['delay']['delay_s'] * 1e3:.3g} / {tp['delay']['delay_s'] * 1e3:.3g} ms")
            if "vibration" in fp and "vibration" in tp:
                par.append(f"mode {fp['vibration']['frequency_hz']:.4g} / {tp['vibration']['frequency_hz']:.4g} Hz")
            if "lowpass" in fp and "lowpass" in tp:
                par.append(f"low-pass {fp['lowpass']['cutoff_hz']:.4g} / {tp['lowpass']['cutoff_hz']:.4g} Hz")
            print(f"| {'+'.join(r['truth']) or 'none'} | {', '.join(r['found']) or 'none'} | "
                  f"{r['blind_before']:.4g} → {r['blind_after']:.4g} | {s:.0%} | {ref} | {'; '.join(par)} |")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stages", type=int, default=3, help="stages per single-effect class and for none")
    ap.add_argument("--pairs", type=int, default=None, help="stages per pair of effects (default: a third of --stages)")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--fs", type=float, default=50e3)
    ap.add_argument("--timing", default=None, help="time one 100 kHz stage with these effects ('none' or e.g. delay+creep)")
    a = ap.parse_args()
    if a.timing is not None:
        from preisach.diagnose import diagnose

        names = () if a.timing in ("", "none") else tuple(a.timing.split("+"))
        unknown = [x for x in names if x not in EFFECTS]
        if unknown:
            ap.error(f"--timing: unknown effect {', '.join(unknown)} (one of none, {', '.join(EFFECTS)})")
        st = make_stage(7, names, fs=100e3, dur=2.0)
        t0 = time.perf_counter()
        rep = diagnose(st["train"], [{k: h[k] for k in "tuy"} for h in st["holdouts"]], progress=True)
        el = time.perf_counter() - t0
        found = [e["name"] for e in rep.effects if e["detected"]]
        print(f"truth {names or ('none',)}: found {found or ['none']} in {el:.1f} s "
              f"(6 s of 100 kHz data, {len(CANDIDATES_ALL)} candidates)")
        return 0
    run(a.stages, a.seed, a.fs, n_per_pair=a.pairs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
