"""preisach.sim: Stage construction, JSON, presets, determinism, analytic block
responses through the Python API, validation, and run_loop."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

import preisach
from preisach.sim import LoopResult, Stage, Timing, hysteresis_block, run_loop

FS = 100_000.0


def amplitude_at(x: np.ndarray, f: float, fs: float = FS) -> float:
    t = np.arange(len(x)) / fs
    return float(2 * abs(np.sum(x * np.exp(-2j * np.pi * f * t))) / len(x))


# ---------------------------------------------------------------- blocks through Python

def test_mode_step_response_matches_analytic() -> None:
    f, z = 780.0, 0.02
    st = Stage([{"type": "vibration", "modes": [{"freq_hz": f, "damping": z}]}])
    # At rest at 0 for the first sample, then a unit step.
    y = st.run(np.r_[0.0, np.ones(3000)])
    assert y[0] == 0.0
    y = y[1:]
    t = (np.arange(3000) + 1) / FS
    w = 2 * np.pi * f
    wd = w * math.sqrt(1 - z * z)
    exact = 1 - np.exp(-z * w * t) * (np.cos(wd * t) + z / math.sqrt(1 - z * z) * np.sin(wd * t))
    np.testing.assert_allclose(y, exact, atol=1e-9)


@pytest.mark.parametrize("order", [1, 2, 3, 4])
def test_lowpass_minus_3db_at_cutoff(order: int) -> None:
    fc = 2000.0
    st = Stage([{"type": "lowpass", "cutoff_hz": fc, "order": order}])
    n = 100_000
    y = st.run(np.sin(2 * np.pi * fc * np.arange(2 * n) / FS))[n:]
    assert amplitude_at(y, fc) == pytest.approx(1 / math.sqrt(2), abs=1e-6)
    st.reset()
    assert st.run(np.r_[0.0, np.ones(20_000)])[-1] == pytest.approx(1.0, abs=1e-9)


def test_delay_integer_and_fractional() -> None:
    x = np.arange(200, dtype=float)
    y = Stage([{"type": "delay", "delay_s": 7 / FS}]).run(x)
    np.testing.assert_array_equal(y[7:], x[:-7])
    np.testing.assert_array_equal(y[:7], x[0])  # at rest: the line holds the first sample
    y = Stage([{"type": "delay", "delay_s": 4.58e-4}]).run(x)
    np.testing.assert_allclose(y[50:], x[50:] - 45.8, atol=1e-9)


def test_creep_converges_to_dc_gain_and_drift_formula() -> None:
    st = Stage([{"type": "creep", "gains": [0.03, 0.02], "time_constants_s": [0.01, 0.05]}])
    assert st.run(np.r_[0.0, np.ones(100_000)])[-1] == pytest.approx(1.05, abs=1e-9)
    st = Stage([{"type": "drift", "gain_per_s": 0.01, "offset": 0.1, "offset_per_s": 0.2}], sample_rate_hz=1000)
    x = np.linspace(-1, 1, 500)
    t = np.arange(500) / 1000
    np.testing.assert_allclose(st.run(x), (1 + 0.01 * t) * x + 0.1 + 0.2 * t, atol=1e-12)
    assert st.time_s == pytest.approx(0.5)
    st.time_s = 100.0
    assert st.step(1.0) == pytest.approx(2.0 * 1 + 0.1 + 20.0)


def test_identified_hysteresis_block_equals_model_prediction() -> None:
    rng = np.random.default_rng(1)
    w = np.triu(rng.random((8, 8)))
    model = preisach.PreisachModel(w, (0.0, 2.0), offset=0.3)
    u = 1 + 0.9 * np.sin(np.linspace(0, 20, 3000)) * np.linspace(0.2, 1, 3000)
    for interp in (True, False):
        st = Stage([hysteresis_block(model, interpolated=interp)])
        want = model.predict(u, output="interpolated" if interp else "stepwise")
        np.testing.assert_array_equal(st.run(u), want)
        back = Stage.from_json(st.to_json())
        np.testing.assert_array_equal(back.run(u), want)


# ---------------------------------------------------------------- preset, JSON, determinism

def test_paper_preset_units_and_blocks() -> None:
    st = Stage.preset("paper")
    assert st.sample_rate_hz == FS
    assert [b["type"] for b in st.blocks] == [
        "quantizer", "lowpass", "amplifier", "hysteresis", "creep", "vibration", "sensor"]
    sensor = st.blocks[-1]
    assert sensor["gain"] == 0.2 and sensor["delay_s"] == 0.0
    assert Stage.preset("paper", delay=True).blocks[-1]["delay_s"] == 4.58e-4
    # Slow ramp over the usable DAC range: 0..~40 µm, i.e. ~0..8 V at the sensor.
    # The stage starts at rest at u = 0: ~1.1 µm of hysteresis output, ~0.22 V.
    y = st.run(np.linspace(0, 7.5, 100_000))
    assert 0.0 < y[0] < 0.5 and 5.0 < y[-1] < 10.0
    assert "Stage(quantizer -> lowpass" in repr(st)


def test_json_round_trip_and_replay() -> None:
    st = Stage.preset("paper", seed=4, delay=True)
    d = json.loads(st.to_json())
    assert d["format"] == "preisach-chain" and d["version"] == 2 and d["sample_rate_hz"] == FS
    hyst = d["blocks"][3]
    assert hyst["type"] == "hysteresis" and hyst["source"] == "parametric" and hyst["n_h"] == 500
    assert "weights" not in hyst
    u = 3.75 + 3 * np.sin(2 * np.pi * 20 * np.arange(20_000) / FS)
    y1 = st.run(u)
    y2 = Stage.from_json(st.to_json()).run(u)
    np.testing.assert_array_equal(y1, y2)
    st.reset()
    np.testing.assert_array_equal(st.run(u), y1)
    assert not np.array_equal(Stage.preset("paper", seed=5, delay=True).run(u), y1)
    # A copy is independent.
    c = st.copy()
    c.reset()
    np.testing.assert_array_equal(c.run(u), y1)


def test_step_equals_run() -> None:
    a = Stage.preset("paper")
    b = Stage.preset("paper")
    u = np.linspace(0, 5, 1000)
    np.testing.assert_array_equal(a.run(u), [b.step(float(x)) for x in u])


# ---------------------------------------------------------------- validation

@pytest.mark.parametrize("block, name", [
    ({"type": "creep", "gains": [0.1], "time_constants_s": [-1.0]}, "taus_s[0]"),
    ({"type": "creep", "amplitudes": [0.1], "taus_s": [-1.0]}, "taus_s[0]"),
    ({"type": "vibration", "modes": [{"freq_hz": 780, "damping": 0.0}]}, "modes[0].damping"),
    ({"type": "vibration", "modes": [{"frequency_hz": 780, "damping": 0.0}]}, "modes[0].damping"),
    ({"type": "lowpass", "cutoff_hz": 60_000}, "cutoff_hz"),
    ({"type": "delay", "delay_s": -1e-3}, "delay_s"),
    ({"type": "sensor", "noise_std": -1.0}, "noise_std"),
    ({"type": "quantizer", "bits": 40, "range": [-10, 10]}, "bits"),
])
def test_bad_parameters_raise_naming_them(block: dict, name: str) -> None:
    with pytest.raises(ValueError) as info:
        Stage([block])
    msg = str(info.value)
    assert msg.startswith(f"blocks[0] ({block['type']}): {name}: "), msg


def test_other_bad_input() -> None:
    with pytest.raises(ValueError, match=r"^blocks\[0\] \(lowpass\): cutoff_hz: must be below Nyquist"):
        Stage([{"type": "lowpass", "cutoff_hz": 600}], sample_rate_hz=1000)
    with pytest.raises(ValueError, match=r"^blocks\[0\] \(lowpass\): cutoff_hz: must be finite, got nan"):
        Stage([{"type": "lowpass", "cutoff_hz": float("nan")}])
    with pytest.raises(ValueError, match=r"^blocks\[0\] \(vibration\): modes\[0\].damping: must be finite, got inf"):
        Stage([{"type": "vibration", "modes": [{"freq_hz": 780.0, "damping": np.inf}]}])
    with pytest.raises(ValueError, match=r"^preset 'paper': damping: must be finite"):
        Stage.preset("paper", damping=float("nan"))
    with pytest.raises(ValueError, match="sample_rate_hz"):
        Stage([], sample_rate_hz=-1)
    with pytest.raises(ValueError, match="blocks\\[0\\]"):
        Stage(["lowpass"])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="^corrupt chain"):
        Stage.from_json("{nope")
    with pytest.raises(ValueError, match="^corrupt chain"):
        Stage([{"type": "warp"}])
    with pytest.raises(ValueError, match="^corrupt chain: unsupported version"):
        Stage.from_json('{"format": "preisach-chain", "version": 3, "blocks": []}')
    with pytest.raises(ValueError, match="^corrupt chain: missing 'format'"):
        Stage.from_json('{"version": 2, "sample_rate_hz": 1000, "blocks": []}')
    with pytest.raises(ValueError, match="overrides"):
        Stage.preset("paper", dampign=0.1)
    with pytest.raises(ValueError, match="modes\\[0\\].damping"):
        Stage.preset("paper", damping=-0.1)
    with pytest.raises(ValueError, match="unknown preset"):
        Stage.preset("lab")
    st = Stage.preset("paper")
    with pytest.raises(ValueError, match="u: NaN at index 1"):
        st.run([0.0, float("nan")])
    with pytest.raises(ValueError, match="u: must be finite"):
        st.step(float("inf"))


# ---------------------------------------------------------------- run_loop

def test_run_loop_identity_equals_stage_run() -> None:
    r = 3.0 + np.sin(2 * np.pi * 10 * np.arange(10_000) / FS)
    st = Stage.preset("paper")
    res = run_loop(None, st, r, method="identity")
    assert isinstance(res, LoopResult) and isinstance(res.timing, Timing)
    np.testing.assert_array_equal(res.u, r)
    np.testing.assert_array_equal(res.y, Stage.preset("paper").run(r))
    np.testing.assert_array_equal(res.error, r - res.y)
    t = res.timing
    assert t.samples == 10_000 and t.budget_ns == 10_000.0
    assert 0 < t.mean_ns <= t.max_ns and t.p99_ns <= t.max_ns and 0 <= t.misses <= 10_000


def test_run_loop_with_an_inverse_compensates_the_stage() -> None:
    # Noise-free hysteresis + sensor gain only: the inverse of a model identified on it
    # must beat no compensation by a wide margin.
    st = Stage.preset("paper", creep=False, noise_std=0.0, dac_bits=0, adc_bits=0)
    n = 200_000
    t = np.arange(n) / FS
    u = 3.75 + 3.7 * (0.05 + 0.95 * t / t[-1]) * np.sin(2 * np.pi * 25 * t)
    y = st.run(u)
    model = preisach.PreisachModel.fit(u, y, 40)
    r = 4.0 + 2.0 * np.sin(2 * np.pi * 5 * np.arange(40_000) / FS)
    # Baseline: the straight line through the major loop's ends (no hysteresis model).
    u_lin = u.min() + (r - y.min()) * (u.max() - u.min()) / (y.max() - y.min())
    lin = run_loop(None, st, u_lin, method="identity")
    rms_lin = np.sqrt(np.mean((r - lin.y)[10_000:] ** 2))
    # (The stepwise closest match keeps a level's worth of error; with the stage at
    # rest from the first sample, y.min() is the loop's, not a start-up 0, so the
    # baseline is fairer than it was: 0.38 V, not 0.48 V.)
    for method, factor in (("continuous", 0.3), ("interpolated", 0.3), ("closest", 0.4)):
        res = run_loop(model, st, r, method=method)
        e = res.error[10_000:]
        assert np.sqrt(np.mean(e**2)) < factor * rms_lin, method
    # The interpolated method's preview lines u up with the reference: a lag of L = 500
    # samples on this 5 Hz, 2 V sine would alone cost an RMS error of 2π·5·2·L/fs/√2.
    a = run_loop(model, st, r, method="interpolated", lookahead=500).error[10_000:]
    lag_rms = 2 * np.pi * 5 * 2.0 * 500 / FS / np.sqrt(2)
    assert np.sqrt(np.mean(a**2)) < 0.4 * lag_rms


def test_run_loop_validation() -> None:
    st = Stage.preset("paper")
    model = preisach.PreisachModel(np.triu(np.ones((4, 4))), (0.0, 7.5))
    with pytest.raises(ValueError, match="method"):
        run_loop(model, st, [1.0], method="magic")
    with pytest.raises(ValueError, match="model"):
        run_loop(None, st, [1.0], method="continuous")
    with pytest.raises(ValueError, match="lookahead"):
        run_loop(model, st, [1.0], method="closest", lookahead=3)
    with pytest.raises(ValueError, match="reference: NaN at index 0"):
        run_loop(model, st, [float("nan")])
    with pytest.raises(ValueError, match="reference: empty"):
        run_loop(model, st, [])
    with pytest.raises(ValueError, match="stage"):
        run_loop(model, "paper", [1.0])  # type: ignore[arg-type]


# ---------------------------------------------------------------- rest at the first sample

@pytest.mark.parametrize(
    "block",
    [
        {"type": "lowpass", "cutoff_hz": 20_000.0, "order": 4},
        {"type": "lowpass", "cutoff_hz": 300.0, "order": 3},
        {"type": "vibration", "modes": [{"freq_hz": 780.0, "damping": 0.02}]},
        {"type": "creep", "gains": [0.01, 0.01, 0.01], "time_constants_s": [0.1, 1.0, 10.0]},
        {"type": "delay", "delay_s": 4.58e-4},
        {"type": "amplifier", "saturation": [-30.0, 180.0], "slew_v_per_s": 1e5},
        {"type": "sensor", "lowpass": {"cutoff_hz": 20_000.0, "order": 4}, "delay_s": 4.58e-4},
    ],
)
def test_each_block_starts_in_equilibrium_with_its_first_sample(block: dict) -> None:
    st = Stage([block])
    for x0 in (1.3, -2.0):
        for restart in (st.reset, st.reset_state):
            restart()
            y = st.run(np.full(10_000, x0))
            assert np.max(np.abs(y - y[0])) < 1e-10 * max(1.0, abs(y[0])), block["type"]
            assert y[0] != 0.0


def test_paper_stage_does_not_ring_at_the_start() -> None:
    # Quiet stage: constant in, constant out from the first sample (u = 0 gives ~1.1 µm).
    st = Stage.preset("paper", noise_std=0.0, dac_bits=0, adc_bits=0, delay=True)
    y = st.run(np.zeros(20_000))
    assert y[0] > 0.1
    assert np.max(np.abs(y - y[0])) < 1e-9
    # Default stage (noise, DAC/ADC): no 780 Hz content above the 1 nm noise floor,
    # also in run_loop, which resets the stage first.
    n = int(round(39 * FS / 780.0))
    for y in (Stage.preset("paper").run(np.zeros(n)),
              run_loop(None, Stage.preset("paper"), np.full(n, 3.0), method="identity").y):
        assert amplitude_at(y - y.mean(), 780.0) / 0.2 < 1e-4


def test_reset_replays_and_reset_state_keeps_time() -> None:
    st = Stage.preset("paper", seed=3, drift_offset_per_s=1.0)
    u = 3.0 + np.sin(2 * np.pi * 30 * np.arange(5000) / FS)
    y1 = st.run(u)
    st.reset()
    np.testing.assert_array_equal(st.run(u), y1)
    t = st.time_s
    st.reset_state()
    assert st.time_s == pytest.approx(t)
    quiet = Stage.preset("paper", noise_std=0.0, dac_bits=0, adc_bits=0, drift_offset_per_s=1.0, creep=False)
    quiet.run(u)
    quiet.reset_state()
    y = quiet.run(np.full(1000, 2.0))
    # Flat apart from the drift's offset ramp in absolute time (1 V/s).
    np.testing.assert_allclose(y - y[0], np.arange(1000) / FS, atol=1e-9)
