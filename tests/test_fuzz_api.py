"""Fuzz every public Python function with hostile values, shapes, sizes, rates and time
(hypothesis, the ``ci`` profile's budget). Each call returns or raises a ValueError
naming an argument (tests/fuzzing.py: the contract); inputs are never modified."""
from __future__ import annotations

import numpy as np
import pytest
from fuzzing import NOT_NUMBERS, finite_float, hostile_array, hostile_float, outcome, sweep
from hypothesis import assume, given
from hypothesis import strategies as st

import preisach
from preisach.sim import Stage, run_loop

pytestmark = pytest.mark.filterwarnings("ignore::preisach.PreisachWarning")

any_value = st.one_of(hostile_float, st.sampled_from(NOT_NUMBERS), st.integers(-(2**70), 2**70))
sizes = st.one_of(st.integers(-3, 50), st.sampled_from([0, 10**5, 10**6, 2**31, 2**40, 2**63, 2**64 + 1, -(2**63)]))
ranges = st.one_of(
    st.tuples(finite_float, finite_float),
    st.sampled_from([(0.0, 0.0), (1.0, 1.0 + 1e-15), (-1e300, 1e300), (0.0, 1e300), (1e-310, 2e-310),
                     (5.0, 1.0), (float("nan"), 1.0), (0.0, float("inf")), (-1e308, 1e308)]),
    st.sampled_from([None, (1.0,), (1.0, 2.0, 3.0), "ab", 5.0, [None, 1]]))
methods = st.sampled_from(["closest", "interpolated", "continuous", "CLOSEST", "", "identity", None, 3])
lookaheads = st.one_of(st.none(), st.integers(-5, 50), st.sampled_from([2**24, 2**24 + 1, 2**62, 2**64, 1.5, "3"]))


@pytest.fixture(scope="module")
def model() -> preisach.PreisachModel:
    u = sweep(3000)
    y = 0.3 * u + np.tanh(u - 5.0)
    return preisach.PreisachModel.fit(u, y, n_h=12, u_range=(0.0, 10.0))


@pytest.fixture(scope="module")
def stage() -> Stage:
    return Stage.preset("paper", noise_std=0.0)


def unchanged(before: object, after: object) -> bool:
    if isinstance(before, np.ndarray):
        return isinstance(after, np.ndarray) and np.array_equal(before, after, equal_nan=True) and \
            before.dtype == after.dtype
    return True


def frozen(*arrays: object) -> list[object]:
    return [a.copy() if isinstance(a, np.ndarray) else a for a in arrays]


# --- the model -----------------------------------------------------------------------
@given(w=hostile_array(), n=st.integers(0, 5), rng=ranges, offset=any_value,
       output=st.sampled_from(["stepwise", "interpolated", "x", None]))
def test_model_constructor(w, n, rng, offset, output):
    weights = np.resize(np.asarray(w, dtype=object) if not isinstance(w, np.ndarray) else w, (n, n)) \
        if isinstance(w, np.ndarray) and w.size else w
    outcome(lambda: preisach.PreisachModel(weights, rng, offset, output), ["weights", "n_h", "u_range", "offset",
                                                                           "output"])


@given(u=hostile_array(), y=hostile_array(), n_h=sizes, rng=ranges, reg=any_value,
       solver=st.sampled_from(["auto", "active", "clarabel", "structured", "gradient", "x", ""]),
       output=st.sampled_from(["stepwise", "interpolated", "?"]))
def test_fit(u, y, n_h, rng, reg, solver, output):
    keep = frozen(u, y)
    got = outcome(lambda: preisach.PreisachModel.fit(u, y, n_h, rng, reg, solver, output),
                  ["u", "y", "n_h", "u_range", "reg", "solver", "output", "weights"])
    if isinstance(got, preisach.PreisachModel):
        assert np.all(np.isfinite(got.weights)) and got.report is not None
    assert all(unchanged(a, b) for a, b in zip(keep, (u, y)))


@given(n=st.integers(1, 200), n_h=st.integers(1, 30), lo=finite_float, span=st.sampled_from([1e-300, 1e-12, 1.0,
                                                                                          1e6, 1e300]),
       scale=st.sampled_from([1e-300, 1e-320, 1.0, 1e150, 1e300]))
def test_fit_on_extreme_scales(n, n_h, lo, span, scale):
    """Valid but extreme records: tiny or huge ranges and outputs, denormal values."""
    u = lo + span * sweep(n, 0.0, 1.0)
    y = scale * np.sin(np.arange(n))
    assume(np.all(np.isfinite(u)))
    got = outcome(lambda: preisach.PreisachModel.fit(u, y, n_h), ["u", "y", "n_h", "u_range", "weights"])
    if isinstance(got, preisach.PreisachModel):
        assert np.all(np.isfinite(got.weights)) and np.isfinite(got.offset)


@given(u=hostile_array(), state=st.one_of(st.none(), hostile_array()),
       output=st.sampled_from([None, "stepwise", "interpolated", "nope"]))
def test_predict(model, u, state, output):
    keep = frozen(u, state)
    got = outcome(lambda: model.predict(u, state, output=output), ["u", "state", "output"])
    if isinstance(got, np.ndarray):
        assert got.dtype == np.float64 and got.shape == np.atleast_1d(u).shape
    assert all(unchanged(a, b) for a, b in zip(keep, (u, state)))


@given(state=st.one_of(st.none(), hostile_array()), xs=st.lists(st.one_of(hostile_float, finite_float), max_size=8),
       block=hostile_array(), new_state=hostile_array())
def test_stream(model, state, xs, block, new_state):
    s = outcome(lambda: model.stream(state), ["state"])
    if isinstance(s, Exception):
        return
    for x in xs:
        outcome(lambda: s.step(x), ["u"])
    outcome(lambda: s.process(block), ["block"])
    outcome(lambda: setattr(s, "state", new_state), ["state"])
    assert np.all(np.isfinite(s.state))


@given(r=hostile_array(), method=methods, lookahead=lookaheads)
def test_invert(model, r, method, lookahead):
    keep = frozen(r)
    got = outcome(lambda: model.invert(r, method=method, lookahead=lookahead), ["r", "method", "lookahead"])
    if isinstance(got, np.ndarray):
        assert got.dtype == np.float64 and np.all(np.isfinite(got))
    assert unchanged(keep[0], r)


@given(method=methods, lookahead=lookaheads, xs=st.lists(st.one_of(hostile_float, finite_float), max_size=8),
       block=hostile_array(), state=st.one_of(st.none(), st.dictionaries(st.sampled_from(
           ["memory", "saturated", "t", "u_prev", "last_cm", "knots", "r_prev", "x"]), any_value, max_size=8)))
def test_inverter(model, method, lookahead, xs, block, state):
    inv = outcome(lambda: model.inverter(method=method, lookahead=lookahead), ["method", "lookahead"])
    if isinstance(inv, Exception):
        return
    for x in xs:
        outcome(lambda: inv.step(x), ["r"])
    outcome(lambda: inv.process(block), ["block", "r"])
    good = inv.state
    outcome(lambda: setattr(inv, "state", state), ["state"])
    inv.state = good
    assert np.isfinite(inv.step(1.0))


# --- chains, stages and the loop ------------------------------------------------------
@given(t=hostile_array(), u=hostile_array(), x0=st.one_of(st.none(), any_value),
       how=st.sampled_from(["as is", "irregular", "reversed", "repeated", "rate"]),
       fs=st.sampled_from([1e-300, 1e-3, 1.0, 1e4, 1e6, 1e12, 1e300]))
def test_chain_records(stage, t, u, x0, how, fs):
    """predict/simulate on hostile, irregular and non-monotone time and hostile rates."""
    if how != "as is" and isinstance(u, np.ndarray) and u.ndim == 1 and u.size > 1:
        t = np.arange(u.size) / fs
        if how == "irregular":
            t = t + 0.4 / fs * np.sin(np.arange(u.size)) ** 2 * (np.arange(u.size) % 3 == 1)
        elif how == "reversed":
            t = t[::-1].copy()
        elif how == "repeated":
            t[1] = t[0]
    keep = frozen(t, u)
    for run in (stage.predict, stage.simulate):
        got = outcome(lambda: run(t, u, x0), ["t", "u", "initial_input", "sample_rate_hz", "delay_s", "cutoff_hz",
                                             "frequency_hz"])
        if isinstance(got, np.ndarray):
            assert got.dtype == np.float64 and got.shape == np.atleast_1d(u).shape
    assert all(unchanged(a, b) for a, b in zip(keep, (t, u)))


@given(u=hostile_array(), x=any_value, f=hostile_array(), t=any_value)
def test_stage_per_sample(stage, u, x, f, t):
    s = stage.copy()
    outcome(lambda: s.run(u), ["u"])
    outcome(lambda: s.step(x), ["u"])
    outcome(lambda: s.response(f), ["f_hz", "blocks"])
    outcome(lambda: setattr(s, "time_s", t), ["time_s", "t"])
    outcome(lambda: setattr(s, "initial_input", x), ["initial_input"])
    outcome(lambda: setattr(s, "sample_rate_hz", x), ["sample_rate_hz"])


OVERRIDES = ("delay", "seed", "noise_std", "n_h", "resonance_hz", "damping", "creep", "creep_per_decade",
             "lowpass_hz", "lowpass_order", "dac_bits", "adc_bits", "drift_gain_per_s", "drift_offset_per_s",
             "sample_rate_hz", "bogus")


@given(name=st.sampled_from(["paper", "PAPER", "", "none", 3]),
       over=st.dictionaries(st.sampled_from(OVERRIDES), st.one_of(any_value, sizes), max_size=3))
def test_stage_preset(name, over):
    got = outcome(lambda: Stage.preset(name, **over), ["name", "preset", "blocks", *OVERRIDES])
    if isinstance(got, Stage):
        outcome(lambda: got.run(np.linspace(0.0, 5.0, 50)), ["u"])


@given(reference=hostile_array(), method=st.sampled_from(["continuous", "interpolated", "closest", "identity", "x"]),
       lookahead=st.one_of(st.none(), st.integers(-2, 300), st.sampled_from([2**24 + 1, 2**62])),
       with_model=st.booleans())
def test_run_loop(model, stage, reference, method, lookahead, with_model):
    keep = frozen(reference)
    outcome(lambda: run_loop(model if with_model else None, stage, reference, method, lookahead),
            ["model", "stage", "reference", "method", "lookahead"])
    assert unchanged(keep[0], reference)


@given(t=hostile_array())
def test_sample_period(t):
    got = outcome(lambda: preisach.chain.sample_period(t), ["t"])
    if isinstance(got, float):
        assert got > 0 and np.isfinite(got)


@given(y=hostile_array(), y_hat=hostile_array())
def test_fit_percent(y, y_hat):
    got = outcome(lambda: preisach.fit_percent(y, y_hat), ["y", "y_hat"])
    if isinstance(got, float) and np.isnan(got):  # documented: a constant record matched exactly
        yy, yh = (np.atleast_1d(np.asarray(a, dtype=np.float64)) for a in (y, y_hat))
        assert np.ptp(yy) == 0 and np.array_equal(yy, yh)
    elif isinstance(got, float):
        assert got <= 100.0


@given(t=hostile_array(), u=hostile_array(), y=hostile_array(), drop=st.sampled_from([None, "t", "u", "y"]))
def test_compare(model, t, u, y, drop):
    rec = {"t": t, "u": u, "y": y}
    if drop:
        del rec[drop]
    outcome(lambda: preisach.compare(model, rec), ["t", "u", "y", "record"])


@given(u=hostile_array(max_len=12), n_h=st.one_of(st.integers(-1, 4), st.sampled_from([10**6, 2**63, "4", 2.5])),
       drop=st.sampled_from([None, "t", "u", "y"]), n_hold=st.integers(0, 2))
def test_diagnose_refuses_bad_records(u, n_h, drop, n_hold):
    """Bad records and arguments are refused up front (a valid diagnosis is slow and is
    tested in test_diagnose.py)."""
    n = np.size(u) if isinstance(u, np.ndarray) and u.ndim == 1 else 5
    rec = {"t": np.arange(n) / 1e3, "u": u, "y": np.zeros(n)}
    if drop:
        del rec[drop]
    assume(not (isinstance(u, np.ndarray) and u.ndim == 1 and u.size > 3 and np.all(np.isfinite(u)) and drop is None
                and n_hold and isinstance(n_h, int) and 1 <= n_h <= 4))
    outcome(lambda: preisach.diagnose(rec, [rec] * n_hold, n_h=n_h, progress=False),
            ["train", "holdouts", "holdout", "n_h", "t", "u", "y"])


@pytest.mark.parametrize("method", ["closest", "interpolated", "continuous"])
def test_invert_far_outside_the_reachable_range(model, method):
    """Regression: ``r = [131076, 0]`` made the closest match index past the Everett
    table (a panic surfacing as RuntimeError)."""
    for e in range(18):
        for sign in (1.0, -1.0):
            r = np.array([sign * 1.31076 * 10.0**e, 0.0, -sign * 10.0**e, 0.3])
            u = model.invert(r, method=method)
            assert np.all((u >= 0.0) & (u <= 10.0))
            inv = model.inverter(method=method, lookahead=3 if method == "interpolated" else None)
            assert np.all(np.isfinite(inv.process(r)))


@given(t=hostile_array(max_len=8), u=hostile_array(max_len=8), y=hostile_array(max_len=8),
       fs=st.one_of(hostile_float, st.sampled_from(NOT_NUMBERS)), what=st.sampled_from(["loop", "tracking", "spectra",
                                                                                        "weights"]))
def test_plots(tmp_path, monkeypatch, model, t, u, y, fs, what):
    """Bad arrays are refused naming the argument before matplotlib is imported (valid
    ones are drawn but not rendered to PNG here, for time)."""
    plt = pytest.importorskip("matplotlib.pyplot")
    monkeypatch.setattr(preisach.plots, "_save", lambda fig, p: plt.close(fig) or str(p))
    path = tmp_path / "p.png"
    calls = {"loop": (lambda: preisach.plots.plot_loop(t, u, y, y, path), ["t", "u", "measured", "model"]),
             "tracking": (lambda: preisach.plots.plot_tracking(t, u, y, path), ["t", "reference", "measured"]),
             "spectra": (lambda: preisach.plots.plot_spectra({"u": u}, fs, path), ["signals", "sample_rate_hz"]),
             "weights": (lambda: preisach.plots.plot_weights(u, path), ["model"])}
    call, names = calls[what]
    outcome(call, names)


# --- regressions found by fuzzing ------------------------------------------------------
def test_regressions_found_by_fuzzing(tmp_path, model):
    def refused(call, starts):
        with pytest.raises(ValueError) as e:
            call()
        assert str(e.value).startswith(starts), str(e.value)

    # A chain without a version: was a panic (an internal RuntimeError).
    refused(lambda: preisach.Chain.from_json('{"format": "preisach-chain", "blocks": []}'),
            "corrupt chain: unsupported version null")
    # Nesting deeper than Python's recursion limit: was a RecursionError.
    refused(lambda: preisach.Chain.from_json("[" * 100_000 + "]" * 100_000), "corrupt chain: not JSON")
    deep: dict = {}
    for _ in range(5000):
        deep = {"x": deep}
    refused(lambda: preisach.Chain.from_dict({"format": "preisach-chain", "version": 2, "blocks": [], "report": deep}),
            "chain: nested too deeply")
    # Non-numeric arrays: were NumPy's message without the argument.
    refused(lambda: model.invert(["a", "b"]), "r: cannot be converted")
    refused(lambda: model.inverter().process(["a"]), "block: cannot be converted")
    refused(lambda: preisach.chain.sample_period(["a", "b"]), "t: cannot be converted")
    refused(lambda: model.stream().step(None), "u: expected a number")
    refused(lambda: model.inverter().step("1"), "r: expected a number")
    # A look-ahead past usize: was an OverflowError.
    refused(lambda: model.invert([1.0], "interpolated", lookahead=2**64), "lookahead: ")
    refused(lambda: model.inverter("interpolated", lookahead=2**64), "lookahead: ")
    # n_h far past the cap with a range: allocated n_h centres first (MemoryError).
    refused(lambda: preisach.PreisachModel.fit(np.linspace(0, 1, 9), np.zeros(9), 2**40, (0.0, 1.0)), "n_h: ")
    # Masses whose sum overflows: NaN outputs.
    refused(lambda: preisach.PreisachModel(np.triu(np.full((3, 3), 1e308)), (0.0, 1.0)), "weights: the masses sum")
    # Values near the float64 limits: overflowed to NaN.
    assert preisach.fit_percent([1e308, -1e308], [-1e308, 1e308]) == pytest.approx(-100.0)
    # A truncated .npz: was an EOFError (and left the file open).
    npz = tmp_path / "r.npz"
    np.savez(npz, t=np.arange(3.0), u=np.zeros(3), y=np.zeros(3))
    npz.write_bytes(npz.read_bytes()[:40])
    refused(lambda: preisach.read_record(npz), f"{npz}: not a readable .npz file")
    # Plots: mismatched lengths were matplotlib's message.
    refused(lambda: preisach.plots.plot_loop([0.0, 1.0], [0.0], [0.0, 1.0], [0.0, 1.0], tmp_path / "p.png"),
            "u: length 1 does not match t")
