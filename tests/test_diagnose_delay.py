"""diagnose: a delay found where it shows. A delay only the holdouts carry is added to the
chain with the training record's own timing, fitted on some holdouts jointly with each
one's starting staircase (a start-only error is the initial state's, not the delay's)
and scored on the others; a delay a mode's fit takes from a low-pass replaces it. On the
project's simulator (``preisach.sim.Stage``) and on the independent rig, random
parameters."""
import independent_stage as bv
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from preisach.chain import Chain
from preisach.diagnose import diagnose
from preisach.diagnose.crossfit import _fit_delay, distinct, holdout_delay, profiles, shifted, shifted_sse
from preisach.diagnose.effects import FitState, Record, _grid_then_parabola
from preisach.diagnose.ranges import Bound, delay_grid
from preisach.diagnose.search import Fitter
from preisach.sim import Stage, hysteresis_block
from stage_records import stage_records


def _found(rep):
    return {e["name"]: e for e in rep.effects if e["detected"]}


def _why(rep):
    return [(e["name"], e["detected"], e["refused"]) for e in rep.effects]


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 40.0), st.integers(20, 300), st.integers(0, 2**31 - 1))
def test_the_shift_is_the_chains_delay_block(samples, n, seed):
    """The rows shifted in numpy are what the chain's delay block (Rust) gives."""
    y = np.random.default_rng(seed).standard_normal((3, n))
    dt = 1e-4
    t = np.arange(n) * dt
    ref = np.array([Chain(None, {"delay": {"delay_s": samples * dt}}).predict(t, r) for r in y])
    np.testing.assert_allclose(shifted(y, samples), ref, atol=1e-9)


class _Linear:
    """An identity "hysteresis" for the independent stage (its linear part alone)."""

    def predict(self, u):
        return np.asarray(u, dtype=np.float64)


@settings(max_examples=10, deadline=None)
@given(st.floats(500.0, 2000.0), st.floats(0.005, 0.05), st.floats(1e-4, 1e-3), st.sampled_from([20e3, 50e3]))
def test_the_independent_stages_delay_seen_is_its_lag_beyond_the_mode(f0, z, d, fs):
    """The truth a found delay is compared with on the independent stage: the measured
    lag of a slow sine through its mode and delay is ``delay_seen`` plus the continuous
    mode's own lag (``2 zeta / omega_0``, which the chain's mode carries), within 1 % of a
    sample."""
    eff = {"vibration": {"frequency_hz": f0, "damping": z}, "delay": {"delay_s": d}}
    f = 20.0
    t = np.arange(int(fs)) / fs
    u = 50.0 + 20.0 * np.sin(2 * np.pi * f * t)
    y = bv.simulate(_Linear(), eff, t, u, 0.0, np.random.default_rng(0))
    m = t.size // 2
    e = np.exp(-2j * np.pi * f * t[m:])
    lag = -np.angle(np.sum((y[m:] - y[m:].mean()) * e) / np.sum((u[m:] - 50.0) * e)) / (2 * np.pi * f)
    assert abs(lag - bv.delay_seen(eff, fs) - 2 * z / (2 * np.pi * f0)) * fs < 0.01


def test_a_delay_is_fitted_jointly_with_the_starting_staircase():
    """A record that starts with a rise through the range after unrecorded history (came
    down from a random high level: an offset on a ramp, which a delay also makes), then
    a sine (simulated through the chain): the delay fitted with the staircase profiled
    is the true one within 1 %, closer than the fit that ignores the start's memory."""
    rng = np.random.default_rng(7)
    hm = bv.true_hysteresis(rng, n_h=40)
    fs = 10e3
    lo, hi = hm.u_range
    span = hi - lo
    for _ in range(3):
        d = float(rng.uniform(3e-4, 2e-3))
        a, b = lo + 0.35 * span, lo + 0.65 * span
        ramp = np.linspace(lo + 0.05 * span, hi - 0.05 * span, 2000)
        sine = a + (b - a) * (0.5 + 0.5 * np.sin(2 * np.pi * 20 * np.arange(3000) / fs))
        u = np.concatenate([ramp, np.linspace(ramp[-1], a, 500), sine])
        t = np.arange(u.size) / fs
        blocks = Chain(hm, {"delay": {"delay_s": d}}).blocks
        blocks[0] = dict(blocks[0], initial_extrema=[float(rng.uniform(lo + 0.6 * span, hi))])
        y = Chain.from_blocks(blocks).predict(t, u) + 1e-3 * rng.standard_normal(u.size)
        rec = Record("r", t, u, y, 1.0 / fs)
        stt = FitState(hm, {})
        outs = profiles(stt, rec)
        bound = Bound(0.0, 0.02, False, physical_lo=True)
        joint = _fit_delay(stt, [(rec, slice(None))], bound, {"r": outs})
        blind = _fit_delay(stt, [(rec, slice(None))], bound, {"r": outs[:1]})
        assert abs(joint / d - 1) < 0.01 and abs(joint - d) < abs(blind - d), (joint, blind, d)


def _stage_records(seed, delay_s, fs=20e3, creep=None, lowpass=None):
    """The project's simulator: a random hysteresis (then a creep element ``creep``:
    (gain, time constant), and a low-pass ``lowpass``: (cutoff, order), on every record),
    a training record on a clean channel and two holdouts (triangle, steps) on one delayed
    by ``delay_s``."""
    rng = np.random.default_rng(seed)
    blocks = [hysteresis_block(bv.true_hysteresis(rng))]
    if creep is not None:
        blocks.append({"type": "creep", "gains": [creep[0]], "time_constants_s": [creep[1]]})
    if lowpass is not None:
        blocks.append({"type": "lowpass", "cutoff_hz": lowpass[0], "order": lowpass[1]})
    clean = Stage(blocks, sample_rate_hz=fs)
    delayed = Stage(blocks + [{"type": "delay", "delay_s": delay_s}], sample_rate_hz=fs)
    recs, t0 = [], 0.0
    for kind, stage in (("train", clean), ("triangle", delayed), ("steps", delayed)):
        u = bv.waveform(kind, fs, 1.5, rng)
        t = t0 + np.arange(u.size) / fs
        recs.append({"t": t, "u": u, "y": stage.simulate(t, u) + 0.003 * rng.standard_normal(u.size)})
        t0 = float(t[-1]) + 1.0
    return recs


def test_a_holdout_only_delay_on_the_project_simulator():
    rng = np.random.default_rng(2026)
    d = float(rng.uniform(3e-4, 3e-3))
    recs = _stage_records(int(rng.integers(1 << 30)), d)
    rep = diagnose(recs[0], recs[1:], progress=False)
    found = _found(rep)
    assert rep.dominant_effect == "delay" and set(found) == {"delay"}, _why(rep)
    assert found["delay"]["fitted_on"] == "holdouts"
    assert abs(found["delay"]["params"]["delay_s"] / d - 1) < 0.10, (found["delay"]["params"], d)


def test_real_creep_stays_next_to_a_holdout_only_delay_on_the_project_simulator():
    """Creep on every record (random gain and time constant) and a delay only the
    holdouts carry: both found; the creep, re-tested once the delay is in the chain, is
    kept."""
    rng = np.random.default_rng(2027)
    d = float(rng.uniform(3e-4, 3e-3))
    creep = (float(rng.uniform(0.04, 0.08)), float(np.exp(rng.uniform(np.log(0.05), np.log(0.3)))))
    recs = _stage_records(int(rng.integers(1 << 30)), d, creep=creep)
    rep = diagnose(recs[0], recs[1:], progress=False)
    found = _found(rep)
    assert {"creep", "delay"} <= set(found), _why(rep)
    assert abs(found["delay"]["params"]["delay_s"] / d - 1) < 0.10, (found["delay"]["params"], d)


def test_a_real_lowpass_stays_next_to_a_holdout_only_delay_on_the_project_simulator():
    """A low-pass on every record (random cutoff and order) and a delay only the holdouts
    carry, which hides the low-pass from the search's holdout score: both found (the
    low-pass on the holdouts' halves, once the delay is in the chain), its cutoff within
    half of the true one."""
    rng = np.random.default_rng(2028)
    d = float(rng.uniform(3e-4, 3e-3))
    lp = (float(rng.uniform(300.0, 1200.0)), int(rng.integers(1, 3)))
    recs = _stage_records(int(rng.integers(1 << 30)), d, lowpass=lp)
    rep = diagnose(recs[0], recs[1:], progress=False)
    found = _found(rep)
    assert {"lowpass", "delay"} <= set(found), _why(rep)
    assert abs(found["lowpass"]["params"]["cutoff_hz"] / lp[0] - 1) < 0.5, (found["lowpass"]["params"], lp)


def test_a_lowpass_standing_in_for_a_holdout_only_delay_is_dropped_on_the_rig():
    """A rig stage of the ``holdout_delay`` class whose search accepts a low-pass for part
    of the lag only the holdouts carry (its share of the lag chosen on them): once the
    delay is in the chain, the chain without the low-pass scores better and it is
    dropped; the delay alone, within 10 % of the holdouts' channel lag."""
    import rig

    case = rig.make_case("holdout_delay", 7004)
    truth = case["truth"]
    rep = diagnose(*rig.records(case), progress=False)
    found = _found(rep)
    assert set(found) == {"delay"}, _why(rep)
    assert "only the holdouts carry" in {e["name"]: e["refused"] for e in rep.effects}["lowpass"], _why(rep)
    lag = truth["delay_s"] + truth["timing_s"]
    assert abs(found["delay"]["params"]["delay_s"] / lag - 1) < 0.10, (found["delay"]["params"], lag)


def test_a_holdout_only_delay_on_the_rig():
    """The rig's ``holdout_delay`` class (random stage): the holdouts' channel lag (its
    delay plus the capture's timing) within 10 %, and nothing else (the creep the search
    accepts for part of the lag is dropped once the delay is in the chain)."""
    import rig

    case = rig.make_case("holdout_delay", 4711)
    truth = case["truth"]
    rep = diagnose(*rig.records(case), progress=False)
    found = _found(rep)
    assert rep.dominant_effect == "delay" and set(found) == {"delay"}, _why(rep)
    lag = truth["delay_s"] + truth["timing_s"]
    assert abs(found["delay"]["params"]["delay_s"] / lag - 1) < 0.10, (found["delay"]["params"], lag)


def test_a_mode_and_a_delay_on_the_rig():
    """The rig's ``paper_mode_delay`` class (the paper's protocol, random stage): the mode
    within 3 % and the delay within 10 % of the channel's delay plus the capture's lag
    (the chain's mode carries the stage mode's own), no low-pass standing in for its lag
    (the holdouts' steps choose a low-pass's share of the lag)."""
    import rig

    case = rig.make_case("paper_mode_delay", 4712)
    truth = case["truth"]
    rep = diagnose(*rig.records(case), progress=False)
    found = _found(rep)
    assert {"vibration", "delay"} <= set(found) and "lowpass" not in found, _why(rep)
    assert abs(found["vibration"]["params"]["frequency_hz"] / truth["modes"][0][0] - 1) < 0.03
    lag = truth["delay_s"] + truth["timing_s"]
    assert abs(found["delay"]["params"]["delay_s"] / lag - 1) < 0.10, (found["delay"]["params"], lag)


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 60.0), st.integers(20, 200), st.integers(0, 2**31 - 1), st.integers(0, 3))
def test_the_shifted_errors_are_those_of_the_shifted_rows(samples, n, seed, cut):
    """``shifted_sse`` (no shifted copy) is the sum of squares of the shifted rows' error
    on any slice (start, end, a half, all), shifts past the record's end included."""
    rng = np.random.default_rng(seed)
    rows, y = rng.standard_normal((4, n)), rng.standard_normal(n)
    sl = (slice(None), slice(0, n // 2), slice(n // 2, None), slice(n // 3, n - 3))[cut]
    ref = np.sum((shifted(rows, samples)[:, sl] - y[sl]) ** 2, axis=1)
    np.testing.assert_allclose(shifted_sse(rows, y, samples, sl), ref, rtol=1e-10, atol=1e-10)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**31 - 1), st.one_of(st.floats(-0.2, 1.2), st.integers(0, 8).map(lambda k: k / 8)),
       st.sampled_from([{}, {"vibration": {"frequency_hz": 300.0, "damping": 0.05},
                             "creep": {"taus_s": [0.02], "amplitudes": [0.05]}}]))
def test_the_profiles_run_only_the_starting_staircases_of_a_memory_of_their_own(seed, start, effects):
    """``profiles`` leaves out the starting staircases the first sample wipes out or that
    only repeat a shorter one (``initial.own_memory``): its distinct rows are those of
    every staircase run (the brute force), in the same order, whatever the first sample
    (on a staircase level, outside the model's range)."""
    from preisach.diagnose.initial import predictor, staircases

    rng = np.random.default_rng(seed)
    hm = bv.true_hysteresis(rng, n_h=20)
    lo, hi = hm.u_range
    t = np.arange(600) / 5e3
    u0 = lo + start * (hi - lo)
    u = u0 + 0.3 * (hi - lo) * np.sin(2 * np.pi * 15 * t) * rng.uniform(-1.0, 1.0)
    rec = Record("r", t, u, np.zeros_like(u), 2e-4)
    stt = FitState(hm, dict(effects, delay={"delay_s": 1e-3}))
    bare = FitState(hm, effects)
    brute = np.array([predictor(bare, rec)(ex) for ex in [None] + staircases(bare)])
    fast = profiles(stt, rec)
    np.testing.assert_array_equal(distinct(fast), distinct(brute))
    assert fast.shape[0] <= brute.shape[0]


@given(st.integers(0, 2**31 - 1), st.integers(1, 12), st.integers(1, 6), st.floats(0.0, 30.0))
def test_repeated_profiles_are_dropped_and_the_least_error_stays(seed, n_rows, n_kinds, samples):
    """``distinct``: every row kept once, in the order of its first appearance (the
    chain's output from rest stays first), and the least shifted error over the rows is
    the same as over all of them."""
    rng = np.random.default_rng(seed)
    kinds = rng.standard_normal((n_kinds, 50))
    pick = rng.integers(0, n_kinds, n_rows)
    rows, y = kinds[pick], rng.standard_normal(50)
    d = distinct(rows)
    first = sorted({int(k): i for i, k in reversed(list(enumerate(pick)))}.values())
    np.testing.assert_array_equal(d, rows[first])
    assert np.min(shifted_sse(d, y, samples, slice(None))) == np.min(shifted_sse(rows, y, samples, slice(None)))


def _plain_fit_delay(stt, parts, bound, outs):
    """The delay fit on the shifted rows themselves, every error computed anew (the
    oracle of the shared, copy-free fit)."""
    d0 = float(stt.effects.get("delay", {}).get("delay_s", 0.0))
    hi = max(bound.hi - d0, 0.0)
    dt = min(r.dt for r, _ in parts)
    if hi <= dt:
        return 0.0

    def sse(d):
        total = 0.0
        for r, sl in parts:
            e = shifted(outs[r.name], (d0 + max(d, 0.0)) / r.dt)[:, sl] - r.y[sl]
            s = np.sum(e * e, axis=1)
            total += float(np.min(s) if sl.start in (None, 0) else s[0])
        return total

    d, _ = _grid_then_parabola(sse, delay_grid(dt, hi))
    return float(min(max(d, 0.0), hi))


def _fitted(train, holdouts):
    """The hysteresis fitted to the training record (the diagnosis's fit, no effect) and
    the records."""
    def rec(name, r):
        return Record(name, r["t"], r["u"], r["y"], float(r["t"][1] - r["t"][0]))

    tr = rec("train", train)
    hos = [rec(f"holdout {i + 1}", h) for i, h in enumerate(holdouts)]
    fitter = Fitter(tr, 20, (float(tr.u.min()), float(tr.u.max())), stride=4)
    return fitter.state({}), hos


@pytest.mark.parametrize("source", ["project", "rig"])
def test_the_holdout_delay_fit_is_the_plain_one(source):
    """The holdouts' delay fit (its folds sharing each record's errors, computed without
    shifted copies) finds the delays the plain fit finds, fold by fold, with two holdouts
    and with one (its halves), on the project's simulator and on the rig."""
    import rig

    rng = np.random.default_rng(99 if source == "project" else 98)
    for _ in range(2):
        if source == "project":
            recs = _stage_records(int(rng.integers(1 << 30)), float(rng.uniform(3e-4, 3e-3)))
            stt, hos = _fitted(recs[0], recs[1:])
        else:
            stt, hos = _fitted(*rig.records(rig.make_case("holdout_delay", int(rng.integers(1 << 30)))))
        bound = Bound(0.0, 0.01, False, physical_lo=True)
        for hs in (hos, hos[:1]):
            outs = {h.name: profiles(stt, h) for h in hs}
            xf = holdout_delay(stt, hs, lambda s, hs=hs: [s.predict(h) - h.y for h in hs], bound)
            # Folds that no delay of at least ``min_delay`` fits alike are not scored.
            skip = holdout_delay(stt, hs, lambda s, hs=hs: [s.predict(h) - h.y for h in hs], bound, min_delay=1.0)
            assert xf["errors"] is not None and skip["errors"] is None and skip["plain"] is None
            assert skip["folds"] == xf["folds"] and skip["added_s"] == xf["added_s"]
            if len(hs) >= 2:
                fits = [[(g, slice(None)) for g in hs if g is not h] for h in hs]
            else:
                m = hs[0].y.size // 2
                fits = [[(hs[0], slice(0, m))], [(hs[0], slice(m, None))]]
            plain = [_plain_fit_delay(stt, f, bound, outs) for f in fits]
            np.testing.assert_allclose([f["added_s"] for f in xf["folds"]], plain, rtol=1e-6, atol=1e-9)
            full = _plain_fit_delay(stt, [(h, slice(None)) for h in hs], bound, outs)
            np.testing.assert_allclose(xf["added_s"], full, rtol=1e-6, atol=1e-9)


def _slow_sine_lag(y, u, fs, f):
    """The lag (seconds) of ``y``'s fundamental at ``f`` behind ``u``'s (second half)."""
    m = u.size // 2
    e = np.exp(-2j * np.pi * f * np.arange(m, u.size) / fs)
    return -np.angle(np.sum((y[m:] - y[m:].mean()) * e) / np.sum((u[m:] - u[m:].mean()) * e)) / (2 * np.pi * f)


def test_the_simulators_mode_leads_the_chains_by_half_a_sample():
    """``Stage.simulate`` samples a mode with the input held over the interval that ends
    at each sample (a step shows at the sample it is applied), the chain's ``predict``
    (the diagnosis's fits) with a first-order hold: on a slow sine the stage's mode leads
    by half a sample, so the delay a chain needs next to it is the stage's less half a
    sample."""
    fs, f = 20e3, 20.0
    u = 50.0 + 20.0 * np.sin(2 * np.pi * f * np.arange(int(fs)) / fs)
    t = np.arange(u.size) / fs
    blocks = [{"type": "vibration", "modes": [{"frequency_hz": 900.0, "damping": 0.02}]}]
    lead = _slow_sine_lag(Chain.from_blocks(blocks).predict(t, u), u, fs, f) - _slow_sine_lag(
        Stage(blocks, sample_rate_hz=fs).simulate(t, u), u, fs, f)
    assert abs(lead * fs - 0.5) < 0.01


@pytest.mark.parametrize("seed", [4713, 4714])
def test_a_mode_and_a_delay_on_the_project_simulator(seed):
    """A mode (600-1400 Hz, damping 0.01-0.04) and a delay (0.25-1 ms), random, on the
    project's simulator (a training sweep with steps, a triangle and steps held out, at
    20 kHz): both found, the mode within 3 % and the delay within 10 % of the delay a
    chain needs (the stage's less the half sample its mode leads; the chain's mode
    carries its own lag, the delay the rest)."""
    rng = np.random.default_rng(seed)
    f0, z = float(rng.uniform(600.0, 1400.0)), float(np.exp(rng.uniform(np.log(0.01), np.log(0.04))))
    d = float(rng.uniform(2.5e-4, 1e-3))
    recs = stage_records(seed, [{"type": "vibration", "modes": [{"frequency_hz": f0, "damping": z}]},
                                {"type": "delay", "delay_s": d}], fs=20e3)
    rep = diagnose(recs[0], recs[1:], progress=False)
    found = _found(rep)
    assert {"vibration", "delay"} <= set(found), _why(rep)
    assert abs(found["vibration"]["params"]["frequency_hz"] / f0 - 1) < 0.03, (found["vibration"]["params"], f0)
    need = d - 0.5 / 20e3
    assert abs(found["delay"]["params"]["delay_s"] / need - 1) < 0.10, (found["delay"]["params"], need)
