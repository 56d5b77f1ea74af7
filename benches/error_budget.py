"""Error budget of compensation on the ``paper`` preset: what each part of the stage
and of the model adds to the peak tracking error (10 µm sines at 5 Hz and 50 Hz around
20 µm, after a 50 ms lead-in from rest and one period, as ``preisach demo`` measures).

The oracle is the simulator with blocks switched off one at a time, compensated by the
chain inverse of the *true* chain: the preset's linear blocks around an exact Preisach
model of its parametric hysteresis (500 levels; its reversible part as diagonal masses,
equal to the block to 1e-5 µm). Then the hysteresis model is replaced by identified
ones (n_h = 100 on the demo's identification sine), and the linear part by nothing (the
hysteresis inverse alone).

    python benches/error_budget.py
"""
from __future__ import annotations

import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import describe  # noqa: E402

FS = 100e3


def true_model(p: dict[str, Any]) -> Any:
    """The parametric hysteresis block ``p`` as a Preisach model (the core's density on
    its grid; the reversible part as diagonal masses, linear within each cell)."""
    import preisach

    lo, hi = p["u_range"]
    n = p["n_h"]
    d = (hi - lo) / n
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    beta, alpha = lo + (i + 0.5) * d, lo + (j + 0.5) * d
    h = np.where(i == j, d / 6, 0.5 * np.abs(alpha - beta) + (i > j))
    z = (np.log(h) - np.log(p["coercivity_median"])) / p["coercivity_sigma"]
    m = 0.5 * (alpha + beta)
    w = np.where(i == j, 0.5, 1.0) * np.exp(-0.5 * z * z) / h \
        * np.exp(-0.5 * ((m - p["interaction_mean"]) / p["interaction_sigma"]) ** 2)
    w = np.where(j >= i, w, 0.0)
    w *= 0.5 * p["hysteretic_stroke"] / w.sum()
    levels = lo + d * np.arange(n + 1)
    f = (p.get("offset", 0.0) + p["reversible_slope"] * (levels - lo)
         + p["reversible_saturation"] * np.tanh((levels - p["interaction_mean"]) / p["reversible_width"]))
    w[np.arange(n), np.arange(n)] += np.diff(f) / 2
    return preisach.PreisachModel(w, (lo, hi), 0.5 * p["hysteretic_stroke"] + 0.5 * (f[0] + f[-1]), "interpolated")


def stage_blocks(off: tuple[str, ...] = ()) -> list[dict[str, Any]]:
    """The preset's blocks with some switched off: ``creep``, ``vibration``, ``lowpass``
    (the DAC's and the sensor's filters), ``noise``, ``quantization``, ``saturation``."""
    from preisach.sim import Stage

    out = []
    for b in Stage.preset("paper").blocks:
        kind = b["type"]
        if (kind == "quantizer" and "quantization" in off) or (kind == "lowpass" and "lowpass" in off) \
                or kind in off:
            continue
        if kind == "amplifier" and "saturation" in off:
            b["saturation"] = None
        if kind == "sensor":
            b["noise_std"] = 0.0 if "noise" in off else b["noise_std"]
            b["adc"] = None if "quantization" in off else b["adc"]
            b["lowpass"] = None if "lowpass" in off else b["lowpass"]
        out.append(b)
    return out


def linear_part(blocks: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """The invertible blocks before and after the hysteresis (noise, quantizers and the
    amplifier's saturation left out)."""
    pre: list[dict[str, Any]] = []
    post: list[dict[str, Any]] = []
    side = pre
    for b in blocks:
        if b["type"] == "hysteresis":
            side = post
        elif b["type"] == "amplifier":
            side.append({"type": "amplifier", "gain": b["gain"]})
        elif b["type"] == "sensor":
            side.append({"type": "sensor", "gain": b["gain"], "lowpass": b["lowpass"]})
        elif b["type"] != "quantizer":
            side.append(b)
    return pre, post


def track(chain: Any, blocks: list[dict[str, Any]], f_hz: float, lead_s: float = 0.05) -> float:
    """Peak error [% of the amplitude] of the chain inverse of ``chain`` run on the stage
    of ``blocks`` in the 100 kHz loop (``lead_s``: the reference's lead-in from rest)."""
    from preisach import demo
    from preisach.sim import Stage, run_loop

    sv = demo.SENSOR_V_PER_UM
    centre, amp = 20 * sv, 10 * sv
    lead = int(lead_s * FS)
    tr = np.arange(int(round((3 if f_hz < 10 else 10) / f_hz * FS))) / FS
    r = np.concatenate([demo._ramp(0.0, centre - amp, lead), centre - amp * np.cos(2 * np.pi * f_hz * tr)])
    y = run_loop(chain, Stage(blocks, sample_rate_hz=FS), r).y
    return float(np.abs(r - y)[lead + int(FS / f_hz):].max() / amp * 100)


def row(label: str, chain: Any, blocks: list[dict[str, Any]], lead_s: float = 0.05) -> None:
    print(f"| {label} | {track(chain, blocks, 5.0, lead_s):.2f} | {track(chain, blocks, 50.0, lead_s):.2f} |",
          flush=True)


def main() -> int:
    import preisach
    from preisach import demo
    from preisach._refit import refit_hysteresis
    from preisach.sim import Stage

    warnings.simplefilter("ignore", preisach.PreisachWarning)
    print(describe())
    print()
    print("| compensation; stage | 5 Hz peak [%] | 50 Hz peak [%] |")
    print("|---|---:|---:|")
    hyst = next(b for b in Stage.preset("paper").blocks if b["type"] == "hysteresis")
    tm = preisach.Chain(true_model(hyst)).blocks
    for off in [(), ("noise", "quantization"), ("creep",), ("vibration",), ("lowpass",), ("saturation",),
                ("noise", "quantization", "creep", "vibration", "lowpass")]:
        blocks = stage_blocks(off)
        pre, post = linear_part(blocks)
        row(f"true chain; {'full stage' if not off else 'without ' + ', '.join(off)}",
            preisach.Chain.from_blocks(pre + tm + post), blocks)
    full = stage_blocks()
    pre, post = linear_part(full)
    for off in [(), ("creep",), ("vibration", "lowpass"), ("creep", "vibration", "lowpass")]:
        blocks = stage_blocks(off)
        row(f"true hysteresis inverse alone; {'full stage' if not off else 'without ' + ', '.join(off)}",
            preisach.Chain.from_blocks([{"type": "amplifier", "gain": 20.0}] + tm + [{"type": "sensor", "gain": 0.2}]),
            blocks)
    # Identified models (input: DAC volts; output: µm), behind the true linear part.
    u, n_sine = demo.identification_input(False)
    us = u[:n_sine]
    h = true_model(hyst).predict(20.0 * us)
    dac = [b for b in pre if b["type"] != "amplifier"]
    for kind in ("stepwise", "interpolated"):
        for floor in (preisach.model.DIAGONAL_FLOOR, 0.0):
            for n_h in ((50, 100, 200) if kind == "interpolated" and floor else (100,)):
                m = preisach.PreisachModel.fit(us, h, n_h, output=kind, diagonal_floor=floor)
                m = preisach.PreisachModel(m.weights, m.u_range, m.offset, "interpolated")
                row(f"n_h = {n_h} fitted ({kind}, floor {floor:g}) on the clean hysteresis output + true linear part",
                    preisach.Chain.from_blocks(dac + preisach.Chain(m).blocks + post), full)
    y = demo._record(Stage.preset("paper"), u)[:n_sine]
    t = np.arange(n_sine) / FS
    # Creep as the chain models it (the rest of the linear part true), the hysteresis
    # refitted behind it each time.
    creeps = [("the true bank (0.1-100 s, 1 % each)", next(b for b in post if b["type"] == "creep")),
              ("0.1 s and 1 s, 1 % each", {"type": "creep", "taus_s": [0.1, 1.0], "amplitudes": [0.01] * 2}),
              ("one element, 0.46 s, 2.1 %", {"type": "creep", "taus_s": [0.46], "amplitudes": [0.021]}),
              ("one element, 25 ms, 1.9 %", {"type": "creep", "taus_s": [0.025], "amplitudes": [0.019]}),
              ("none", None)]
    for label, cr in creeps:
        rest = [b for b in post if b["type"] != "creep"]
        start = preisach.Chain.from_blocks(dac + tm + ([cr] if cr else []) + rest)
        chain = refit_hysteresis(start, t, us, y, n_h=100)
        row(f"n_h = 100 refitted on the measured record behind the linear part, creep: {label}", chain, full)
        if cr is None:
            row("the same, the reference's lead-in 1 s (not 50 ms)", chain, full, lead_s=1.0)
    # The creep fitted again behind the refitted hysteresis on the demo's held steps.
    uc = demo.creep_input(False)
    held = (np.arange(uc.size) / FS, uc, demo._record(Stage.preset("paper"), uc))
    start = preisach.Chain.from_blocks(dac + tm + [b for b in post if b["type"] != "creep"])
    chain = refit_hysteresis(start, t, us, y, n_h=100, creep_records=[held])
    cr = next((b for b in chain.blocks if b["type"] == "creep"), {"taus_s": [], "amplitudes": []})
    fitted = ", ".join(f"{tau:.3g} s {c * 100:.2f} %" for tau, c in zip(cr["taus_s"], cr["amplitudes"]))
    row(f"n_h = 100 and creep refitted (`creep_records`: the demo's two 2 s holds; found {fitted or 'none'})",
        chain, full)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
