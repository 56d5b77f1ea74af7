"""Chain blocks against SciPy (test-only dependency) and JSON round trips."""
import json
import math

import numpy as np
import pytest
from scipy import signal

from preisach import PreisachModel
from preisach.chain import Chain, butterworth_pf, delay_signal, lti, mode_pf


def _x(n=20000, fs=50e3, seed=0):
    rng = np.random.default_rng(seed)
    x = np.convolve(np.cumsum(rng.normal(size=n)) * 0.01, np.ones(40) / 40, "same")
    return np.arange(n) / fs, x + (np.arange(n) > n // 2)


@pytest.mark.parametrize("order,fc", [(1, 800.0), (2, 1500.0), (3, 600.0)])
def test_butterworth_matches_scipy_lsim(order, fc):
    t, x = _x()
    P, R = butterworth_pf(fc, order)
    b, a = signal.butter(order, 2 * math.pi * fc, analog=True)
    _, yr, _ = signal.lsim(signal.lti(b, a), x - x[0], t, interp=True)
    assert np.max(np.abs(lti(x, t[1] - t[0], P, R) - (yr + x[0]))) < 1e-9


def test_mode_matches_scipy_and_rings_at_its_frequency():
    t, x = _x()
    w = 2 * math.pi * 900
    _, yr, _ = signal.lsim(signal.lti([w * w], [1, 2 * 0.01 * w, w * w]), x - x[0], t, interp=True)
    P, R = mode_pf(900, 0.01)
    assert np.max(np.abs(lti(x, t[1] - t[0], P, R) - (yr + x[0]))) < 1e-8


def test_slow_pole_is_exact_over_long_records():
    # tau = 10 s at 50 kHz: the closed forms cancel catastrophically without the series.
    t, x = _x(200000)
    y = lti(x, t[1] - t[0], [complex(-0.1)], [complex(0.1)])
    _, yr, _ = signal.lsim(signal.lti([0.1], [1, 0.1]), x - x[0], t, interp=True)
    assert np.max(np.abs(y - (yr + x[0]))) < 1e-9


@pytest.mark.parametrize("fs,fc,order", [(25e3, 5600.0, 2), (50e3, 12e3, 1), (100e3, 20e3, 4), (25e3, 11e3, 3)])
def test_fast_poles_match_scipy_over_many_blocks(fs, fc, order):
    # Fast poles split the record into many short blocks whose carries are summed at
    # once; the result must still be the exact first-order-hold response.
    t, x = _x(30000, fs, seed=3)
    P, R = butterworth_pf(fc, order)
    b, a = signal.butter(order, 2 * math.pi * fc, analog=True)
    _, yr, _ = signal.lsim(signal.lti(b, a), x - x[0], t, interp=True)
    y = lti(x, t[1] - t[0], P, R)
    assert np.max(np.abs(y - (yr + x[0]))) < 1e-11
    # At rest: a constant input gives the constant back from the first sample.
    assert np.max(np.abs(lti(np.full(5000, 2.5), t[1] - t[0], P, R) - 2.5)) < 1e-12


def test_delay_is_a_shift_at_rest_before_start():
    x = np.sin(np.linspace(0, 10, 1000)) + 2
    y = delay_signal(x, 7.0, 1.0)
    assert np.allclose(y[7:], x[:-7]) and np.allclose(y[:7], x[0])


def _model():
    n = 20
    w = np.triu(np.ones((n, n))) / n
    return PreisachModel(w, (0, 10), 0.5, "interpolated")


def test_chain_round_trip_and_rate_independence_of_parameters(tmp_path):
    eff = [{"name": "delay", "params": {"delay_s": 3e-4}},
           {"name": "vibration", "params": {"frequency_hz": 800.0, "damping": 0.02}},
           {"name": "drift", "params": {"gain_per_s": 0.01, "offset": 0.1, "offset_per_s": 0.0}}]
    ch = Chain(_model(), eff)
    p = tmp_path / "c.json"
    ch.save(p)
    d = json.loads(p.read_text())
    assert d["format"] == "preisach-chain" and d["version"] == 1
    ch2 = Chain.load(p)
    fs1, fs2 = 100e3, 20e3
    t1 = np.arange(int(0.2 * fs1)) / fs1
    t2 = np.arange(int(0.2 * fs2)) / fs2
    u = lambda t: 5 + 4 * np.sin(2 * np.pi * 15 * t - np.pi / 2)  # noqa: E731
    y1 = ch2.predict(t1, u(t1))
    y2 = ch2.predict(t2, u(t2))
    # The same physical chain at two sample rates agrees where the samples coincide.
    assert np.max(np.abs(y1[::5] - y2)) < 0.02 * np.ptp(y1)
    assert np.allclose(ch.predict(t1, u(t1)), y1)


def test_chain_rejects_bad_effects():
    with pytest.raises(ValueError, match="unknown effect"):
        Chain(_model(), [{"name": "magic", "params": {}}])
    with pytest.raises(ValueError, match="delay_s"):
        Chain(_model(), [{"name": "delay", "params": {}}])
    with pytest.raises(ValueError, match="format"):
        Chain.from_dict({"format": "x"})
