"""Chain blocks against SciPy (test-only dependency): each linear block sampled by the
zero-order hold against ``scipy.signal.cont2discrete``, by the first-order hold against
``scipy.signal.lsim``, the per-sample low-pass against ``scipy.signal.butter``, frequency
responses against ``scipy.signal.freqs``; the hold difference between a per-sample and a
record run, bounded; initial conditions; sample rates; JSON round trips and bad files.

Parameters are drawn at random (hypothesis) in realistic ranges."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from lti_reference import lsim_reference, tf_creep, tf_mode, tf_rate, zoh_reference
from preisach import Chain, PreisachModel, load
from preisach.chain import sample_period

SLOW = settings(max_examples=12, deadline=None)


def _record(n: int, fs: float, seed: int, t0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A smooth random walk with a step in the middle, sampled at ``fs`` from ``t0``."""
    rng = np.random.default_rng(seed)
    x = np.convolve(np.cumsum(rng.normal(size=n)) * 0.01, np.ones(40) / 40, "same")
    return t0 + np.arange(n) / fs, x + (np.arange(n) > n // 2)


def _zero_hysteresis(lo: float = -50.0, hi: float = 50.0) -> dict:
    """A hysteresis block with no mass (output 0): puts the rate branch alone."""
    return Chain(PreisachModel(np.zeros((1, 1)), (lo, hi))).blocks[0]


# --------------------------------------------------------------------------- strategies
fs_st = st.sampled_from([10e3, 25e3, 50e3, 100e3])
mode_st = st.tuples(st.floats(50.0, 3000.0), st.floats(0.005, 0.9))
creep_st = st.lists(st.tuples(st.floats(0.002, 2.0), st.floats(0.0, 0.1)), min_size=1, max_size=3)


def _mode_block(modes):
    return {"type": "vibration", "modes": [{"frequency_hz": f, "damping": z} for f, z in modes]}


def _creep_block(elems, normalized=False):
    b = {"type": "creep", "taus_s": [e[0] for e in elems], "amplitudes": [e[1] for e in elems]}
    if normalized:
        b["normalized"] = True
    return b


# --------------------------------------------------------------------------- zero-order hold
@SLOW
@given(modes=st.lists(mode_st, min_size=1, max_size=2), fs=fs_st, seed=st.integers(0, 99))
def test_vibration_zoh_equals_cont2discrete_mode_by_mode(modes, fs, seed):
    """Modes in series, each sampled by the hold (what the per-sample run defines)."""
    modes = [(min(f, 0.45 * fs), z) for f, z in modes]
    t, x = _record(3000, fs, seed)
    y = Chain.from_blocks([_mode_block(modes)]).simulate(t, x)
    want = x
    for f, z in modes:
        want = zoh_reference(*tf_mode(f, z), want, 1 / fs)
    assert np.max(np.abs(y - want)) < 1e-12 * max(1.0, np.max(np.abs(want)))


@SLOW
@given(elems=creep_st, normalized=st.booleans(), fs=fs_st, seed=st.integers(0, 99))
def test_creep_zoh_equals_cont2discrete(elems, normalized, fs, seed):
    taus = [e[0] for e in elems]
    if len(set(taus)) < len(taus):
        return  # equal time constants merge: covered below
    t, x = _record(3000, fs, seed)
    y = Chain.from_blocks([_creep_block(elems, normalized)]).simulate(t, x)
    want = zoh_reference(*tf_creep(taus, [e[1] for e in elems], normalized), x, 1 / fs)
    assert np.max(np.abs(y - want)) < 1e-12 * max(1.0, np.max(np.abs(want)))


def test_creep_with_equal_time_constants_merges():
    t, x = _record(2000, 10e3, 1)
    a = Chain.from_blocks([{"type": "creep", "taus_s": [0.1, 0.1], "amplitudes": [0.02, 0.03]}])
    b = Chain.from_blocks([{"type": "creep", "taus_s": [0.1], "amplitudes": [0.05]}])
    np.testing.assert_allclose(a.predict(t, x), b.predict(t, x), rtol=0, atol=1e-14)
    np.testing.assert_allclose(a.simulate(t, x), b.simulate(t, x), rtol=0, atol=1e-14)


@SLOW
@given(gain=st.floats(1e-6, 1e-2) | st.floats(-1e-2, -1e-6), tau=st.floats(2e-4, 2e-2), fs=fs_st, seed=st.integers(0, 99))
def test_rate_zoh_equals_cont2discrete_on_the_hysteresis_input(gain, tau, fs, seed):
    t, x = _record(2000, fs, seed)
    chain = Chain.from_blocks([_zero_hysteresis(), {"type": "rate", "gain_s": gain, "tau_s": tau}])
    want = zoh_reference(*tf_rate(gain, tau), x, 1 / fs)
    assert np.max(np.abs(chain.simulate(t, x) - want)) < 1e-12 * max(1.0, np.max(np.abs(want)))


@pytest.mark.parametrize("order", [1, 2, 3, 4])
@pytest.mark.parametrize("fs,fc", [(100e3, 20e3), (10e3, 300.0), (50e3, 24e3)])
def test_per_sample_lowpass_equals_scipy_butter(order, fs, fc):
    t, x = _record(4000, fs, order)
    b, a = signal.butter(order, fc, fs=fs)
    want = signal.lfilter(b, a, x, zi=signal.lfilter_zi(b, a) * x[0])[0]
    y = Chain.from_blocks([{"type": "lowpass", "cutoff_hz": fc, "order": order}]).simulate(t, x)
    assert np.max(np.abs(y - want)) < 1e-11


# --------------------------------------------------------------------------- first-order hold
@SLOW
@given(modes=st.lists(mode_st, min_size=1, max_size=1), elems=creep_st, fs=fs_st, seed=st.integers(0, 99))
def test_foh_equals_lsim_for_modes_and_creep(modes, elems, fs, seed):
    t, x = _record(3000, fs, seed, t0=1.7)
    (f, z), = modes
    y = Chain.from_blocks([_mode_block(modes)]).predict(t, x)
    assert np.max(np.abs(y - lsim_reference(*tf_mode(f, z), t, x))) < 1e-9
    taus = [e[0] for e in elems]
    if len(set(taus)) == len(taus):
        y = Chain.from_blocks([_creep_block(elems)]).predict(t, x)
        assert np.max(np.abs(y - lsim_reference(*tf_creep(taus, [e[1] for e in elems]), t, x))) < 1e-9


@pytest.mark.parametrize("order,fc,fs", [(1, 800.0, 50e3), (2, 1500.0, 50e3), (3, 600.0, 50e3),
                                         (2, 5600.0, 25e3), (4, 20e3, 100e3), (3, 11e3, 25e3),
                                         (2, 30e3, 25e3)])
def test_foh_lowpass_equals_lsim_at_any_cutoff(order, fc, fs):
    """Exact at the samples, also with the cutoff above Nyquist (a record run has no
    Nyquist limit)."""
    t, x = _record(6000, fs, 3)
    b, a = signal.butter(order, 2 * math.pi * fc, analog=True)
    y = Chain.from_blocks([{"type": "lowpass", "cutoff_hz": fc, "order": order}]).predict(t, x)
    assert np.max(np.abs(y - lsim_reference(b, a, t, x))) < 1e-9


def test_slow_pole_is_exact_over_long_records():
    # tau = 10 s at 50 kHz: the closed forms cancel catastrophically without the series.
    t, x = _record(200_000, 50e3, 4)
    y = Chain.from_blocks([_creep_block([(10.0, 1.0)], normalized=True)]).predict(t, x)
    assert np.max(np.abs(y - lsim_reference([1.0], [10.0, 1.0], t, x))) < 1e-9


@SLOW
@given(delay=st.floats(0.0, 2e-3), fs=fs_st, seed=st.integers(0, 99))
def test_delay_is_linear_interpolation_at_rest_before_the_start(delay, fs, seed):
    t, x = _record(1000, fs, seed)
    want = np.interp(t - delay, t, x, left=x[0])
    for run in (Chain.from_blocks([{"type": "delay", "delay_s": delay}]).predict,
                Chain.from_blocks([{"type": "delay", "delay_s": delay}]).simulate):
        assert np.max(np.abs(run(t, x) - want)) < 1e-9


@SLOW
@given(modes=st.lists(mode_st, min_size=1, max_size=2), fc=st.floats(100.0, 5e3), order=st.integers(1, 4),
       elems=creep_st, delay=st.floats(0.0, 1e-3), gain=st.floats(0.1, 5.0))
def test_frequency_response_equals_freqs(modes, fc, order, elems, delay, gain):
    f = np.geomspace(1.0, 2e4, 200)
    w = 2 * math.pi * f
    blocks = [_mode_block(modes), {"type": "lowpass", "cutoff_hz": fc, "order": order},
              _creep_block(elems), {"type": "delay", "delay_s": delay},
              {"type": "sensor", "gain": gain}]
    h = Chain.from_blocks(blocks).response(f)
    want = np.exp(-1j * w * delay) * gain
    for fm, z in modes:
        want = want * signal.freqs(*tf_mode(fm, z), worN=w)[1]
    want = want * signal.freqs(*signal.butter(order, 2 * math.pi * fc, analog=True), worN=w)[1]
    taus = [e[0] for e in elems]
    if len(set(taus)) < len(taus):
        return
    want = want * signal.freqs(*tf_creep(taus, [e[1] for e in elems]), worN=w)[1]
    assert np.max(np.abs(h - want) / np.maximum(np.abs(want), 1e-12)) < 1e-9


# --------------------------------------------------------------------------- per sample vs record
def _l1_mode(f: float, z: float) -> float:
    """∫|h| of a mode's impulse response ``ω/√(1−ζ²) e^{−ζωt} sin(ω_d t)``."""
    w = 2 * math.pi * f
    wd = w * math.sqrt(1 - z * z)
    t = np.linspace(0.0, 12 / (z * w), 400_001)
    h = w / math.sqrt(1 - z * z) * np.exp(-z * w * t) * np.sin(wd * t)
    return float(np.trapezoid(np.abs(h), t))


@SLOW
@given(f=st.floats(200.0, 1500.0), z=st.floats(0.05, 0.3), elems=creep_st, gain=st.floats(-2e-3, 2e-3),
       tau=st.floats(1e-3, 1e-2), delay=st.floats(0.0, 5e-4), seed=st.integers(0, 99))
def test_per_sample_and_record_runs_differ_by_the_hold_alone(f, z, elems, gain, tau, delay, seed):
    """On a slow input the per-sample run (input held over each interval) and the record
    run (input linear between samples) of one chain differ by the hold: its input error is
    at most the change over one sample, ``max|Δv|`` of the signal ``v`` entering the
    linear blocks, and a stable block passes it with at most its L1 gain ``∫|h|``. So
    ``|y_zoh − y_foh| <= (∫|h_creep| · ∫|h_mode| · ∫|h_delay|) · max|Δv|`` with
    ``∫|h_creep| = 1 + Σc`` (a positive kernel), ``∫|h_delay| = 1``, and the rate branch
    adding ``2|gain|/τ · max|Δu|`` to ``max|Δv|``."""
    fs = 20e3
    n = 8000
    t = np.arange(n) / fs
    rng = np.random.default_rng(seed)
    u = 5 + 4 * np.sin(2 * np.pi * 3 * t + rng.uniform(0, 6)) * np.sin(2 * np.pi * 0.7 * t + 1)
    w = np.triu(rng.uniform(0.0, 1.0, (10, 10))) / 20
    model = PreisachModel(w, (0.0, 10.0), 0.2, "interpolated")
    blocks = Chain(model).blocks + [{"type": "rate", "gain_s": gain, "tau_s": tau}, _creep_block(elems),
                                    _mode_block([(f, z)]), {"type": "delay", "delay_s": delay}]
    chain = Chain.from_blocks(blocks)
    v = model.predict(u)
    dv = np.max(np.abs(np.diff(v))) + 2 * abs(gain) / tau * np.max(np.abs(np.diff(u)))
    bound = (1 + sum(e[1] for e in elems)) * _l1_mode(f, z) * dv
    diff = np.max(np.abs(chain.simulate(t, u) - chain.predict(t, u)))
    assert diff <= bound
    assert bound < 0.1 * np.ptp(v)  # the bound says something


# --------------------------------------------------------------------------- initial conditions
def test_initial_input_is_a_step_from_rest_and_defaults_to_the_first_input():
    fs = 50e3
    t = np.arange(5000) / fs
    u = np.full(t.size, 2.0)
    mode = _mode_block([(700.0, 0.02)])
    ch = Chain.from_blocks([mode])
    for run in (ch.predict, ch.simulate):
        assert np.ptp(run(t, u)) < 1e-12  # at rest with the first input: no ringing
        y = run(t, u, initial_input=0.0)  # at rest at 0: a step at the first sample
        y_step = lsim_reference(*tf_mode(700.0, 0.02), np.r_[-1 / fs, t], np.r_[0.0, u])[1:]
        if run == ch.predict:
            assert np.max(np.abs(y - y_step)) < 1e-9
        assert np.max(y) > 3.5 and abs(y[-1] - 2.0) < 0.05
    ch.initial_input = 0.0
    assert ch.to_dict()["initial_input"] == 0.0
    np.testing.assert_array_equal(ch.predict(t, u), ch.predict(t, u, initial_input=0.0))
    assert Chain.from_json(ch.to_json()).initial_input == 0.0


def test_initial_extrema_set_the_hysteresis_memory():
    """Memory after an unrecorded history: the same as running the history first."""
    rng = np.random.default_rng(5)
    model = PreisachModel(np.triu(rng.uniform(0, 1, (12, 12))), (0.0, 10.0), 0.0, "interpolated")
    history = [9.0, 2.0, 7.5, 4.0]
    block = dict(Chain(model).blocks[0], initial_extrema=history)
    ch = Chain.from_blocks([block])
    t = np.arange(300) / 1e3
    u = 5 + 2 * np.sin(2 * np.pi * 3 * t)
    want = model.predict(np.r_[history, u])[len(history):]
    np.testing.assert_allclose(ch.predict(t, u), want, rtol=0, atol=1e-12)
    assert not np.allclose(ch.predict(t, u), model.predict(u))
    assert Chain.from_json(ch.to_json()).blocks[0]["initial_extrema"] == history


# --------------------------------------------------------------------------- sample rates
@pytest.mark.parametrize("run", ["simulate", "predict"])
def test_a_step_rises_at_the_same_time_at_10_and_100_khz(run):
    """50 % rise of a step through hysteresis, mode, low-pass and delay, run at the
    record's own rate: the same time within one sample of the coarser rate (a step given
    at a sample happened within the sample interval before it: the hold of a per-sample
    run applies it over that interval, a record run ramps over it)."""
    rng = np.random.default_rng(2)
    model = PreisachModel(np.triu(rng.uniform(0.2, 1, (20, 20))) / 40, (0.0, 10.0), 0.0, "interpolated")
    blocks = Chain(model).blocks + [_mode_block([(780.0, 0.05)]), {"type": "lowpass", "cutoff_hz": 1000.0},
                                    {"type": "delay", "delay_s": 3e-4}]
    chain = Chain.from_blocks(blocks)
    rise = []
    for fs in (10e3, 100e3):
        t = np.arange(int(0.03 * fs)) / fs
        u = np.where(t >= 0.01, 8.0, 2.0)
        y = getattr(chain, run)(t, u)
        half = 0.5 * (y[0] + y[-1])
        k = int(np.argmax(y >= half))
        rise.append(t[k - 1] + (half - y[k - 1]) / (y[k] - y[k - 1]) * (t[k] - t[k - 1]))
    assert abs(rise[0] - rise[1]) <= 1e-4, rise
    # The rise itself: the delay, then about a quarter period of the mode and the filter's lag.
    assert 0.01 + 3e-4 < rise[1] < 0.0110


def test_sample_period_rejects_irregular_and_non_increasing_time_naming_the_row():
    t = np.arange(1000) * 1e-4
    assert sample_period(t) == pytest.approx(1e-4)
    # Rounding of a stored time axis (float32 at 100 s) is fine.
    assert sample_period((t + 100.0).astype(np.float32).astype(np.float64)) == pytest.approx(1e-4, rel=1e-3)
    with pytest.raises(ValueError, match=r"t: time must increase strictly \(row 10"):
        sample_period(np.r_[t[:10], t[9], t[11:]])
    with pytest.raises(ValueError, match=r"t: irregular sampling at row 499"):
        sample_period(np.delete(t, 499))  # a missing sample: row 499 comes two periods late
    bad = t.copy()
    bad[300] += 0.6e-4
    with pytest.raises(ValueError, match=r"^rec: irregular sampling at row 300"):
        sample_period(bad, "rec")


# --------------------------------------------------------------------------- JSON
def _model(n=8):
    rng = np.random.default_rng(n)
    return PreisachModel(np.triu(rng.uniform(0, 1, (n, n))) / n, (0, 10), 0.5, "interpolated")


def test_chain_of_a_model_and_effects_keeps_the_pinned_api(tmp_path):
    eff = [{"name": "drift", "params": {"gain_per_s": 0.01, "offset": 0.1}},
           {"name": "delay", "params": {"delay_s": 3e-4}},
           {"name": "vibration", "params": {"frequency_hz": 800.0, "damping": 0.02}}]
    ch = Chain(_model(), eff)
    # The effects run in the fixed order whatever the list's order.
    assert ch.kinds() == ["hysteresis", "vibration", "delay", "drift"]
    assert ch.effects == {"vibration": {"frequency_hz": 800.0, "damping": 0.02}, "delay": {"delay_s": 3e-4},
                          "drift": {"gain_per_s": 0.01, "offset": 0.1, "offset_per_s": 0.0}}
    np.testing.assert_array_equal(ch.model.weights, _model().weights)
    p = tmp_path / "c.json"
    ch.save(p)
    d = json.loads(p.read_text())
    assert d["format"] == "preisach-chain" and d["version"] == 2
    back = Chain.load(p)
    assert back.to_dict() == d and Chain.from_dict(d).to_dict() == d
    fs1, fs2 = 100e3, 20e3
    t1, t2 = np.arange(int(0.2 * fs1)) / fs1, np.arange(int(0.2 * fs2)) / fs2
    u = lambda t: 5 + 4 * np.sin(2 * np.pi * 15 * t - np.pi / 2)  # noqa: E731
    y1, y2 = back.predict(t1, u(t1)), back.predict(t2, u(t2))
    # The same physical chain at two sample rates agrees where the samples coincide.
    assert np.max(np.abs(y1[::5] - y2)) < 0.02 * np.ptp(y1)


BAD_BLOCKS = [
    ({"type": "warp"}, r"blocks\[1\] \(warp\): unknown block type 'warp'"),
    ({"type": "lowpass"}, r"blocks\[1\] \(lowpass\): missing field `cutoff_hz`"),
    ({"type": "lowpass", "cutoff_hz": 500.0, "colour": 1}, r"blocks\[1\] \(lowpass\): unknown field `colour`"),
    ({"type": "lowpass", "cutoff_hz": float("nan")}, r"blocks\[1\] \(lowpass\): cutoff_hz: must be finite, got nan"),
    ({"type": "creep", "taus_s": [0.1, -1.0], "amplitudes": [0.01, 0.02]},
     r"blocks\[1\] \(creep\): taus_s\[1\]: must be > 0, got -1"),
    ({"type": "vibration", "modes": [{"frequency_hz": 700.0, "damping": 0.0}]},
     r"blocks\[1\] \(vibration\): modes\[0\].damping: must be > 0, got 0"),
    ({"type": "delay", "delay_s": -1e-3}, r"blocks\[1\] \(delay\): delay_s: must be >= 0"),
]


@settings(max_examples=40, deadline=None)
@given(n=st.integers(2, 60), i=st.integers(0, 59), j=st.integers(0, 59), bad=st.sampled_from([math.nan, math.inf, -math.inf]),
       as_array=st.booleans())
def test_a_non_finite_mass_anywhere_is_named_by_its_row_and_column(n, i, j, bad, as_array):
    """Masses are checked a row at a time; the error still names the one bad entry
    (given as lists, or rows of a NumPy array)."""
    i, j = sorted((i % n, j % n))
    w = np.triu(np.full((n, n), 0.01))
    block = Chain(PreisachModel(w, (0.0, 1.0))).blocks[0]
    w[i, j] = bad
    block["weights"] = list(w) if as_array else w.tolist()
    with pytest.raises(ValueError, match=rf"^blocks\[0\] \(hysteresis\): weights\[{i}\]\[{j}\]: must be finite, got {bad}$"):
        Chain.from_blocks([block])
    w[i, j] = 0.01
    block["weights"] = list(w) if as_array else w.tolist()
    Chain.from_blocks([block])  # (finite: accepted)


@pytest.mark.parametrize("block,msg", BAD_BLOCKS)
def test_bad_blocks_are_rejected_naming_block_and_field(tmp_path, block, msg):
    d = Chain(_model()).to_dict()
    d["blocks"].append(block)
    with pytest.raises(ValueError, match=msg):
        Chain.from_dict(d)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))  # NaN written as Python's JSON does
    with pytest.raises(ValueError, match=msg):
        load(p)


def test_rate_needs_a_hysteresis_before_it_and_cutoff_nyquist_is_checked_per_run():
    with pytest.raises(ValueError, match=r"blocks\[0\] \(rate\): needs a hysteresis block before it"):
        Chain.from_blocks([{"type": "rate", "gain_s": 1e-3, "tau_s": 1e-3}])
    ch = Chain.from_blocks([{"type": "lowpass", "cutoff_hz": 6000.0}])
    t = np.arange(100) / 10e3
    ch.predict(t, np.ones(100))  # a record run: exact at any rate
    with pytest.raises(ValueError, match=r"blocks\[0\] \(lowpass\): cutoff_hz: must be below Nyquist \(5000 Hz\)"):
        ch.simulate(t, np.ones(100))
    with pytest.raises(ValueError, match=r"blocks\[0\] \(vibration\): modes\[0\].frequency_hz: must be below Nyquist"):
        Chain.from_blocks([_mode_block([(6000.0, 0.1)])]).simulate(t, np.ones(100))
    with pytest.raises(ValueError, match="sample_rate_hz: the chain has none"):
        ch.run([1.0, 2.0])


def test_effects_of_a_general_chain_point_to_blocks():
    st = load_paper()
    assert st.model is None
    with pytest.raises(ValueError, match="use .blocks"):
        st.effects


def load_paper():
    from preisach.sim import Stage

    return Stage.preset("paper")
