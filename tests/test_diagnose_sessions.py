"""diagnose: an output offset that differs between records (sessions), under ``drift``
with a value per record, accepted only on evidence that separates it from unrecorded
history, creep and a slow wander. On the project's simulator (``preisach.sim.Stage``,
random parameters) and on the independent rig (``tests/rig.py``)."""
import independent_stage as bv
import numpy as np
import pytest

from preisach.diagnose import diagnose
from preisach.diagnose.sessions import record_offset
from preisach.sim import Stage, hysteresis_block


def test_a_record_offset_needs_a_constant_offset_after_the_sweep():
    rng = np.random.default_rng(1)
    n = 4000
    u = np.r_[np.linspace(0.0, 1.0, 500), np.linspace(1.0, 0.0, 500), np.full(n - 1000, 0.5)]
    noise = 0.01 * rng.standard_normal(n)
    got = record_offset(-0.3 + noise, u, 0.01)  # err = chain - measured: the measured is 0.3 higher
    assert got is not None and got[0] == pytest.approx(0.3, abs=0.003)
    assert np.sqrt(np.mean(got[1] ** 2)) < 0.012
    fading = np.where(np.arange(n) < 1000, -0.3, 0.0) + noise  # history: gone after the sweep
    assert record_offset(fading, u, 0.01) is None
    trend = -0.3 * np.exp(-np.arange(n) / 1500.0) + noise  # creep restarting with the record
    assert record_offset(trend, u, 0.01) is None
    assert record_offset(-0.008 + noise, u, 0.01) is None  # below the floor


def _records(seed, blocks, offsets, fs=20e3):
    """The project's simulator: a random hysteresis then ``blocks``; a training record and
    two holdouts (triangle, steps), each with its session's sensor offset."""
    rng = np.random.default_rng(seed)
    stage = Stage([hysteresis_block(bv.true_hysteresis(rng))] + blocks, sample_rate_hz=fs)
    recs, t0 = [], 0.0
    for kind, off in zip(("train", "triangle", "steps"), offsets):
        u = bv.waveform(kind, fs, 1.5, rng)
        t = t0 + np.arange(u.size) / fs
        recs.append({"t": t, "u": u, "y": stage.simulate(t, u) + off + 0.003 * rng.standard_normal(u.size)})
        t0 = float(t[-1]) + 1.0
    return recs


def test_session_offsets_on_the_project_stage():
    recs = _records(21, [], (0.0, 0.6, -0.4))
    rep = diagnose(recs[0], recs[1:], progress=False)
    d = next(e for e in rep.effects if e["name"] == "drift")
    assert rep.dominant_effect == "drift" and d["detected"], [(e["name"], e["refused"]) for e in rep.effects]
    got = d["params"]["record_offsets"]
    assert set(got) == {"holdout 1", "holdout 2"}
    # What the drift's trend leaves to the record: the two offsets' difference is the
    # sessions' (a trend through absolute time cannot take it).
    assert got["holdout 1"] > got["holdout 2"]


def test_creep_on_the_project_stage_is_not_sessions():
    """Creep restarts with every record: the offset it leaves is no session's."""
    recs = _records(22, [{"type": "creep", "gains": [0.05], "time_constants_s": [0.3]}], (0.0, 0.0, 0.0))
    rep = diagnose(recs[0], recs[1:], progress=False)
    d = next((e for e in rep.effects if e["name"] == "drift"), None)
    assert d is None or "record_offsets" not in d["params"], d


@pytest.mark.parametrize("name,seed", [("sessions", 1007), ("history", 1006), ("repeats", 1001)])
def test_sessions_on_the_rig(name, seed):
    import rig

    case = rig.make_case(name, seed)
    tr, hos = rig.records(case)
    rep = diagnose(tr, hos, progress=False)
    d = next((e for e in rep.effects if e["name"] == "drift"), None)
    if name == "sessions":
        assert rep.dominant_effect == "drift" and set(d["params"]["record_offsets"]) == {"holdout 1", "holdout 2"}
        true = [r["session_offset"] for r in case["truth"]["records"]]
        # The holdouts' offsets against the training record's session, in order.
        off = d["params"]["record_offsets"]
        assert (off["holdout 1"] > off["holdout 2"]) == (true[1] > true[2])
    else:
        assert d is None or "record_offsets" not in d["params"], d
