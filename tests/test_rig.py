"""The independent rig (tests/rig.py) behaves as the physics it claims: the play-operator
hysteresis is rate independent with wiping-out, records start at rest, the capture reads
before the command acts and lags a slow command by its ``timing_s``, modes ring at their
frequency, a channel's delay is a shift."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

import rig


@pytest.fixture(scope="module")
def hyst() -> rig.PlayHysteresis:
    return rig.draw_hysteresis(np.random.default_rng(4))


def test_play_hysteresis_is_rate_independent(hyst: rig.PlayHysteresis) -> None:
    ext = [0.0, 120.0, 30.0, 90.0, 50.0, 140.0, 10.0]
    outs = []
    for per in (7, 113):
        x = np.concatenate([np.linspace(a, b, per) for a, b in zip(ext[:-1], ext[1:])])
        y, _ = hyst.run(x, hyst.rest_state([]))
        ends = np.cumsum([per] * (len(ext) - 1)) - 1
        outs.append(y[ends])
    np.testing.assert_allclose(outs[0], outs[1], rtol=0, atol=1e-12)


def test_play_hysteresis_wipes_out_inner_loops(hyst: rig.PlayHysteresis) -> None:
    p0 = hyst.rest_state([])
    plain = np.concatenate([np.linspace(0, 130, 50), np.linspace(130, 20, 50)])
    inner = np.concatenate([np.linspace(0, 80, 30), np.linspace(80, 40, 20), np.linspace(40, 130, 40),
                            np.linspace(130, 20, 50)])
    y1, _ = hyst.run(plain, p0)
    y2, _ = hyst.run(inner, p0)
    # After the input exceeds the inner maximum, the descent is the same.
    np.testing.assert_allclose(y1[-50:], y2[-50:], atol=1e-12)
    # And the loop is a loop: descending branch above the ascending one at mid input.
    assert y1[75] > np.interp(plain[75], plain[:50], y1[:50])


def _quiet(r: rig.Rig) -> rig.Rig:
    r.noise_std = 0.0
    r.wander_std = 0.0
    return r


def test_a_record_at_rest_starts_without_a_transient() -> None:
    r = _quiet(rig.draw_rig(np.random.default_rng(1), ("vibration", "creep", "lowpass"), 10e3))
    rec = r.record(np.full(2000, 4.0), 10e3)
    assert np.ptp(rec["y"]) <= 2 * 20.0 / 2**16  # the ADC's resolution only


def test_the_capture_reads_before_the_command_acts() -> None:
    r = _quiet(rig.Rig(hyst=rig.draw_hysteresis(np.random.default_rng(2)), amp_hz=1e7, aa_hz=0.45 * 1e4 * 4))
    u = np.r_[np.full(50, 2.0), np.full(50, 6.0)]
    y = r.record(u, 1e4)["y"]
    assert abs(y[50] - y[0]) < 1e-3 and abs(y[52] - y[0]) > 0.5


def _phase_lag(r: rig.Rig, fs: float, f: float, channel: str = "clean") -> float:
    """The lag (seconds) of a slow sine's fundamental through the rig with a linear
    "hysteresis" (measured on the capture, the transient of the first half dropped)."""
    h = r.hyst
    h.w = np.zeros_like(h.w)
    h.kappa, h.eps, h.a = 0.0, 0.0, 1.0
    t = np.arange(int(2 * fs)) / fs
    u = 5.0 + 2.0 * np.sin(2 * np.pi * f * t)
    y = r.record(u, fs, channel=channel)["y"]
    m = t.size // 2
    e = np.exp(-2j * np.pi * f * t[m:])
    return float(-np.angle(np.sum((y[m:] - y[m:].mean()) * e) / np.sum((u[m:] - 5.0) * e)) / (2 * np.pi * f))


@pytest.mark.parametrize("effects,fs", [((), 10e3), (("vibration", "delay"), 10e3), (("vibration",), 5e3)])
def test_the_timing_is_the_lag_of_a_slow_command(effects: tuple[str, ...], fs: float) -> None:
    """What a delay fitted on the capture approaches (random stages): the measured lag of
    a 10 Hz and a 40 Hz sine is ``timing_s`` (with the modes) plus the channel's delay,
    within a step of the analog grid (a sixteenth of a sample; a sample of latency on
    top of the DAC's hold would be sixteen); without the modes
    (a chain carrying them), the lag of the same stage without them."""
    for seed in range(2):
        r = _quiet(rig.draw_rig(np.random.default_rng(40 + seed), effects, fs))
        d = r.delays["clean"]
        for f in (10.0, 40.0):
            assert abs(_phase_lag(r, fs, f) - d - r.timing_s(fs)) * fs < 1 / rig.OVERSAMPLE
        lag = r.timing_s(fs, modes=False)
        r.modes = []
        assert abs(_phase_lag(r, fs, 10.0) - d - lag) * fs < 1 / rig.OVERSAMPLE


def test_a_mode_rings_at_its_frequency_after_a_step_from_rest() -> None:
    fs = 10e3
    r = _quiet(rig.draw_rig(np.random.default_rng(3), ("vibration",), fs))
    f0, z0 = r.modes[0]
    y = r.record(np.full(4000, 6.0), fs, rest=1.0)["y"]
    ring = y[5:] - np.mean(y[-500:])
    spec = np.abs(np.fft.rfft(ring * np.hanning(ring.size), 8 * ring.size))
    f = np.fft.rfftfreq(8 * ring.size, 1 / fs)
    fd = f0 * math.sqrt(1 - z0 * z0)
    assert abs(f[np.argmax(spec)] / fd - 1) < 0.01


def test_a_delayed_channel_is_the_clean_one_shifted() -> None:
    fs = 10e3
    r = _quiet(rig.draw_rig(np.random.default_rng(5), (), fs))
    r.delays = {"clean": 0.0, "delayed": 7 / fs}
    u = rig.wf_sine(fs, 20.0, 0.3)
    clean = r.record(u, fs)["y"]
    late = r.record(u, fs, channel="delayed")["y"]
    np.testing.assert_allclose(late[7:], clean[:-7], atol=2 * 20.0 / 2**16)


def test_the_analog_chain_matches_lsim_of_the_whole_system() -> None:
    # With a linear "hysteresis" the capture is one continuous system driven by the DAC's
    # held commands: scipy.signal.lsim of the product system on the fine grid, read at
    # the ticks one fine step before each command acts.
    fs = 10e3
    r = _quiet(rig.draw_rig(np.random.default_rng(6), ("vibration", "lowpass"), fs))
    h = r.hyst
    h.w = np.zeros_like(h.w)
    h.kappa, h.eps, h.a = 0.0, 0.0, 0.2
    u = 1.0 + 4.0 * (np.arange(3000) >= 100) + np.sin(2 * np.pi * 45 * np.arange(3000) / fs)
    got = r.record(u, fs, rest=1.0)["y"]
    wa = 2 * math.pi * r.amp_hz
    b, a = np.array([rig.AMP_GAIN * wa * h.a * r.sensor_gain]), np.array([1.0, wa])
    for bb, aa in r._analog():
        b, a = np.polymul(b, bb), np.polymul(a, aa)
    dac = np.repeat(u, rig.OVERSAMPLE) - 1.0  # deviation from rest (lsim starts at rest at 0)
    tf = np.arange(dac.size) / (fs * rig.OVERSAMPLE)
    _, y, _ = signal.lsim((b, a), dac, tf, interp=False)
    want = y[::rig.OVERSAMPLE] + got[0]
    # (FOH between fine steps: 0.2 % on the fastest transient; a one-sample shift is 20 %.)
    assert np.max(np.abs(got - want)) < 3e-3 * np.ptp(want)


@pytest.mark.parametrize("name", sorted(rig.CLASSES))
def test_every_class_makes_records_with_a_truth(name: str) -> None:
    c = rig.make_case(name, 11)
    recs = [c["train"], *c["holdouts"], c["blind"]]
    assert all(np.all(np.diff(r["t"]) > 0) and np.all(np.isfinite(r["y"])) for r in recs)
    assert c["truth"]["dominant"] == (c["truth"]["effects"][0] if c["truth"]["effects"] else "none")
    if name == "repeats":
        assert all(np.array_equal(r["u"], recs[0]["u"]) for r in recs)
