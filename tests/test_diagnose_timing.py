"""diagnose: the record's own timing (``Fitter.timing``): a delay shorter than the
shortest one called a delay, fitted on the profiled error of the training record. On the
project's simulator (``preisach.sim.Stage``, random hysteresis and delay) and the
independent rig (``tests/rig.py``, whose capture lags by half a sample of its DAC's
hold, its filters and its well-damped mode: ``Rig.timing_s``)."""
import independent_stage as bv
import numpy as np
import pytest
import rig

from preisach.diagnose.effects import Record
from preisach.diagnose.search import Fitter
from preisach.sim import Stage, hysteresis_block


def _stage_record(seed, delay_samples, fs=4e3):
    """A random hysteresis behind a delay of ``delay_samples`` samples (none when 0),
    driven by the independent stage's training sweep, with noise."""
    rng = np.random.default_rng(seed)
    blocks = [hysteresis_block(bv.true_hysteresis(rng))]
    if delay_samples > 0:
        blocks.append({"type": "delay", "delay_s": delay_samples / fs})
    stage = Stage(blocks, sample_rate_hz=fs)
    u = bv.waveform("train", fs, 2.0, rng)
    t = np.arange(u.size) / fs
    return Record("train", t, u, stage.simulate(t, u) + 0.002 * rng.standard_normal(u.size), 1 / fs)


def _fitter(rec, n_h=30):
    lo, hi = float(rec.u.min()), float(rec.u.max())
    pad = 0.05 * (hi - lo)
    return Fitter(rec, n_h, (lo - pad, hi + pad))


def _timing(fitter):
    return float(fitter.timing({}).get("delay", {"delay_s": 0.0})["delay_s"])


@pytest.mark.parametrize("seed", [11, 12])
def test_the_timing_fit_recovers_a_delay_below_two_samples_on_the_simulator(seed):
    """A delay of 0.4 to 1.7 samples (random) within a tenth of a sample, below the bound."""
    d = float(np.random.default_rng(seed + 100).uniform(0.4, 1.7))
    rec = _stage_record(seed, d)
    f = _fitter(rec)
    got = _timing(f) / rec.dt
    assert got < 2.0
    assert abs(got - d) < 0.1, (got, d)


@pytest.mark.parametrize("seed", [13, 14])
def test_the_timing_fit_finds_no_delay_where_there_is_none(seed):
    """The simulator without a delay: none, or one far below a sample."""
    rec = _stage_record(seed, 0.0)
    assert _timing(_fitter(rec)) / rec.dt < 0.1


@pytest.mark.parametrize("seed", [21, 22])
def test_the_timing_fit_on_the_rig_is_the_same_lag_on_every_record(seed):
    """The rig's capture (random stage, no effect) lags by its DAC's hold, its filters and
    its well-damped mode (``timing_s``, about 1.7 samples): the timing fitted at the
    diagnosis's bound (two samples) on its identification sine and on its steps, triangle
    and sine records is that lag within a quarter of a sample, the same within a third of
    a sample on every record."""
    case = rig.make_case("none", seed)
    fs = case["fs"]
    got = []
    for r in [case["train"], *case["holdouts"], case["blind"]]:
        f = _fitter(Record(r["kind"], r["t"], r["u"], r["y"], 1 / fs))
        f.min_delay = 2 / fs
        got.append(_timing(f) * fs)
    assert all(abs(g - case["truth"]["timing_s"] * fs) < 0.25 for g in got), (got, case["truth"]["timing_s"] * fs)
    assert max(got) - min(got) < 1 / 3, got
