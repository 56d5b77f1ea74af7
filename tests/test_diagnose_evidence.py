"""diagnose: an honest ``none``. Drift and rate are detected only on held-out evidence
of their kind (a trend calibrated on the other records shrinks each holdout's error; a
rate effect beats the record's timing), and the masses the training record does not
identify cannot stand in for an effect on the holdouts. No false alarm where there is
nothing to find, and real drift and rate effects are still found: on the independent
rig (``tests/rig.py``), the independent stage (``tests/independent_stage.py``, SciPy)
and the project's simulator (``preisach.sim.Stage``), with random parameters."""
import warnings

import independent_stage as bv
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from preisach import PreisachModel
from preisach.diagnose import diagnose
from preisach.diagnose.identified import identified, unidentified
from scipy import signal
from stage_records import stage_records

FALSE_ALARMS = {"drift", "rate"}


def _found(rep):
    return {e["name"] for e in rep.effects if e["detected"]}


# -- the masses a record identifies ----------------------------------------------------
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_h=st.integers(3, 24), start=st.floats(0.2, 0.8))
def test_unidentified_masses_are_dropped_and_the_records_output_is_kept(seed, n_h, start):
    rng = np.random.default_rng(seed)
    w = np.triu(rng.uniform(0.0, 1.0, (n_h, n_h)))
    model = PreisachModel(w, (0.0, 1.0), float(rng.normal()), "interpolated")
    # A record that starts mid-range and stays inside the model range.
    lo, hi = rng.uniform(0.05, 0.95 * start), rng.uniform(start + 0.05 * (1 - start), 0.95)
    t = np.linspace(0.0, 1.0, 800)
    u = np.clip(start + (hi - lo) / 2 * np.sin(2 * np.pi * 3 * t) * t, lo, hi)
    u[0] = start
    got = identified(model, u)
    np.testing.assert_allclose(got.predict(u), model.predict(u), atol=1e-9 * w.sum())
    cells = unidentified(model, u)
    assert np.all(got.weights[cells] == 0)
    np.testing.assert_array_equal(got.weights[~cells], w[~cells])
    # Brute force: every cell dropped is one whose relay alone gives a constant output.
    for i, j in zip(*np.nonzero(cells)):
        one = np.zeros_like(w)
        one[i, j] = 1.0
        assert np.ptp(PreisachModel(one, (0.0, 1.0), 0.0, "interpolated").predict(u)) < 1e-12


def test_a_further_record_does_not_see_what_the_training_record_left_unidentified():
    """Two models equal on the training record (the masses it does not identify differ,
    the offset compensates) predict the same on any further record once identified."""
    rng = np.random.default_rng(3)
    n_h = 20
    w = np.triu(rng.uniform(0.0, 1.0, (n_h, n_h)))
    t = np.linspace(0.0, 1.0, 4000)
    u = 0.5 - 0.35 * np.cos(2 * np.pi * 4 * t) * t  # starts mid-range, never below 0.15
    cells = unidentified(PreisachModel(w, (0.0, 1.0)), u)
    assert cells.any()
    w2 = np.where(cells, rng.uniform(0.0, 3.0, w.shape), w)
    a = PreisachModel(w, (0.0, 1.0), 0.0, "interpolated")
    b0 = PreisachModel(w2, (0.0, 1.0), 0.0, "interpolated")
    b = PreisachModel(w2, (0.0, 1.0), float(a.predict(u)[0] - b0.predict(u)[0]), "interpolated")
    np.testing.assert_allclose(a.predict(u), b.predict(u), atol=1e-9)
    further = 0.1 + 0.8 * np.abs(np.sin(2 * np.pi * 2 * t))  # starts low
    assert np.ptp(a.predict(further) - b.predict(further)) > 0.1  # as fitted: they differ
    np.testing.assert_allclose(identified(a, u).predict(further), identified(b, u).predict(further), atol=1e-9)


# -- no false alarm --------------------------------------------------------------------
@pytest.mark.parametrize("name,seed", [("none", 3000), ("history", 2006)])
def test_no_drift_or_rate_false_alarm_on_the_rig(name, seed):
    import rig

    case = rig.make_case(name, seed)
    tr, hos = rig.records(case)
    rep = diagnose(tr, hos, progress=False)
    assert not _found(rep) & FALSE_ALARMS, [(e["name"], e["refused"]) for e in rep.effects]
    if name == "none":
        # Nothing the stage adds to its hysteresis (a finer grid is the model's own matter).
        assert _found(rep) <= {"discretization"}, [(e["name"], e["refused"]) for e in rep.effects]


def test_no_drift_or_rate_false_alarm_on_the_project_stage():
    recs = stage_records(31, [], gap_s=0.5)
    rep = diagnose(recs[0], recs[1:], progress=False)
    assert not _found(rep) & FALSE_ALARMS, [(e["name"], e["refused"]) for e in rep.effects]


# -- real effects are still found ------------------------------------------------------
def test_a_drift_in_absolute_time_is_found_on_the_independent_stage():
    st_ = bv.make_stage(4101, ("drift",), fs=20e3)
    rep = diagnose(st_["train"], [{k: h[k] for k in "tuy"} for h in st_["holdouts"]], progress=False)
    assert rep.dominant_effect == "drift", [(e["name"], e["refused"]) for e in rep.effects]
    d = next(e for e in rep.effects if e["name"] == "drift")
    assert np.sign(d["params"]["gain_per_s"]) == np.sign(st_["params"]["drift"]["gain_per_s"])


def _rate_branch(u, fs, gain_s, tau_s):
    """``gain_s s / (1 + s tau_s)`` of ``u`` (SciPy, bilinear), at rest at ``u[0]``."""
    b, a, _ = signal.cont2discrete(([gain_s, 0.0], [tau_s, 1.0]), 1.0 / fs, method="bilinear")
    b = np.ravel(b)
    return signal.lfilter(b, a, u, zi=signal.lfilter_zi(b, a) * u[0])[0]


def test_a_rate_effect_is_found_on_the_independent_stage():
    fs = 20e3
    rng = np.random.default_rng(4202)
    hm = bv.true_hysteresis(rng)
    gain_s, tau_s = rng.uniform(2e-4, 4e-4), rng.uniform(1e-3, 3e-3)
    recs, t0 = [], 0.0
    for kind in ("train", "triangle", "sine"):
        u = bv.waveform(kind, fs, 1.5, rng)
        t = t0 + np.arange(u.size) / fs
        y = hm.predict(u) + _rate_branch(u, fs, gain_s, tau_s) + 0.003 * rng.standard_normal(u.size)
        recs.append({"t": t, "u": u, "y": y})
        t0 = float(t[-1]) + 0.5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rep = diagnose(recs[0], recs[1:], progress=False)
    assert rep.dominant_effect == "rate", [(e["name"], e["refused"]) for e in rep.effects]
    r = next(e for e in rep.effects if e["name"] == "rate")["params"]
    assert r["tau_s"] == pytest.approx(tau_s, rel=0.5)


def test_a_rate_effect_is_found_on_the_project_stage():
    rng = np.random.default_rng(4303)
    gain_s, tau_s = rng.uniform(2e-4, 4e-4), rng.uniform(1e-3, 3e-3)
    recs = stage_records(4303, [{"type": "rate", "gain_s": gain_s, "tau_s": tau_s}], gap_s=0.5)
    rep = diagnose(recs[0], recs[1:], progress=False)
    assert rep.dominant_effect == "rate", [(e["name"], e["refused"]) for e in rep.effects]
