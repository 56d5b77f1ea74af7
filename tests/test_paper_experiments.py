"""The paper's three compensation experiments (the paper §4.2) on the simulated `paper` stage.

Identification: a sine of increasing amplitude with 100 reversals (50 periods at 10 Hz,
between the creep band below 5 Hz and a tenth of the 780 Hz resonance, the paper §3.1),
then the paper's interpolated closest-match inverse (Fig. 9) as feed-forward, tracking
a 10 µm amplitude sine (2 V at the 1/5 V/µm sensor):

- §4.2.1 n_h = 10 at 5 Hz: poor (large error at the extrema);
- §4.2.2 n_h = 100 at 50 Hz: vibrations near the resonance, error still below §4.2.1;
- §4.2.3 n_h = 100 at 5 Hz: the best.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import preisach
from preisach.sim import Stage, run_loop

FS = 100_000.0
SENSOR_V_PER_UM = 0.2
RESONANCE_HZ = 780.0
BAND = (650.0, 950.0)  # around the resonance, avoiding the 50 Hz fundamental's low harmonics


def identification_input(f_hz: float = 10.0, reversals: int = 100) -> np.ndarray:
    periods = reversals // 2
    n = int(round(periods / f_hz * FS))
    t = np.arange(n) / FS
    envelope = 0.05 + 0.95 * t / t[-1]
    # DAC 0–7.5 V is the usable range (0–150 V at the piezo).
    return 3.75 + 3.7 * envelope * np.sin(2 * np.pi * f_hz * t)


def band_rms(x: np.ndarray, lo: float, hi: float) -> float:
    """RMS of the part of `x` in [lo, hi] Hz (Parseval over a Hann-free DFT of whole periods)."""
    spec = np.fft.rfft(x - x.mean())
    f = np.fft.rfftfreq(len(x), 1 / FS)
    sel = (f >= lo) & (f <= hi)
    return float(np.sqrt(2 * np.sum(np.abs(spec[sel]) ** 2)) / len(x))


def peak_hz(x: np.ndarray, lo: float, hi: float) -> float:
    spec = np.abs(np.fft.rfft(x - x.mean()))
    f = np.fft.rfftfreq(len(x), 1 / FS)
    sel = (f >= lo) & (f <= hi)
    return float(f[sel][np.argmax(spec[sel])])


@pytest.fixture(scope="module")
def experiments() -> dict:
    stage = Stage.preset("paper")
    u = identification_input()
    y = stage.run(u)
    mid = 0.5 * (y.min() + y.max())
    models = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", preisach.PreisachWarning)
        for n_h in (10, 100):
            models[n_h] = preisach.PreisachModel.fit(u, y, n_h)
    out: dict = {"_models": models, "_mid": mid}
    for name, n_h, f in (("low_discretization", 10, 5.0), ("high_frequency", 100, 50.0), ("best", 100, 5.0)):
        periods = 4
        r = reference(mid, f, periods)
        n = len(r)
        res = run_loop(models[n_h], stage, r, method="interpolated")
        # Judge the last three periods (the first starts from negative saturation).
        k0 = n // periods
        e = res.error[k0:] / SENSOR_V_PER_UM  # µm
        out[name] = {
            "n_h": n_h,
            "f": f,
            "rms_um": float(np.sqrt(np.mean(e**2))),
            "max_um": float(np.abs(e).max()),
            "band_um": band_rms(res.y[k0:], *BAND) / SENSOR_V_PER_UM,
            "peak_hz": peak_hz(res.error[k0:], 500.0, 1200.0),
            "timing": res.timing,
        }
    return out


def reference(mid: float, f: float, periods: int = 4) -> np.ndarray:
    n = int(round(periods / f * FS))
    return mid + 10.0 * SENSOR_V_PER_UM * np.sin(2 * np.pi * f * np.arange(n) / FS)


def test_summary_covers_every_sample_of_each_experiment(experiments: dict) -> None:
    """The figures quoted in docs/benchmarks.md: each experiment ran its whole reference
    through the 100 kHz loop (every sample timed) and its figures are consistent (an RMS
    error no larger than the peak error, the vibration peak inside the searched band).
    `pytest -s` prints them."""
    for name, d in experiments.items():
        if name.startswith("_"):
            continue
        t = d["timing"]
        assert t.samples == len(reference(experiments["_mid"], d["f"]))
        assert 0.0 < d["rms_um"] <= d["max_um"]
        assert 500.0 <= d["peak_hz"] <= 1200.0
        print(f"{name:20s} n_h={d['n_h']:4d} f={d['f']:5.1f} Hz  rms {d['rms_um']:.3f} µm  max {d['max_um']:.3f} µm"
              f"  band {d['band_um'] * 1000:.1f} nm  peak {d['peak_hz']:.0f} Hz"
              f"  loop mean {t.mean_ns:.0f} ns p99 {t.p99_ns:.0f} ns")


def test_low_discretization_is_far_worse(experiments: dict) -> None:
    """§4.2.1: n_h = 10 gives a significant error, far above n_h = 100 at the same 5 Hz."""
    low, best = experiments["low_discretization"], experiments["best"]
    assert low["rms_um"] > 2.5 * best["rms_um"]
    assert low["max_um"] > 2.0 * best["max_um"]
    assert low["rms_um"] > 0.5  # "significant" against a 10 µm amplitude


def test_high_frequency_excites_the_resonance(experiments: dict) -> None:
    """§4.2.2: at 50 Hz the measurement carries vibrations near the resonance (the
    same loop on a stage whose mode is well damped has almost none), more than at
    5 Hz, and they show in the peak error; yet the error stays below the n_h = 10 case.
    (The paper judges this case by its vibrations; with the stage starting at rest its
    RMS error is as small as the 5 Hz one, so RMS is not what separates them.)"""
    hf, best, low = experiments["high_frequency"], experiments["best"], experiments["low_discretization"]
    r = reference(experiments["_mid"], 50.0)
    k0 = len(r) // 4
    damped = run_loop(experiments["_models"][100], Stage.preset("paper", damping=0.7), r, method="interpolated")
    damped_band = band_rms(damped.y[k0:], *BAND) / SENSOR_V_PER_UM
    assert hf["band_um"] > 10 * damped_band
    assert hf["band_um"] > 2 * best["band_um"]
    assert abs(hf["peak_hz"] - RESONANCE_HZ) < 100.0
    assert hf["max_um"] > best["max_um"]
    assert hf["rms_um"] < low["rms_um"]


def test_high_discretization_low_frequency_is_best(experiments: dict) -> None:
    """§4.2.3: n_h = 100 at 5 Hz is the best of the three: the smallest peak error (the
    paper's measure: about 5 % at the maximum), the least vibration, and an RMS error
    no larger than the others'."""
    best = experiments["best"]
    for other in ("low_discretization", "high_frequency"):
        assert best["max_um"] < experiments[other]["max_um"]
        assert best["band_um"] < experiments[other]["band_um"]
        assert best["rms_um"] <= 1.02 * experiments[other]["rms_um"]
    assert best["rms_um"] < 0.05 * 10.0  # within 5 % of the 10 µm amplitude
