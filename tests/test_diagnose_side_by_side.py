"""diagnose: the serial steps' work side by side and without repeats changes no number.

The starting staircases' runs on a thread pool (``initial.estimate``, ``own_start``,
``crossfit.profiles`` with a pool's ``map``) against the same functions run one after
the other; the chain's run from a staircase (``initial.predictor``) against the same
chain run from rest through the staircase's path (hysteresis is rate independent); the
estimates kept per chain and record (``initial.Starts``) and the holdout errors kept per
chain (``steps.Run.holdout_errors``) against fresh ones. On both simulators: the
project's stage (``preisach.sim.Stage``) and the independent rig (``tests/rig.py``),
random stages and chains."""
from __future__ import annotations

import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
import rig
from hypothesis import given, settings
from hypothesis import strategies as st
from preisach import PreisachModel, PreisachWarning
from preisach.chain import Chain
from preisach.diagnose import crossfit, initial, steps
from preisach.diagnose.effects import FitState, Record
from preisach.diagnose.records import load_record
from preisach.diagnose.search import Trials
from preisach.sim import Stage

def _pool_map(fn: Any, items: Any) -> list[Any]:
    """``map`` on a pool of two threads (shut down on return: no thread outlives a test)."""
    with ThreadPoolExecutor(2) as pool:
        return list(pool.map(fn, list(items)))


def _project_records(seed: int) -> list[Record]:
    """The project's stage: an identification record and two records after a history
    they do not show (rose to a random level, fell to another, then to the first sample)."""
    rng = np.random.default_rng(seed)
    fs = 50e3
    stage = Stage.preset("paper", creep=False, seed=seed)
    n = int(0.4 * fs)
    tt = np.arange(n) / fs
    ident = 3.75 - 3.6 * np.linspace(0.05, 1, n) * np.cos(2 * np.pi * rng.uniform(3, 6) * tt)
    out = []
    for i, (hist, a) in enumerate([([], 0.0), ([rng.uniform(5.5, 7.0), rng.uniform(0.5, 2.0)], 1.5),
                                   ([rng.uniform(5.5, 7.0)], 2.5)]):
        u = ident if i == 0 else 3.75 - a * np.cos(2 * np.pi * rng.uniform(8, 20) * tt[: n // 2])
        pts = [0.0] + list(hist) + [float(u[0])]
        pre = np.concatenate([np.linspace(p, q, 50) for p, q in zip(pts[:-1], pts[1:])] + [np.full(200, u[0])])
        uu = np.concatenate([pre, u])
        t = 2.0 * i + np.arange(uu.size) / fs
        y = stage.simulate(t, uu)
        out.append(load_record({"t": t[pre.size:], "u": u, "y": y[pre.size:]}, f"record {i}"))
    return out


def _rig_records(seed: int) -> list[Record]:
    """The independent rig: a stage of the class whose records follow unrecorded history."""
    tr, hos = rig.records(rig.make_case("history", seed))
    return [load_record(r, f"record {i}") for i, r in enumerate([tr] + hos)]


def _records(source: str, seed: int) -> list[Record]:
    return _project_records(seed) if source == "project" else _rig_records(seed)


def _chain(recs: list[Record], rng: np.random.Generator, dynamic: bool) -> FitState:
    """A model fitted on the first record, with random effects behind it (``dynamic``) or none."""
    tr = recs[0]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PreisachWarning)
        model = PreisachModel.fit(tr.u, tr.y, 20)
    eff: dict[str, dict[str, Any]] = {}
    if dynamic:
        eff["lowpass"] = {"cutoff_hz": float(rng.uniform(200.0, 2000.0)), "order": int(rng.integers(1, 3))}
        eff["delay"] = {"delay_s": float(rng.uniform(0.0, 3e-4))}
    return FitState(model, eff)


SOURCES = st.sampled_from(["project", "rig"])


@settings(max_examples=6, deadline=None)
@given(SOURCES, st.integers(0, 10_000), st.floats(0.2, 0.9), st.floats(0.0, 1.0))
def test_a_staircase_start_is_the_run_from_rest_through_its_path(source, seed, top, frac):
    """Hysteresis alone: the run from a staircase ``[M, m]`` equals the run from rest at
    the range's bottom through ``M`` and ``m`` to the record's first input (the oracle:
    the chain's plain run, the path's samples dropped)."""
    recs = _records(source, seed)
    sta = _chain(recs, np.random.default_rng(seed), dynamic=False)
    rec = recs[1]
    lo, hi = sta.model.u_range
    M = lo + top * (hi - lo)
    m = lo + frac * (M - lo) * 0.95
    got = initial.predictor(sta, rec)([M, m])
    path = np.array([lo, M, m])
    u = np.concatenate([path, rec.u])
    t = rec.t[0] + (np.arange(u.size) - path.size) * rec.dt
    want = Chain(sta.model, {}).predict(t, u)[path.size:]
    assert np.allclose(got, want, rtol=0, atol=1e-12 * max(1.0, float(np.max(np.abs(want)))))
    assert np.array_equal(initial.predictor(sta, rec)([]), sta.predict(rec))
    assert np.array_equal(initial.predict_from(sta, rec, [M, m]), got)


@settings(max_examples=6, deadline=None)
@given(SOURCES, st.integers(0, 10_000), st.booleans())
def test_starts_on_a_thread_pool_are_those_run_one_after_the_other(source, seed, dynamic):
    """``estimate``, ``own_start`` and ``profiles`` with a pool's ``map`` return exactly
    what they return run one after the other (the same numbers, bit for bit)."""
    recs = _records(source, seed)
    sta = _chain(recs, np.random.default_rng(seed), dynamic)
    for rec in recs[1:]:
        serial = initial.estimate(sta, rec)
        assert initial.estimate(sta, rec, run=_pool_map) == serial
        err = sta.predict(rec) - rec.y
        a, exa = initial.own_start(sta, rec, err, serial)
        b, exb = initial.own_start(sta, rec, err, serial, run=_pool_map)
        assert exa == exb and np.array_equal(a, b)
        assert np.array_equal(crossfit.profiles(sta, rec), crossfit.profiles(sta, rec, _pool_map))


@settings(max_examples=4, deadline=None)
@given(SOURCES, st.integers(0, 10_000))
def test_starts_are_estimated_once_per_chain_and_record(source, seed):
    """``Starts`` returns ``estimate``'s result, estimating each chain's start on each
    record once (an equal chain built anew counts as the same), another chain's anew."""
    recs = _records(source, seed)
    rng = np.random.default_rng(seed)
    a = _chain(recs, rng, True)
    a2 = FitState(a.model, {k: dict(v) for k, v in a.effects.items()})
    b = FitState(a.model, dict(a.effects, delay={"delay_s": a.effects["delay"]["delay_s"] + 1e-4}))
    calls: list[tuple[str, str]] = []
    real = initial.estimate

    def counted(s: FitState, r: Record, levels: int = 9, run: Any = map) -> initial.Estimate:
        calls.append((Chain(s.model, s.effects).to_json(), r.name))
        return real(s, r, levels, run)

    initial.estimate = counted
    try:
        starts = initial.Starts(_pool_map)
        for s in (a, a2, b, a):
            for r in recs[1:]:
                assert starts(s, r) == real(s, r)
    finally:
        initial.estimate = real
    assert len(calls) == len(set(calls)) == 2 * (len(recs) - 1)


@settings(max_examples=4, deadline=None)
@given(SOURCES, st.integers(0, 10_000), st.sampled_from([None, "creep", "drift"]))
def test_holdout_errors_kept_are_the_fresh_ones(source, seed, slow):
    """The holdout errors a run keeps per chain equal a fresh computation, for more
    chains than it keeps and with slow effects (calibrated across the records); a
    caller that changes the arrays returned changes nothing kept."""
    recs = _records(source, seed)
    rng = np.random.default_rng(seed)
    trials = Trials(2)
    run = steps.Run(recs[0], recs[1:], 20, (), 0.1, trials, print, None, None, None, 1, 1)  # type: ignore[arg-type]
    chains = []
    for _ in range(steps.ERRORS_KEPT + 2):
        s = _chain(recs, rng, True)
        if slow == "creep":
            s.effects["creep"] = {"taus_s": [float(rng.uniform(0.05, 0.5))], "amplitudes": [float(rng.uniform(0, 0.1))]}
        elif slow == "drift":
            s.effects["drift"] = {"gain_per_s": float(rng.uniform(-1e-3, 1e-3)), "offset": 0.0,
                                  "offset_per_s": float(rng.uniform(-1e-3, 1e-3))}
        chains.append(s)
    try:
        for s in chains + chains[::-1]:
            got = run.holdout_errors(s)
            fresh = run._holdout_errors(s)
            assert all(np.array_equal(g, f) for g, f in zip(got, fresh))
            for g in got:
                g[:] = np.nan
            assert all(np.array_equal(g, f) for g, f in zip(run.holdout_errors(s), fresh))
    finally:
        trials.close()
