"""The chain inverse: feed-forward through hysteresis, linear blocks, delay and drift.

Oracles: the chain itself (``Chain.predict`` and ``Chain.simulate`` of the project's
blocks) and the independent stage of ``tests/independent_stage.py`` (SciPy filters, no
project block), with random parameters; the references are smooth and inside the
reachable range, well below the inverse's bandwidth.
"""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from independent_stage import draw_effects, true_hysteresis
from independent_stage import simulate as independent_simulate

import preisach
from preisach import Chain, ChainInverter, PreisachModel
from preisach.cli import main
from preisach.sim import Stage

FS = 20e3
#: Samples at rest before a reference moves (more than any latency here).
REST = 200


def _reference(model: PreisachModel, gain: float, f_hz: float, n: int, rng: np.random.Generator) -> np.ndarray:
    """``c - a cos(2 pi f t)`` inside the middle of the model's reachable range (times the
    chain's static gain after the hysteresis), after ``REST`` samples at rest at its
    bottom (the inverse assumes the reference rested at its first value before the
    record: a plant started at rest then needs no motion before it)."""
    w = float(model.weights.sum())
    lo, hi = model.offset - w, model.offset + w
    c = lo + (hi - lo) * rng.uniform(0.45, 0.55)
    a = (hi - lo) * rng.uniform(0.2, 0.35)
    t = np.maximum(np.arange(n) - REST, 0) / FS
    return gain * (c - a * np.cos(2 * np.pi * f_hz * t))


def _peak_error(r: np.ndarray, y: np.ndarray, skip: int, end: int = 100) -> float:
    """Peak error after ``skip`` samples and before the last ``end`` (past the record's
    end the inverse holds the last reference sample: the preview there is not the
    reference's), relative to the reference's half span."""
    r, y = r[skip:-end], y[skip:-end]
    return float(np.abs(r - y).max() / (0.5 * float(r.max() - r.min())))


def _static_gain(eff: dict) -> float:
    c = eff.get("creep")
    return 1.0 + (sum(c["amplitudes"]) if c else 0.0)


EFFECT_SETS = [("delay",), ("lowpass",), ("vibration",), ("creep",), ("vibration", "delay"),
               ("creep", "vibration", "lowpass", "delay"), ("vibration", "delay", "drift")]


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), names=st.sampled_from(EFFECT_SETS), f_hz=st.sampled_from([5.0, 20.0, 50.0]))
def test_the_chain_inverse_through_the_chain_reproduces_the_reference(seed, names, f_hz):
    rng = np.random.default_rng(seed)
    model = true_hysteresis(rng, n_h=40)
    eff = draw_effects(rng, names)
    chain = Chain(model, eff)
    n = int(FS * 3 / f_hz) + 2000
    r = _reference(model, _static_gain(eff), f_hz, n, rng)
    u, info = chain.invert(r, FS, return_info=True)
    assert info.saturated == 0 and info.bandwidth_hz < FS / 2
    t = np.arange(n) / FS
    skip = REST + int(FS / f_hz)  # after the rest and one period
    # Deterministic run of the same blocks (first-order hold): the bandwidth-limited
    # inverse leaves (f / bandwidth)^3-small errors.
    assert _peak_error(r, chain.predict(t, u), skip) < 2e-3
    # The per-sample run (zero-order hold, a half-sample lag per sampled block).
    assert _peak_error(r, chain.simulate(t, u), skip) < 5e-3 + 2 * np.pi * f_hz * 2 / FS


@pytest.mark.parametrize("seed", [3, 17, 29])
def test_the_chain_inverse_through_the_independent_stage_reproduces_the_reference(seed):
    """The independent stage: SciPy's zero-order-hold mode (a sample later than the
    project's convention), bilinear low-pass, first-order creep, linear-interpolation
    delay, drift in absolute time; the chain inverse built from the true parameters."""
    rng = np.random.default_rng(seed)
    model = true_hysteresis(rng, n_h=60)
    names = ("creep", "vibration", "lowpass", "delay", "drift")
    eff = draw_effects(rng, names)
    for f_hz in (5.0, 20.0):
        n = int(FS * 3 / f_hz)
        r = _reference(model, _static_gain(eff), f_hz, n, rng)
        u = Chain(model, eff).invert(r, FS)
        t = np.arange(n) / FS
        y = independent_simulate(model, eff, t, u, 0.0, rng)
        # One sample of the mode's convention at f_hz, plus the inverse's own error.
        assert _peak_error(r, y, REST + int(FS / f_hz)) < 4e-3 + 2 * np.pi * f_hz * 1.5 / FS


@pytest.mark.parametrize("method,lookahead", [("continuous", None), ("continuous", 40), ("interpolated", 60),
                                              ("closest", None)])
def test_streaming_equals_offline_once_past_the_latency(method, lookahead):
    rng = np.random.default_rng(5)
    model = true_hysteresis(rng, n_h=30)
    eff = draw_effects(rng, ("creep", "vibration", "lowpass", "delay"))
    chain = Chain(model, eff)
    r = _reference(model, _static_gain(eff), 30.0, 3000, rng)
    off = chain.invert(r, FS, method=method, lookahead=lookahead)
    inv = chain.inverter(FS, lookahead=lookahead, method=method)
    L = inv.latency
    assert L >= int(np.ceil(inv.preview_s * FS - 1e-9))
    stream = inv.process(np.concatenate([r, np.full(L, r[-1])]))
    np.testing.assert_array_equal(stream[L:], off)
    # State: resume from a snapshot, in another inverter, exactly.
    inv.reset()
    first = [inv.step(x) for x in r[:1234]]
    snap = inv.state
    other = chain.inverter(FS, lookahead=lookahead, method=method)
    other.state = json.loads(json.dumps({k: np.asarray(v).tolist() for k, v in snap.items()}))
    np.testing.assert_array_equal(np.concatenate([first, other.process(r[1234:])]),
                                  np.concatenate([first, inv.process(r[1234:])]))


def test_nan_in_the_reference_is_a_value_error_naming_the_index():
    rng = np.random.default_rng(1)
    model = true_hysteresis(rng, n_h=20)
    chain = Chain(model, {"delay": {"delay_s": 1e-3}})
    r = np.full(100, model.offset)
    r[37] = np.nan
    with pytest.raises(ValueError, match="r: NaN at index 37"):
        chain.invert(r, FS)
    inv = chain.inverter(FS)
    with pytest.raises(ValueError, match="r: NaN at index 37"):
        inv.process(r)
    with pytest.raises(ValueError, match="r: must be finite"):
        inv.step(float("inf"))


def test_references_beyond_the_reachable_output_are_clipped_counted_and_warned():
    """Oracle: the reachable output of a chain whose linear part has static gain 1 is the
    model's output at the ends of its range (``predict`` at ``u_range``)."""
    rng = np.random.default_rng(5)
    model = true_hysteresis(rng, n_h=20)
    chain = Chain(model, {"delay": {"delay_s": 1e-3}})
    lo, hi = model.u_range
    y_hi = float(model.predict(np.array([lo, hi]))[-1])
    r = np.full(400, model.offset)
    r[250:300] = y_hi + 1.0  # 50 samples above the top
    with pytest.warns(preisach.PreisachWarning, match=r"^50 of 400 reference samples .* clipped"):
        u, info = chain.invert(r, FS, return_info=True)
    assert info.saturated == 50
    assert np.all(u >= lo) and np.all(u <= hi)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, info = chain.invert(np.full(400, model.offset), FS, return_info=True)
    assert info.saturated == 0


def _identified_block(rng):
    return Chain(true_hysteresis(rng, n_h=10)).blocks[0]


@pytest.mark.parametrize("blocks,msg", [
    (lambda h: [h, {"type": "creep", "taus_s": [0.1], "amplitudes": [2.0], "normalized": True}],
     r"blocks\[1\] \(creep\): not minimum phase \(a zero at"),
    (lambda h: [{"type": "delay", "delay_s": 1e-3}], "has no hysteresis block"),
    (lambda h: [h, {"type": "rate", "gain_s": 1e-4, "tau_s": 1e-3}], r"blocks\[1\] \(rate\): cannot be inverted"),
    (lambda h: [h, h], r"blocks\[1\] \(hysteresis\): cannot be inverted: a second hysteresis"),
    (lambda h: [h, {"type": "drift", "offset": 1.0}, {"type": "delay", "delay_s": 1e-3}],
     r"blocks\[2\] \(delay\): cannot be inverted: only noise or a quantizer may follow a drift"),
])
def test_a_chain_that_cannot_be_inverted_is_a_clear_error(blocks, msg):
    chain = Chain.from_blocks(blocks(_identified_block(np.random.default_rng(2))))
    with pytest.raises(ValueError, match=msg):
        chain.invert(np.ones(10), FS)


def test_a_parametric_hysteresis_and_a_bandwidth_beyond_nyquist_are_refused():
    with pytest.raises(ValueError, match=r"blocks\[3\] \(hysteresis\): cannot be inverted: a parametric"):
        Stage.preset("paper").inverter()
    chain = Chain(true_hysteresis(np.random.default_rng(0), n_h=10), {"lowpass": {"cutoff_hz": 500.0}})
    with pytest.raises(ValueError, match=r"bandwidth_hz: must be below Nyquist \(10000 Hz\)"):
        chain.inverter(FS, bandwidth_hz=10e3)
    with pytest.raises(ValueError, match="lookahead: must be at least"):
        Chain(chain.model, {"delay": {"delay_s": 1e-3}}).inverter(FS, lookahead=5)
    with pytest.raises(ValueError, match="fs: the chain has no sample_rate_hz"):
        chain.inverter()


def test_amplifier_gain_and_a_linear_block_before_the_hysteresis_are_inverted_too():
    rng = np.random.default_rng(11)
    model = true_hysteresis(rng, n_h=40)
    h = Chain(model).blocks[0]
    chain = Chain.from_blocks([{"type": "lowpass", "cutoff_hz": 3000.0, "order": 2},
                               {"type": "amplifier", "gain": 4.0}, h,
                               {"type": "vibration", "modes": [{"frequency_hz": 900.0, "damping": 0.03}]},
                               {"type": "noise", "std": 0.0}])
    # The hysteresis sees 4 u: its input range is a quarter of the model's.
    r = _reference(model, 1.0, 10.0, 6000, rng)
    u = chain.invert(r, FS)
    assert u.max() <= model.u_range[1] / 4 + 1e-9
    assert _peak_error(r, chain.predict(np.arange(r.size) / FS, u), 2000) < 2e-3


def test_run_loop_with_a_chain_uses_the_chain_inverse():
    rng = np.random.default_rng(4)
    model = true_hysteresis(rng, n_h=40)
    eff = {"vibration": {"frequency_hz": 800.0, "damping": 0.02}, "delay": {"delay_s": 4e-4}}
    stage = Stage(Chain(model, eff).blocks, sample_rate_hz=FS)
    r = _reference(model, 1.0, 50.0, 4000, rng)
    chain_run = preisach.sim.run_loop(Chain(model, eff), stage, r)
    model_run = preisach.sim.run_loop(model, stage, r)
    skip = 800
    assert _peak_error(r, chain_run.y, skip) < 0.02
    assert _peak_error(r, chain_run.y, skip) < 0.2 * _peak_error(r, model_run.y, skip)
    np.testing.assert_array_equal(chain_run.u, Chain(model, eff).invert(r, FS))


def test_cli_invert_on_a_chain_writes_the_chain_inverse(tmp_path, capsys):
    rng = np.random.default_rng(8)
    model = true_hysteresis(rng, n_h=20)
    chain = Chain(model, {"vibration": {"frequency_hz": 700.0, "damping": 0.05}, "delay": {"delay_s": 3e-4}})
    chain.save(tmp_path / "aug.json")
    r = _reference(model, 1.0, 20.0, 3000, rng)
    t = np.arange(r.size) / FS
    np.savetxt(tmp_path / "ref.csv", np.column_stack([t, r]), delimiter=",", header="t,r", comments="", fmt="%.17g")
    out = tmp_path / "u.csv"
    assert main(["invert", str(tmp_path / "aug.json"), str(tmp_path / "ref.csv"), "-o", str(out),
                 "--bandwidth", "3000"]) == 0
    assert "chain inverse" in capsys.readouterr().out
    u = np.loadtxt(out, delimiter=",", skiprows=1)[:, 1]
    np.testing.assert_allclose(u, chain.invert(r, FS, bandwidth_hz=3000.0), rtol=0, atol=1e-12)
    assert main(["invert", str(tmp_path / "aug.json"), str(tmp_path / "ref.csv"), "-o", str(out),
                 "--bandwidth", "20000"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bandwidth_hz: must be below Nyquist" in err


def test_chain_inverter_repr_and_latency_in_seconds():
    chain = Chain(true_hysteresis(np.random.default_rng(0), n_h=10), {"delay": {"delay_s": 1e-3}})
    inv = chain.inverter(FS)
    assert isinstance(inv, ChainInverter)
    assert inv.latency == 20 and inv.latency_s == pytest.approx(1e-3)
    assert "latency=20" in repr(inv)


@pytest.mark.parametrize("seed", [5, 6])
def test_the_diagnosed_chain_compensates_the_independent_rig(seed):
    """The rig of ``tests/rig.py`` (no project block, a Prandtl–Ishlinskii hysteresis, a
    mode and a delay drawn at random): identified and diagnosed from its own records,
    the diagnosed chain's inverse recorded on the rig beats the hysteresis inverse alone."""
    from rig import make_case, records

    case = make_case("paper_mode_delay", seed)
    fs = case["fs"]
    train, hold = records(case)
    gap = preisach.diagnose(train, hold, n_h=20, candidates=("delay", "vibration", "lowpass"), progress=False)
    model = PreisachModel.fit(train["u"], train["y"], 40)
    w = float(model.weights.sum())
    lo, hi = model.offset - w, model.offset + w
    amp, c = 0.3 * (hi - lo), 0.5 * (lo + hi)
    for f_hz, goal in ((5.0, 0.02), (50.0, 0.04)):
        n = int(fs * (3 if f_hz < 10 else 10) / f_hz) + REST
        r = c - amp * np.cos(2 * np.pi * f_hz * np.maximum(np.arange(n) - REST, 0) / fs)
        err = {}
        for name, u in (("hysteresis", model.invert(r, method="continuous")), ("chain", gap.chain.invert(r, fs))):
            y = case["rig"].record(np.clip(u, 0.0, 10.0), fs, rng=np.random.default_rng(0))["y"]
            err[name] = float(np.abs(r - y)[REST + int(fs / f_hz):-50].max() / amp)
        assert err["chain"] < goal and err["chain"] < 0.5 * err["hysteresis"], (f_hz, err)


def _amplified(model: PreisachModel, gain: float, **amp: object) -> Chain:
    h = Chain(model).blocks[0]
    return Chain.from_blocks([{"type": "amplifier", "gain": gain, **amp}, h,
                              {"type": "lowpass", "cutoff_hz": 800.0, "order": 1}])


def test_inputs_beyond_the_amplifier_saturation_and_the_dac_range_are_clipped_counted_and_reported():
    rng = np.random.default_rng(5)
    model = true_hysteresis(rng, n_h=30)
    lo, hi = model.u_range
    gain = float(rng.uniform(2.0, 20.0))
    # The amplifier passes only the lower 70 % of the hysteresis's input range.
    top = lo + 0.7 * (hi - lo)
    free = _amplified(model, gain)
    sat = _amplified(model, gain, saturation=[lo, top])
    r = _reference(model, 1.0, 20.0, 4000, rng)
    u_free = free.invert(r, FS)
    over = u_free > top / gain
    assert over.any() and not over.all()  # the oracle: the same chain without the limit
    with pytest.warns(preisach.PreisachWarning, match=rf"{over.sum()} of {r.size} inputs were clipped .* "
                                                     rf"\(first at index {np.argmax(over)}\)"):
        u, info = sat.invert(r, FS, return_info=True)
    np.testing.assert_array_equal(u, np.minimum(u_free, top / gain))
    assert info.clipped == over.sum()
    inv = sat.inverter(FS)
    assert inv.input_limits == pytest.approx(tuple(sorted((lo / gain, top / gain))))
    streamed = np.concatenate([inv.process(r[:1000]), [inv.step(x) for x in r[1000:]]])
    np.testing.assert_array_equal(streamed[inv.latency:], u[:r.size - inv.latency])
    assert inv.clipped == over[:r.size - inv.latency].sum() + int((streamed[:inv.latency] >= top / gain).sum())
    # A DAC quantizer's range in front of the amplifier limits the input the same way.
    dac = Chain.from_blocks([{"type": "quantizer", "bits": 16, "range": [0.0, top / gain]}] + free.blocks)
    assert dac.inverter(FS).input_limits == pytest.approx((0.0, top / gain))


def test_a_reference_inside_the_amplifier_range_is_not_clipped():
    rng = np.random.default_rng(6)
    model = true_hysteresis(rng, n_h=30)
    chain = _amplified(model, 4.0, saturation=[model.u_range[0] - 1.0, model.u_range[1] + 1.0])
    r = _reference(model, 1.0, 20.0, 3000, rng)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        u, info = chain.invert(r, FS, return_info=True)
    assert info.clipped == 0
    np.testing.assert_array_equal(u, _amplified(model, 4.0).invert(r, FS))
