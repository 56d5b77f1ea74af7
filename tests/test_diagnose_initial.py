"""diagnose: the hysteresis memory at a record's start (``initial_state``): the staircase's
refinement below the grid, found with its extrema near the truth after a history the
record does not show (the project's simulated stage), and how it counts for the
dominant effect. The rig's records that start from rest give none: see
``test_diagnose_steps`` and ``test_diagnose`` (a mode, a delay only the holdouts carry)."""
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from preisach.diagnose.initial import refine
from preisach.diagnose.outcome import dominance


@settings(max_examples=60, deadline=None)
@given(st.floats(1.0, 9.0), st.floats(0.0, 1.0), st.booleans())
def test_refine_moves_the_staircase_to_the_minimum_below_the_grid(top, frac, two):
    """A smooth error with its minimum at a staircase between the grid's points (step
    1.0): the refinement starts at the nearest grid point and ends within a sixteenth of
    the step, the order ``m < M`` kept."""
    target = [top, top * frac * 0.9] if two else [top]
    calls = []

    def err(ex):
        calls.append(list(ex))
        return float(sum((a - b) ** 2 for a, b in zip(ex, target)))

    start = [float(np.round(x)) for x in target]
    if two and start[1] >= start[0]:
        start[1] = start[0] - 1.0
    ex, e = refine(err, start, err(start), 1.0)
    assert len(ex) == len(target)
    assert all(abs(a - b) <= 1 / 16 for a, b in zip(ex, target)), (ex, target)
    assert e == err(ex)
    assert all(len(c) == 1 or c[1] < c[0] for c in calls[1:])


def test_refine_keeps_a_staircase_no_move_improves():
    ex, e = refine(lambda x: float(sum(v * v for v in x)), [0.0], 0.0, 1.0)
    assert ex == [0.0] and e == 0.0


def test_the_starting_staircase_counts_by_its_share_of_the_baseline_for_the_dominant_effect():
    """Judged last against a chain the other effects shrank, a staircase that removes
    most of what is left is not the dominant effect over a mode that removed most of the
    baseline's error."""
    mode = {"score": 0.6, "rmse_current": 0.2, "rmse_after": 0.08}
    start = {"score": 0.9, "rmse_current": 0.08, "rmse_after": 0.008}
    assert dominance(start, "initial_state", 0.2) < dominance(mode, "vibration", 0.2)
    assert dominance(start, "initial_state", 0.2) == (0.08 - 0.008) / 0.2
    assert dominance(mode, "vibration", 0.2) == 0.6
    assert dominance(start, "initial_state", 0.0) == 0.0


def _after_history(stage, fs, u, t0, history):
    """A record of ``u`` on ``stage`` whose start follows ramps through ``history`` (the
    input's levels, from 0) and a rest at ``u[0]`` that the record does not show."""
    pts = [0.0] + list(history) + [float(u[0])]
    pre = np.concatenate([np.linspace(a, b, int(0.01 * fs)) for a, b in zip(pts[:-1], pts[1:])]
                         + [np.full(int(0.05 * fs), float(u[0]))])
    uu = np.concatenate([pre, u])
    t = t0 + np.arange(uu.size) / fs
    y = stage.simulate(t, uu)
    return {"t": t[pre.size:], "u": u, "y": y[pre.size:]}


def test_records_after_unrecorded_history_on_the_simulated_stage_have_their_staircases():
    """The project's simulated stage (``preisach.sim.Stage``), random levels: holdout 1
    rose to ``M1``, fell to ``m1`` and rose to its first sample; holdout 2 rose to ``M2``
    and fell to it; both then sine within part of the range. The staircase is found,
    dominant, with ``M2`` and ``m1`` within two cells of the model's grid of the truth
    (``M1`` only sets a strip of relays at the range's bottom, whose masses are small:
    looser)."""
    from preisach.diagnose import diagnose
    from preisach.sim import Stage

    fs = 50e3
    rng = np.random.default_rng(7)
    stage = Stage.preset("paper", creep=False, seed=7)
    n = int(1.5 * fs)
    tt = np.arange(n) / fs
    ident = 3.75 - 3.6 * np.linspace(0.05, 1, n) * np.cos(2 * np.pi * rng.uniform(3, 6) * tt)
    t1 = np.arange(int(1.0 * fs)) / fs
    a1, a2 = rng.uniform(1.2, 1.8), rng.uniform(2.0, 3.0)
    m1 = rng.uniform(0.6, 3.75 - a1 - 0.5)
    big1, big2 = rng.uniform(3.75, 3.75 + 0.8 * a1), rng.uniform(3.75, 3.75 + 0.8 * a2)
    recs = [_after_history(stage, fs, ident, 0.0, []),
            _after_history(stage, fs, 3.75 - a1 * np.cos(2 * np.pi * rng.uniform(8, 20) * t1), 3.0, [big1, m1]),
            _after_history(stage, fs, 3.75 - a2 * np.cos(2 * np.pi * rng.uniform(8, 20) * t1), 5.0, [big2])]
    rep = diagnose(recs[0], recs[1:], progress=False)
    found = [(e["name"], e["detected"], e["shrink_vs_current"], e["refused"]) for e in rep.effects]
    assert rep.dominant_effect == "initial_state", found
    e = next(e for e in rep.effects if e["name"] == "initial_state")
    ex1, ex2 = e["params"]["record_extrema"]["holdout 1"], e["params"]["record_extrema"]["holdout 2"]
    span = float(np.ptp(rep.baseline_model.u_range))
    cell = span / rep.baseline["n_h"]  # the model's resolution
    assert len(ex2) == 1 and abs(ex2[0] - big2) < 2 * cell, (ex2, big2, cell)
    assert len(ex1) == 2 and abs(ex1[1] - m1) < 2 * cell and abs(ex1[0] - big1) < 0.2 * span, (ex1, big1, m1, cell)
