"""diagnose: a low-pass of a lag of two samples or less is an effect only where it beats
a delay of its lag (the record's timing: a capture's latency and anti-aliasing filter
act as a delay of a couple of samples). On the project's simulator (``preisach.sim.Stage``, random parameters) with a
real low-pass (found) and a small delay (found as a delay), and on the independent rig
with nothing but its capture lag (not a low-pass)."""
import math

import numpy as np
import pytest
from preisach.diagnose import diagnose
from preisach.diagnose.lag import delay_equivalent
from preisach.diagnose.search import group_delay
from stage_records import stage_records


def test_the_delay_equivalent_keeps_the_lag():
    eff = {"lowpass": {"cutoff_hz": 800.0, "order": 2}, "delay": {"delay_s": 1e-4}, "drift": {"gain_per_s": 0.01}}
    e = delay_equivalent(eff)
    assert "lowpass" not in e and e["drift"] == eff["drift"]
    assert e["delay"]["delay_s"] == pytest.approx(1e-4 + math.sqrt(2) / (2 * math.pi * 800.0))
    assert delay_equivalent({"lowpass": {"cutoff_hz": 500.0, "order": 1}})["delay"]["delay_s"] == pytest.approx(
        group_delay({"cutoff_hz": 500.0, "order": 1}))


@pytest.mark.parametrize("seed", [3, 4])
def test_a_real_lowpass_is_found(seed):
    rng = np.random.default_rng(100 + seed)
    lp = {"type": "lowpass", "cutoff_hz": float(rng.uniform(300.0, 1000.0)), "order": int(rng.integers(1, 3))}
    recs = stage_records(seed, [lp])
    rep = diagnose(recs[0], recs[1:], progress=False)
    assert rep.dominant_effect == "lowpass", [(e["name"], e["refused"]) for e in rep.effects]


def test_a_small_delay_is_found_as_a_delay():
    """Four samples at 20 kHz: fitted as a delay within 10 %, not as a low-pass."""
    fs = 20e3
    d = 4 / fs
    recs = stage_records(5, [{"type": "delay", "delay_s": d}], fs)
    rep = diagnose(recs[0], recs[1:], progress=False)
    found = {e["name"]: e for e in rep.effects if e["detected"]}
    assert rep.dominant_effect == "delay" and "lowpass" not in found, [(e["name"], e["refused"]) for e in rep.effects]
    assert abs(found["delay"]["params"]["delay_s"] / d - 1) < 0.10


def test_the_rigs_capture_lag_is_not_a_lowpass():
    import rig

    case = rig.make_case("none", 1000)
    tr, hos = rig.records(case)
    rep = diagnose(tr, hos, progress=False)
    lp = next(e for e in rep.effects if e["name"] == "lowpass")
    assert not lp["detected"], lp


def test_only_a_lag_of_two_samples_or_less_is_compared_with_its_delay():
    from preisach import PreisachModel
    from preisach.diagnose.effects import FitState
    from preisach.diagnose.lag import is_timing

    st = FitState(PreisachModel(np.zeros((2, 2)), (0.0, 1.0)), {"lowpass": {"cutoff_hz": 300.0, "order": 1}})

    def never(_):
        raise AssertionError("a lag longer than two samples is not compared")

    assert not is_timing(never, st, 0.1, 0.1, 0.0, 2e-4)  # group delay 0.53 ms > 0.2 ms
    fast = FitState(st.model, {"lowpass": {"cutoff_hz": 2e3, "order": 1}})  # 80 us
    assert is_timing(lambda s: 0.105, fast, 0.1, 0.1, 0.0, 2e-4)  # 5 % better than its delay
    assert not is_timing(lambda s: 0.2, fast, 0.1, 0.1, 0.0, 2e-4)  # half its delay's error
    assert not is_timing(lambda s: 0.105, fast, 0.1, 0.1, 0.0, 2e-5)  # the delay bar below its lag


def _detected(rep):
    return {e["name"]: e["params"] for e in rep.effects if e["detected"]}


@pytest.mark.parametrize("seed", [4716, pytest.param(4717, marks=pytest.mark.xfail(
    strict=True, reason="a known failure: a second-order 1.28 kHz low-pass at 10 kHz, whose group delay (0.18 ms) "
    "is shorter than two samples, is found as a delay of its lag and the capture's: the chain with the true "
    "low-pass scores worse on the holdouts, by the steps record's first level alone (set by masses that only the "
    "training record's lowest samples reach, which the two chains fit differently)"))])
def test_a_lowpass_on_the_rig_is_found_at_its_order_and_cutoff(seed):
    """The rig's ``lowpass`` class (a random 300-1500 Hz Butterworth of order 1 or 2 behind
    the capture's own lag of under two samples; the training record a slow sine, which
    shows either only as a lag): the holdouts' steps and faster sines choose the order
    and the low-pass's share of the lag. Found as the dominant effect at its order, the
    cutoff within 25 % (the capture's lag, about 1.7 samples, is shared between the delay
    and the low-pass), no delay detected."""
    import rig

    case = rig.make_case("lowpass", seed)
    fc, order = case["truth"]["lowpass"]
    rep = diagnose(*rig.records(case), progress=False)
    got = _detected(rep)
    assert rep.dominant_effect == "lowpass" and "delay" not in got, [(e["name"], e["refused"]) for e in rep.effects]
    assert got["lowpass"]["order"] == order
    assert abs(got["lowpass"]["cutoff_hz"] / fc - 1) < 0.25, (got["lowpass"], fc)


@pytest.mark.parametrize("seed", [2001, 2002])
def test_a_lowpass_on_the_independent_stage_is_found_at_its_order_and_cutoff(seed):
    """The independent stage (random cutoff and order, 50 kHz): the low-pass found at its
    order, the cutoff within 10 %, no delay."""
    import independent_stage as ist

    st = ist.make_stage(seed, ("lowpass",))
    true = st["params"]["lowpass"]
    rep = diagnose(st["train"], [{k: h[k] for k in "tuy"} for h in st["holdouts"]], progress=False)
    got = _detected(rep)
    assert rep.dominant_effect == "lowpass" and "delay" not in got, [(e["name"], e["refused"]) for e in rep.effects]
    assert got["lowpass"]["order"] == true["order"]
    assert abs(got["lowpass"]["cutoff_hz"] / true["cutoff_hz"] - 1) < 0.10, (got["lowpass"], true)


@pytest.mark.parametrize("seed", [2101, 2102])
def test_a_delay_on_the_independent_stage_is_not_a_lowpass(seed):
    """The independent stage with a random delay (0.1-1 ms): found as a delay within 10 %,
    no low-pass (a low-pass candidate may not take the delay's lag)."""
    import independent_stage as ist

    st = ist.make_stage(seed, ("delay",))
    d = st["params"]["delay"]["delay_s"]
    rep = diagnose(st["train"], [{k: h[k] for k in "tuy"} for h in st["holdouts"]], progress=False)
    got = _detected(rep)
    assert rep.dominant_effect == "delay" and "lowpass" not in got, [(e["name"], e["refused"]) for e in rep.effects]
    assert abs(got["delay"]["delay_s"] / d - 1) < 0.10, (got["delay"], d)
