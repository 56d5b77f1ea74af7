"""The forward operator: staircase against the relay grid, the Preisach properties,
streaming, persistence, bad input."""
from __future__ import annotations

import json

import numpy as np
import pytest
from conftest import random_weights, relay_grid_predict
from hypothesis import given, settings
from hypothesis import strategies as st

from preisach import PreisachModel


def test_staircase_equals_relay_grid_including_inputs_beyond_the_range(rng):
    for n in [1, 4, 13, 30]:
        w = random_weights(rng, n)
        m = PreisachModel(w, (-2.0, 3.0), offset=0.7)
        u = np.cumsum(rng.normal(0, 0.6, 1500))
        u = np.clip(u, -4, 5) + np.where(rng.random(1500) < 0.05, rng.uniform(-4, 5, 1500), 0)
        got = m.predict(u)
        want = relay_grid_predict(w, -2.0, 3.0, 0.7, u)
        assert np.max(np.abs(got - want)) <= 1e-12 * (w.sum() + 0.7)


def test_integer_and_noncontiguous_inputs_are_accepted(rng):
    m = PreisachModel(np.triu(np.ones((5, 5))).astype(int), (0, 5))
    u = np.arange(0, 10)[::2]  # ints, strided
    assert m.predict(u).dtype == np.float64
    np.testing.assert_allclose(m.predict(u), m.predict(u.astype(float).copy()))


# --- hypothesis: the Preisach properties ------------------------------------------
model_strategy = st.integers(min_value=1, max_value=12).flatmap(
    lambda n: st.tuples(st.just(n), st.integers(0, 2**31 - 1)))
signal = st.lists(st.floats(-1.5, 2.5, allow_nan=False), min_size=1, max_size=60)


def _model(n: int, seed: int) -> PreisachModel:
    return PreisachModel(random_weights(np.random.default_rng(seed), n), (-1.0, 2.0), offset=0.3)


@settings(max_examples=60, deadline=None)
@given(model_strategy, signal, st.floats(-1.0, 2.0), st.floats(-1.0, 2.0))
def test_wiping_out_erases_smaller_extrema(ms, history, lo_x, hi_x):
    """After the input reaches a new global max then a new global min, the output no
    longer depends on the extrema in between (wiping-out)."""
    m = _model(*ms)
    top = max(history) + 0.5
    bottom = min(history) - 0.5
    probe = np.array([lo_x, hi_x, lo_x])
    a = m.predict(np.concatenate([history, [top, bottom], probe]))[-3:]
    b = m.predict(np.concatenate([[top, bottom], probe]))[-3:]
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(model_strategy, st.floats(-1.0, 2.0), st.floats(-1.0, 2.0), signal, signal)
def test_minor_loops_between_the_same_extrema_are_congruent(ms, x1, x2, hist1, hist2):
    """Minor loops between the same two input values have the same shape whatever the
    history, shifted by a constant (congruency)."""
    m = _model(*ms)
    a, b = min(x1, x2), max(x1, x2)
    sweep = np.concatenate([np.linspace(a, b, 9), np.linspace(b, a, 9)])
    loops = []
    for hist in (hist1, hist2):
        # Enter the loop from above so the history is not wiped by it.
        pre = np.concatenate([hist, [max(max(hist), b) + 0.1, a]])
        y = m.predict(np.concatenate([pre, sweep, sweep]))[-len(sweep):]
        loops.append(y - y[0])
    np.testing.assert_allclose(loops[0], loops[1], rtol=0, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(model_strategy, signal, st.lists(st.integers(1, 4), min_size=60, max_size=60), st.integers(2, 7))
def test_rate_independence_repeating_or_resampling_changes_nothing(ms, u, reps, k):
    m = _model(*ms)
    u = np.asarray(u)
    y = m.predict(u)
    rep = np.repeat(np.arange(len(u)), reps[: len(u)])
    np.testing.assert_allclose(m.predict(u[rep]), y[rep], atol=1e-12)
    # Resampling monotone segments linearly (k points per step) passes the same extrema.
    fine = np.concatenate([np.linspace(u[i], u[i + 1], k, endpoint=False) for i in range(len(u) - 1)] + [u[-1:]])
    y_fine = m.predict(fine)
    np.testing.assert_allclose(y_fine[::k], y, atol=1e-12)


@settings(max_examples=60, deadline=None)
@given(model_strategy, signal, st.floats(-1.5, 2.5), st.floats(-1.5, 2.5))
def test_output_is_monotone_in_the_input(ms, hist, x1, x2):
    """From any state, moving to a larger input gives a larger (or equal) output."""
    m = _model(*ms)
    _, s = m.predict(np.asarray(hist), return_state=True)
    y1 = m.predict([x1], state=s)[0]
    y2 = m.predict([x2], state=s)[0]
    assert (y1 - y2) * np.sign(x1 - x2) >= -1e-12


# --- streaming and state ------------------------------------------------------------
def test_stream_equals_predict_and_state_resumes_exactly(rng):
    m = PreisachModel(random_weights(rng, 20), (0, 1))
    u = rng.uniform(-0.2, 1.2, 3000)
    want = m.predict(u)
    s = m.stream()
    got = np.concatenate([[s.step(x) for x in u[:100]], s.process(u[100:1700])])
    snap = s.state
    tail = s.process(u[1700:])
    np.testing.assert_array_equal(np.concatenate([got, tail]), want)
    s.state = snap
    np.testing.assert_array_equal(s.process(u[1700:]), want[1700:])
    # predict from a snapshot resumes too
    np.testing.assert_array_equal(m.predict(u[1700:], state=snap), want[1700:])


def test_interpolated_output_equals_stepwise_on_levels_and_is_continuous(rng):
    m = PreisachModel(random_weights(rng, 10), (0, 1))
    lv = m.levels
    u = lv[rng.integers(0, 11, 500)]
    np.testing.assert_allclose(m.predict(u, output="interpolated"), m.predict(u), atol=1e-12)
    ramp = np.linspace(-0.1, 1.1, 20001)
    y = m.predict(ramp, output="interpolated")
    assert np.max(np.abs(np.diff(y))) < 1e-2 * m.weights.sum()


# --- persistence ---------------------------------------------------------------------
def test_save_load_round_trip(tmp_path, rng):
    m = PreisachModel(random_weights(rng, 7), (-1, 4), offset=2.5)
    p = tmp_path / "m.json"
    m.save(p)
    back = PreisachModel.load(p)
    np.testing.assert_array_equal(back.weights, m.weights)
    assert back.u_range == m.u_range and back.offset == m.offset
    assert not list(tmp_path.glob("*.tmp"))


def _v1(m):
    """The version-1 model file of ``m`` (as the build that wrote version 1 did)."""
    w = m.weights
    return {"format": "preisach-model", "version": 1, "n_h": m.n_h, "u_range": list(m.u_range),
            "offset": m.offset, "output": m.output, "weights": [w[i, i:].tolist() for i in range(m.n_h)]}


def test_save_writes_a_version_2_chain_of_one_block_and_version_1_files_still_load(tmp_path, rng):
    m = PreisachModel(random_weights(rng, 5), (-1, 4), offset=0.5, output="interpolated")
    d = m.to_dict()
    assert d["format"] == "preisach-chain" and d["version"] == 2 and len(d["blocks"]) == 1
    b = d["blocks"][0]
    assert (b["type"], b["source"], b["output"], b["n_h"], b["u_range"]) == \
        ("hysteresis", "identified", "interpolated", 5, [-1.0, 4.0])
    # Square, zeros below the diagonal (what MATLAB's jsondecode gives as a matrix).
    np.testing.assert_array_equal(np.array(b["weights"]), m.weights)
    p = tmp_path / "v1.json"
    p.write_text(json.dumps(_v1(m)))
    back = PreisachModel.load(p)
    np.testing.assert_array_equal(back.weights, m.weights)
    assert back.output == "interpolated" and back.offset == 0.5
    assert back.to_dict() == d


@pytest.mark.parametrize("mutate, msg", [
    (lambda d: d.update(format="other"), "format"),
    (lambda d: d.update(version=99), "version"),
    (lambda d: d.update(n_h=0), "n_h"),
    (lambda d: d["weights"].pop(), "weights"),
    (lambda d: d["weights"][0].__setitem__(0, -1.0), "must be >= 0"),
    (lambda d: d.update(u_range=[3, 1]), "u_range"),
    (lambda d: d["weights"][1].__setitem__(0, "x"), "non-numbers"),
    (lambda d: d.update(output="smooth"), "output"),
])
def test_corrupt_version_1_model_files_are_rejected(tmp_path, rng, mutate, msg):
    d = _v1(PreisachModel(random_weights(rng, 4), (0, 1)))
    mutate(d)
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=msg):
        PreisachModel.load(p)


@pytest.mark.parametrize("mutate, msg", [
    (lambda b: b["weights"].pop(), "blocks\\[0\\] \\(hysteresis\\): weights: expected a square matrix"),
    (lambda b: b["weights"][2].__setitem__(1, 0.5), r"weights\[2\]\[1\]: must be 0 below the diagonal"),
    (lambda b: b["weights"][0].__setitem__(3, -1.0), r"weights\[0\]\[3\]: must be >= 0"),
    (lambda b: b["weights"][1].__setitem__(2, float("nan")), r"weights\[1\]\[2\]: must be finite, got nan"),
    (lambda b: b.update(output="smooth"), "unknown variant `smooth`"),
    (lambda b: b.update(colour="red"), "unknown field `colour`"),
    (lambda b: b.pop("n_h"), "missing field `n_h`"),
])
def test_corrupt_version_2_model_files_are_rejected_naming_the_field(tmp_path, rng, mutate, msg):
    d = PreisachModel(random_weights(rng, 4), (0, 1)).to_dict()
    mutate(d["blocks"][0])
    p = tmp_path / "bad.json"
    p.write_text(json.dumps(d))
    with pytest.raises(ValueError, match=msg):
        PreisachModel.load(p)


def test_a_chain_is_not_a_model(tmp_path, rng):
    from preisach import Chain, load

    m = PreisachModel(random_weights(rng, 4), (0, 1))
    p = tmp_path / "c.json"
    Chain(m, {"delay": {"delay_s": 1e-3}}).save(p)
    with pytest.raises(ValueError, match="not a single identified model: use preisach.load"):
        PreisachModel.load(p)
    assert isinstance(load(p), Chain)
    m.save(p)
    assert isinstance(load(p), PreisachModel)


def test_truncated_json_is_rejected(tmp_path):
    p = tmp_path / "bad.json"
    p.write_text('{"format": "preisach-model", "vers')
    with pytest.raises(ValueError, match="bad.json: corrupt chain: not JSON"):
        PreisachModel.load(p)


# --- bad input -----------------------------------------------------------------------
@pytest.mark.parametrize("args, match", [
    ((np.full((3, 3), np.nan), (0, 1)), "weights"),
    ((np.triu(-np.ones((3, 3))), (0, 1)), "weights: negative"),
    ((np.ones((3, 2)), (0, 1)), "weights: expected a square"),
    ((np.triu(np.ones((3, 3))), (1, 1)), "u_range: lo must be below hi"),
    ((np.triu(np.ones((3, 3))), (0, np.inf)), "u_range: must be finite"),
    ((np.ones((0, 0)), (0, 1)), "n_h"),
])
def test_bad_model_arguments_raise_valueerror_naming_them(args, match):
    with pytest.raises(ValueError, match=match):
        PreisachModel(*args)


def test_bad_predict_input_names_the_first_bad_index():
    m = PreisachModel(np.triu(np.ones((3, 3))), (0, 1))
    with pytest.raises(ValueError, match="u: NaN at index 2"):
        m.predict([0.1, 0.2, np.nan, np.inf])
    with pytest.raises(ValueError, match="u: inf at index 0"):
        m.predict([np.inf])
    with pytest.raises(ValueError, match="u: expected a 1-D"):
        m.predict(np.zeros((2, 2)))
    assert m.predict([]).shape == (0,)


def test_a_mass_below_the_diagonal_is_an_error_naming_the_first():
    with pytest.raises(ValueError, match=r"weights: entry \[1, 0\] = 1 lies below the diagonal"):
        PreisachModel(np.ones((5, 5)), (0, 1))
    w = np.triu(np.ones((4, 4)))
    w[3, 1] = 0.5
    w[2, 0] = -1e-300  # any non-zero value, however small
    with pytest.raises(ValueError, match=r"entry \[2, 0\] = -1e-300"):
        PreisachModel(w, (0, 1))


def test_fit_returns_a_model_with_its_report():
    from preisach import FitReport, FittedModel

    u = np.linspace(0, 1, 200) * np.sin(np.linspace(0, 60, 200)) + 0.5
    m = PreisachModel.fit(u, u**2, 4)
    assert isinstance(m, FittedModel) and isinstance(m, PreisachModel)
    assert isinstance(m.report, FitReport)
    assert PreisachModel(m.weights, m.u_range).report is None


def test_read_record_is_public():
    import preisach
    import preisach.io

    assert preisach.read_record is preisach.io.read_record
    assert "read_record" in preisach.__all__ and "compare" in preisach.__all__ and "plots" in preisach.__all__


TYPED = '''
import numpy as np
from numpy.typing import NDArray
from typing_extensions import assert_type

from preisach import FitReport, PreisachModel
from preisach._inverse import InversionInfo, Inverter, invert

u = np.linspace(0.0, 1.0, 10)
m = PreisachModel.fit(u, u, 3)
assert_type(m.report, FitReport)
assert_type(m.predict(u), NDArray[np.float64])
y, state = m.predict(u, return_state=True)
assert_type(y, NDArray[np.float64])
assert_type(state, NDArray[np.float64])
assert_type(m.invert(u), NDArray[np.float64])
assert_type(m.inverter("continuous"), Inverter)
assert_type(m.inverter("continuous").step(0.5), float)
assert_type(invert(m, u, return_info=True)[1], InversionInfo)
print(m.report.rmse + 1.0)
'''


def test_mypy_sees_real_return_types(tmp_path):
    api = pytest.importorskip("mypy.api")
    (tmp_path / "typed.py").write_text(TYPED)
    out, err, code = api.run([str(tmp_path / "typed.py"), "--strict", "--no-incremental",
                              "--cache-dir", str(tmp_path / "cache")])
    assert code == 0, out + err
