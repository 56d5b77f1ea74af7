"""Compensation: the hysteresis inverse alone against the chain inverse, side by side.

Three parts, printed as Markdown tables under the machine line:

1. **One effect at a time** on the project's simulator at 100 kHz: a smooth Preisach
   model (n_h = 100) followed by one effect (delay 0.3 ms; 2nd-order low-pass at
   1 kHz; a mode at 780 Hz, damping 0.02; creep of 1 % per decade, 0.1–10 s), run in
   the sample loop (``run_loop``) on 5 Hz and 50 Hz sines over 30 % of the output range,
   compensated by the hysteresis inverse of the true model (continuous) and by the chain
   inverse of the true chain.
2. **The ``paper`` preset** as ``preisach demo`` runs it (n_h = 100 identified, 10 µm
   references at 5 Hz and 50 Hz, the demo's peak error after the lead-in and one period),
   with the chain the diagnosis found (its hysteresis refitted at n_h = 100 behind its
   linear part and its creep refitted behind that on the demo's held steps, as the demo
   compensates) and with the preset's true linear part after an
   n_h = 100 model refitted behind it the same way (this separates the diagnosis's error
   from the inverse's).
3. **The independent rig** (``tests/rig.py``: no project block, a generalized
   Prandtl–Ishlinskii hysteresis) of class ``paper_mode_delay``: identified (n_h = 100)
   and diagnosed from its own records, then 5 Hz and 50 Hz feed-forward references
   (10 µm = 2 V of sensor output) recorded on the rig; the diagnosed chain as found and
   with its hysteresis refitted at n_h = 100 behind its linear part on the training
   record (``refit_hysteresis``, as ``preisach demo`` compensates).

Errors are in percent of the reference's amplitude (peak, RMS).

    python benches/compensation.py [--quick] [--rig-seeds 1,2,3]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe  # noqa: E402

FS = 100e3


def _errors(r: np.ndarray, y: np.ndarray, skip: int, amp: float) -> tuple[float, float]:
    e = (r - y)[skip:]
    return float(np.abs(e).max() / amp * 100), float(np.sqrt(np.mean(e ** 2)) / amp * 100)


def _smooth_model(n_h: int = 100) -> Any:
    from preisach import PreisachModel

    i, j = np.meshgrid(np.arange(n_h), np.arange(n_h), indexing="ij")
    c, m = (j - i) / n_h, (i + j) / (2 * n_h) - 0.5
    w = np.exp(-((c - 0.15) ** 2) / 0.02 - m ** 2 / 0.1) + 2.0 * (i == j)
    w = np.triu(w)
    return PreisachModel(w * 15.0 / (2 * w.sum()), (0.0, 10.0), 0.0, "interpolated")


EFFECTS = {
    "delay": {"delay": {"delay_s": 3e-4}},
    "low-pass": {"lowpass": {"cutoff_hz": 1000.0, "order": 2}},
    "mode": {"vibration": {"frequency_hz": 780.0, "damping": 0.02}},
    "creep": {"creep": {"taus_s": [0.1, 1.0, 10.0], "amplitudes": [0.01, 0.01, 0.01]}},
}


def per_effect(quick: bool) -> list[dict[str, Any]]:
    from preisach import Chain
    from preisach.sim import Stage, run_loop

    model = _smooth_model()
    rows = []
    for name, eff in EFFECTS.items():
        chain = Chain(model, eff)
        stage = Stage(chain.blocks, sample_rate_hz=FS)
        gain = 1.0 + sum(eff.get("creep", {}).get("amplitudes", []))
        for f in (5.0, 50.0):
            n = int(FS * (2 if quick else 3) / f) if f < 10 else int(FS * (5 if quick else 10) / f)
            amp = 0.3 * 15.0
            r = gain * (-amp * np.cos(2 * np.pi * f * np.arange(n) / FS))
            skip = int(FS / f)
            h = run_loop(model, stage, r)
            c = run_loop(chain, stage, r)
            rows.append({"effect": name, "f": f, "hyst": _errors(r, h.y, skip, gain * amp),
                         "chain": _errors(r, c.y, skip, gain * amp)})
    return rows


#: The `paper` preset's linear blocks after its hysteresis (the DAC's 20 kHz
#: reconstruction filter moved behind it), in sensor volts.
PAPER_POST = [{"type": "creep", "taus_s": [0.1, 1.0, 10.0, 100.0], "amplitudes": [0.01] * 4},
              {"type": "lowpass", "cutoff_hz": 20e3, "order": 2},
              {"type": "vibration", "modes": [{"frequency_hz": 780.0, "damping": 0.02}]},
              {"type": "sensor", "gain": 0.2, "lowpass": {"cutoff_hz": 20e3, "order": 4}}]


def _identified_through_true_effects() -> Any:
    """n_h = 100 identified on the demo's identification record behind the preset's true
    linear part (``refit_hysteresis``: the record with that part inverted), followed by
    that part."""
    import preisach
    from preisach import demo
    from preisach._refit import refit_hysteresis
    from preisach.sim import Stage

    u, n_sine = demo.identification_input(False)
    y = demo._record(Stage.preset("paper"), u)[:n_sine]
    start = preisach.Chain.from_blocks(preisach.Chain(preisach.PreisachModel(np.eye(2), (0.0, 1.0), 0.0)).blocks
                                       + PAPER_POST)
    return refit_hysteresis(start, np.arange(n_sine) / FS, u[:n_sine], y, n_h=100)


def paper(quick: bool) -> list[dict[str, Any]]:
    import preisach
    from preisach import demo
    from preisach.sim import Stage, run_loop

    with tempfile.TemporaryDirectory() as d:
        res = demo.run(d, quick=quick, plots=False, progress=None)
        diagnosed = preisach.Chain.load(Path(d) / "diagnosis_chain.json")
    by = {r["label"]: r for r in res.tracking}
    true_chain = _identified_through_true_effects()
    model = true_chain.model
    stage = Stage.preset("paper")
    sv = demo.SENSOR_V_PER_UM
    w = float(model.weights.sum())
    centre, amp = 20.0 * sv, 10.0 * sv
    rows = []
    for f in (5.0, 50.0):
        periods = (2 if f < 10 else 5) if quick else (3 if f < 10 else 10)
        lead_n = int(0.05 * FS)
        tr = np.arange(int(round(periods / f * FS))) / FS
        r = np.concatenate([demo._ramp(max(sv * (model.offset - w), 0.0), centre - amp, lead_n),
                            centre - amp * np.cos(2 * np.pi * f * tr)])
        y = run_loop(true_chain, stage, r).y
        skip = lead_n + int(FS / f)
        h = by[f"n_h=100  {f:g} Hz  continuous"]
        c = by.get(f"diagnosed chain  {f:g} Hz  chain inverse")
        rows.append({"f": f, "hyst": (h["max_pct"], h["rms_um"] * sv / amp * 100),
                     "diagnosed": None if c is None else (c["max_pct"], c["rms_um"] * sv / amp * 100),
                     "true": _errors(r, y, skip, amp)})
    return [{"rows": rows, "chain": " -> ".join(diagnosed.kinds()), "effects": res.diagnosis["augmented"]["effects"]}]


def rig(seeds: list[int], quick: bool) -> list[dict[str, Any]]:
    import preisach
    from preisach._refit import refit_hysteresis
    from rig import make_case, records

    out = []
    for seed in seeds:
        case = make_case("paper_mode_delay", seed)
        fs = case["fs"]
        train, hold = records(case)
        model = preisach.PreisachModel.fit(train["u"], train["y"], 100)
        gap = preisach.diagnose(train, hold, n_h=20 if quick else 40, progress=False)
        chain = gap.chain
        if chain.model is not None and "rate" not in chain.kinds():
            refit = refit_hysteresis(chain, train["t"], train["u"], train["y"], n_h=100)
        w = float(model.weights.sum())
        lo, hi = model.offset - w, model.offset + w
        amp = min(2.0, 0.35 * (hi - lo))
        centre = 0.5 * (lo + hi)
        for f in (5.0, 50.0):
            n = int(fs * (3 if f < 10 else 10) / f)
            r = centre - amp * np.cos(2 * np.pi * f * np.arange(n) / fs)
            skip = int(fs / f)
            runs = {"hyst": model.invert(r, method="continuous")}
            if chain.model is not None and "rate" not in chain.kinds():
                runs["chain"] = chain.invert(r, fs)
                runs["refit"] = refit.invert(r, fs)
            errs = {}
            for k, u in runs.items():
                y = case["rig"].record(np.clip(u, 0.0, 10.0), fs, rng=np.random.default_rng(seed))["y"]
                errs[k] = _errors(r, y, skip, amp)
            out.append({"seed": seed, "f": f, "modes": case["truth"]["modes"], "delay_s": case["truth"]["delay_s"],
                        "found": " -> ".join(chain.kinds()), **errs})
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="shorter records, smaller diagnosis")
    p.add_argument("--rig-seeds", default="1,2,3", help="seeds of the rig stages (comma separated; '' for none)")
    a = p.parse_args(argv)
    print(describe())
    print()
    print("| effect | reference | hysteresis inverse: peak / RMS [%] | chain inverse: peak / RMS [%] |")
    print("|---|---:|---:|---:|")
    for row in per_effect(a.quick):
        print(f"| {row['effect']} | {row['f']:g} Hz | {row['hyst'][0]:.2f} / {row['hyst'][1]:.2f} | "
              f"{row['chain'][0]:.2f} / {row['chain'][1]:.2f} |")
    sys.stdout.flush()
    for part in paper(a.quick):
        print()
        print(f"`paper` preset, n_h = 100, 10 µm; diagnosed chain: {part['chain']} (effects {part['effects']})")
        print()
        print("| reference | hysteresis inverse: peak / RMS [%] | chain inverse, diagnosed chain | "
              "chain inverse, identified model + true effects |")
        print("|---:|---:|---:|---:|")
        for row in part["rows"]:
            d = "–" if row["diagnosed"] is None else f"{row['diagnosed'][0]:.2f} / {row['diagnosed'][1]:.2f}"
            print(f"| {row['f']:g} Hz | {row['hyst'][0]:.2f} / {row['hyst'][1]:.2f} | {d} | "
                  f"{row['true'][0]:.2f} / {row['true'][1]:.2f} |")
    sys.stdout.flush()
    seeds = [int(s) for s in a.rig_seeds.split(",") if s.strip()]
    if seeds:
        print()
        print("Independent rig, class `paper_mode_delay`, identified (n_h = 100) and diagnosed from its own records:")
        print()
        print("| seed | mode [Hz] / delay [ms] | chain found | reference | hysteresis inverse: peak / RMS [%] | "
              "chain inverse, as diagnosed | chain inverse, hysteresis refitted (n_h = 100) |")
        print("|---:|---|---|---:|---:|---:|---:|")
        for row in rig(seeds, a.quick):
            modes = ", ".join(f"{m[0]:.0f}" for m in row["modes"])
            ch = ["–" if k not in row else f"{row[k][0]:.2f} / {row[k][1]:.2f}" for k in ("chain", "refit")]
            print(f"| {row['seed']} | {modes} / {row['delay_s'] * 1e3:.2f} | {row['found']} | {row['f']:g} Hz | "
                  f"{row['hyst'][0]:.2f} / {row['hyst'][1]:.2f} | {ch[0]} | {ch[1]} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
