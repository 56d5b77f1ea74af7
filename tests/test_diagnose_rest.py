"""diagnose: records that start with a step from an unrecorded rest level. The rest
input before the first sample is estimated (the chain's initial condition), the ringing
that follows is explained by the mode, and the start is localized as after a step. On
the project's simulator (``preisach.sim.Stage``, random parameters) and on the
independent rig (``tests/rig.py``)."""
import math

import independent_stage as bv
import numpy as np
import pytest
from lti_reference import tf_lowpass, tf_mode
from scipy import signal

from preisach.diagnose import diagnose
from preisach.diagnose import rest as rest_mod
from preisach.diagnose.effects import FitState, Record
from preisach.sim import Stage, hysteresis_block


@pytest.mark.parametrize("f,z", [(700.0, 0.02), (1300.0, 0.005)])
def test_the_transient_is_one_minus_the_step_response(f, z):
    """``1 - s(t)`` of a mode and a low-pass in series, against SciPy's response of the
    product of their transfer functions to the first-order hold's input: 1 at rest, a
    ramp to 0 over the sample before the first."""
    fs = 50e3
    dt = 1 / fs
    t = np.arange(4000) * dt
    eff = {"vibration": {"frequency_hz": f, "damping": z}, "lowpass": {"cutoff_hz": 3e3, "order": 2}}
    col = rest_mod.transient(eff, t)
    (bm, am), (bl, al) = tf_mode(f, z), tf_lowpass(3e3, 2)
    sys_ = signal.lti(np.polymul(bm, bl), np.polymul(am, al))
    tt = np.linspace(-dt, t[-1], 40 * t.size + 1)
    xx = np.interp(tt, [-dt, 0.0], [1.0, 0.0])
    _, yy, _ = signal.lsim(sys_, xx - 1.0, tt - tt[0])
    np.testing.assert_allclose(col, 1.0 + yy[40::40], atol=3e-3)
    assert rest_mod.transient({"delay": {"delay_s": 1e-3}}, t) is None  # no dynamics: no transient
    k = rest_mod.support(col)
    assert np.all(np.abs(col[k:]) < 0.05 * np.max(np.abs(col))) and abs(col[k - 1]) >= 0.05 * np.max(np.abs(col))


def _stage(seed, fs=20e3):
    """The project's simulator with a random hysteresis (``independent_stage``'s smooth
    random density) and a random lightly damped mode."""
    rng = np.random.default_rng(seed)
    hm = bv.true_hysteresis(rng)
    mode = {"frequency_hz": float(rng.uniform(600.0, 1400.0)),
            "damping": float(math.exp(rng.uniform(math.log(0.01), math.log(0.04))))}
    stage = Stage([hysteresis_block(hm), {"type": "vibration", "modes": [mode]}], sample_rate_hz=fs)
    return stage, mode, rng


def test_rest_input_recovered_through_the_exact_chain():
    """A record simulated by the chain itself from a rest below its first input: the
    transient's amplitude, inverted on the hysteresis's rising branch, is the rest."""
    stage, mode, rng = _stage(3)
    fs = 20e3
    t = np.arange(int(0.3 * fs)) / fs
    u = 60.0 + 25.0 * np.sin(2 * np.pi * 5.0 * t)
    st = FitState(stage.model, {"vibration": mode})
    for r0 in (5.0, 30.0, 55.0):
        y = stage.simulate(t, u, initial_input=r0) + 1e-3 * rng.standard_normal(t.size)
        rec = Record("r", t, u, y, 1 / fs)
        fixed, a = rest_mod.remove(st, rec, st.predict(rec) - y)
        assert a < 0  # the rest lay below the first input
        assert rest_mod.rest_input(st, rec, a, (0.0, 100.0)) == pytest.approx(r0, abs=1.0)
        assert np.sqrt(np.mean(fixed ** 2)) < 0.2 * np.sqrt(np.mean((st.predict(rec) - y) ** 2))
    # A record that starts at rest at its first input: nothing to remove.
    y = stage.simulate(t, u) + 1e-3 * rng.standard_normal(t.size)
    rec = Record("r", t, u, y, 1 / fs)
    e = st.predict(rec) - y
    fixed, a = rest_mod.remove(st, rec, e)
    assert a == 0.0 and fixed is e


def _check(rep, rests, freq, u_train, steps=None):
    """The mode found and dominant, each record's rest input (where the training input
    reached it: below, the model cannot tell its rising branch; ``rest_input`` is then
    the training input's lowest value) within 5 % of the input span, each step (the
    output's change from the rest to the first sample) within 5 %."""
    found = [(e["name"], e["shrink_vs_current"], e["refused"]) for e in rep.effects]
    assert rep.dominant_effect == "vibration", found
    v = next(e for e in rep.effects if e["name"] == "vibration")
    assert abs(v["params"]["frequency_hz"] / freq - 1) < 0.03
    got = v["params"]["rest_input"]
    assert got == rep.augmented["rest_input"] and set(got) == set(rests)
    lo, span = float(np.min(u_train)), float(np.ptp(u_train))
    for name, r0 in rests.items():
        assert abs(got[name] - max(r0, lo)) < 0.05 * span, (name, got[name], r0)
        if steps is not None:
            assert v["params"]["rest_step"][name] == pytest.approx(steps[name], rel=0.05)
    # The start of the training record (a smooth sine: no step of its own) is where
    # its error lies: after the step from rest.
    assert rep.where[0]["segments"]["after_step"]["share_of_error"] > 0.5


def test_a_step_from_rest_is_explained_by_the_mode_on_the_project_stage():
    """The paper's protocol (a smooth sine of increasing amplitude far below the mode,
    from mid-range) and holdouts of steps and a triangle from mid-range, every record
    starting at a step from an unrecorded rest level below its first input."""
    stage, mode, rng = _stage(7)
    fs = 20e3
    recs, rests, steps, t0 = [], {}, {}, 0.0
    for name in ("train", "holdout 1", "holdout 2"):
        tt = np.arange(int((1.5 if name == "train" else 1.0) * fs)) / fs
        if name == "train":
            u = 50.0 - 45.0 * np.linspace(0.05, 1.0, tt.size) * np.cos(2 * np.pi * 8.0 * tt)
        elif name == "holdout 1":
            u = np.repeat(np.r_[rng.uniform(40.0, 60.0), rng.uniform(10.0, 90.0, 7)], tt.size // 8)
        else:
            u = 50.0 + 40.0 * (2 / np.pi) * np.arcsin(np.sin(2 * np.pi * rng.uniform(10.0, 30.0) * tt))
        r0 = float(rng.uniform(0.0, 0.25 * u[0]))
        t = t0 + np.arange(u.size) / fs
        y = stage.simulate(t, u, initial_input=r0) + 0.003 * rng.standard_normal(u.size)
        recs.append({"t": t, "u": u, "y": y, "name": name})
        rests[name] = r0
        steps[name] = float(np.diff(stage.model.predict(np.array([r0, u[0]])))[0])
        t0 = float(t[-1]) + 1.0
    rep = diagnose(recs[0], recs[1:], progress=False)
    _check(rep, rests, mode["frequency_hz"], recs[0]["u"], steps)


def test_a_step_from_rest_on_the_rig():
    import rig

    case = rig.make_case("step_from_rest", 1005)
    tr, hos = rig.records(case)
    rep = diagnose(tr, hos, progress=False)
    rests = {n: r["rest"] for n, r in zip(("train", "holdout 1", "holdout 2"), case["truth"]["records"])}
    _check(rep, rests, case["truth"]["modes"][0][0], tr["u"])


def test_the_start_counts_only_when_it_carries_an_error_of_its_own():
    assert not rest_mod.concentrated(0.01, 0.004, 0.01)  # no larger than the rest of the record
    assert not rest_mod.concentrated(1.0, 0.6, 0.01)  # not halved by the transient
    assert rest_mod.concentrated(1.0, 0.1, 0.01)
    col = np.exp(-np.arange(1000) / 10.0)
    assert rest_mod.amplitude(-2.0 * col, col) == pytest.approx(2.0)
    r = np.r_[np.full(400, 1.0), 0.01 * np.ones(20_000)]
    assert rest_mod.starts_with_step(r, 1e-4) and not rest_mod.starts_with_step(np.ones(20_000), 1e-4)
