"""Write the version-1 files of this directory and their outputs (``outputs.npz``).

Run once, with the build that wrote version-1 files (before the chain format became
version 2); ``tests/test_golden.py`` checks that the current build reads every file,
gives the same outputs to rounding and round-trips it through version 2 exactly.

Files:

- ``model_stepwise.json``: a fitted ``preisach-model`` (stepwise, with its fit report);
- ``model_interpolated.json``: a hand-made ``preisach-model`` (interpolated output);
- ``chain_effects.json``: a ``preisach-chain`` as ``diagnose --save-model`` writes it,
  with every effect (rate, creep of two elements, vibration, low-pass, delay, drift);
- ``stage_paper.json``, ``stage_paper_delay_drift.json``: the ``paper`` preset (default,
  and with the sensor delay, drift and another noise seed);
- ``stage_every_block.json``: a hand-made stage with every block type.

Outputs: models on the record ``chain_t``/``chain_u`` (``PreisachModel.predict``), the
chain on the same record (``Chain.predict(t, u)``), every stage on ``stage_u`` from
rest at its own sample rate (``Stage.run``).
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np

from preisach import PreisachModel
from preisach.chain import Chain
from preisach.sim import Stage, hysteresis_block

HERE = Path(__file__).resolve().parent


def chain_record() -> tuple[np.ndarray, np.ndarray]:
    """0.5 s at 10 kHz from t = 2.5 s: a decaying sine with a few steps (input 0-10)."""
    t = 2.5 + np.arange(5000) / 10e3
    s = t - t[0]
    u = 5 + 4.5 * np.exp(-s / 0.3) * np.sin(2 * np.pi * 13 * s - np.pi / 2)
    u += 0.8 * ((s > 0.2) & (s < 0.32)) - 0.6 * (s > 0.41)
    return t, np.clip(u, 0.0, 10.0)


def stage_record() -> np.ndarray:
    """4000 samples of DAC volts: a rising sine, a step, a dwell."""
    k = np.arange(4000)
    u = 3.75 + 3.0 * np.sin(2 * np.pi * k / 900) * np.minimum(1.0, k / 1500)
    u[2500:3200] = 6.5
    u[3200:] = 1.2
    return u


def main() -> None:
    t, u = chain_record()
    su = stage_record()
    out: dict[str, np.ndarray] = {"chain_t": t, "chain_u": u, "stage_u": su}

    rng = np.random.default_rng(16)
    n = 10
    lv = np.linspace(0, 10, n + 1)
    c = (lv[:-1] + lv[1:]) / 2
    B, A = np.meshgrid(c, c, indexing="ij")
    w = np.where(A >= B, np.exp(-((A - B) / 3.0) ** 2) * rng.uniform(0.5, 1.0, (n, n)), 0.0) / 8
    truth = PreisachModel(w, (0.0, 10.0), 0.4, "stepwise")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fitted = PreisachModel.fit(u, truth.predict(u) + 0.01 * rng.standard_normal(u.size), 12)
    fitted.save(HERE / "model_stepwise.json")
    out["model_stepwise"] = fitted.predict(u)

    interp = PreisachModel(w[:8, :8] * 2, (1.0, 9.0), -0.2, "interpolated")
    interp.save(HERE / "model_interpolated.json")
    out["model_interpolated"] = interp.predict(u)

    effects = [
        {"name": "rate", "params": {"gain_s": 2e-3, "tau_s": 4e-3}},
        {"name": "creep", "params": {"taus_s": [0.05, 0.4], "amplitudes": [0.03, 0.02]}},
        {"name": "vibration", "params": {"frequency_hz": 620.0, "damping": 0.03}},
        {"name": "lowpass", "params": {"cutoff_hz": 900.0, "order": 3}},
        {"name": "delay", "params": {"delay_s": 3.3e-4}},
        {"name": "drift", "params": {"gain_per_s": 0.01, "offset": 0.05, "offset_per_s": -0.02}},
    ]
    ch = Chain(PreisachModel(w, (-0.5, 10.5), 0.3, "interpolated"), effects)
    ch.save(HERE / "chain_effects.json")
    out["chain_effects"] = ch.predict(t, u)

    stages = {
        "stage_paper": Stage.preset("paper"),
        "stage_paper_delay_drift": Stage.preset("paper", delay=True, seed=3, drift_gain_per_s=0.02,
                                                drift_offset_per_s=0.1),
        "stage_every_block": Stage([
            {"type": "quantizer", "bits": 12, "range": [-10.0, 10.0]},
            {"type": "lowpass", "cutoff_hz": 5000.0, "order": 3},
            {"type": "amplifier", "gain": 2.0, "saturation": [-1.0, 14.0], "slew_v_per_s": 2e4},
            hysteresis_block(PreisachModel(w, (0.0, 12.0), 0.1), interpolated=False),
            {"type": "creep", "gains": [0.02, 0.01], "time_constants_s": [0.002, 0.02]},
            {"type": "vibration", "modes": [{"freq_hz": 900.0, "damping": 0.05},
                                            {"freq_hz": 2600.0, "damping": 0.1}]},
            {"type": "delay", "delay_s": 1.13e-4},
            {"type": "drift", "gain_per_s": 0.5, "offset": 0.01, "offset_per_s": 0.3},
            {"type": "hysteresis", "source": "parametric", "lo": -1.0, "hi": 5.0, "n_h": 60,
             "hysteretic_stroke": 2.0, "coercivity_median": 0.4, "coercivity_sigma": 0.6,
             "interaction_sigma": 1.5, "reversible_slope": 0.1, "reversible_saturation": 0.2},
            {"type": "noise", "std": 1e-3, "seed": 7},
            {"type": "sensor", "gain": 0.5, "lowpass": {"cutoff_hz": 8000.0, "order": 4}, "delay_s": 3e-5,
             "noise_std": 5e-4, "seed": 2, "adc": {"bits": 14, "range": [-5.0, 5.0]}},
        ], sample_rate_hz=50e3),
    }
    for name, st in stages.items():
        (HERE / f"{name}.json").write_text(st.to_json() + "\n")
        out[name] = st.run(su)
    np.savez_compressed(HERE / "outputs.npz", **out)
    print(json.dumps({k: v.shape[0] for k, v in out.items()}))


if __name__ == "__main__":
    main()
