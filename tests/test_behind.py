"""Masses fitted behind linear dynamics (``_preisach.Behind``, ``_preisach.fit_behind``):
against dense least squares on relay columns filtered by SciPy (the oracle), the masses'
projection against SciPy's NNLS (plain, and with the smoothness term the diagnosis
adds), nested chains never fitting worse, the averaged-window fit, and the diagnoser's
drift calibration."""
import numpy as np
import pytest
from lti_reference import apply_effects

from preisach import Chain, PreisachModel, _preisach
from preisach.diagnose.effects import FitState, Record
from preisach.diagnose.search import PART_FLOOR, Fitter, calibrate_slow

N_H = 5
RANGE = (0.0, 1.0)
DT = 1e-4


def _blocks(effects, delay_samples=0.0):
    """The linear effects as the core chain the fit takes."""
    eff = dict(effects)
    if delay_samples:
        eff["delay"] = {"delay_s": delay_samples * DT}
    return Chain(None, eff)._core


def _input(n=6000, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) * DT
    u = 0.5 + 0.45 * np.sin(2 * np.pi * 9 * t) * np.cos(2 * np.pi * 1.3 * t) + 0.03 * rng.standard_normal(n)
    u[n // 3:] += 0.1 * (np.arange(n - n // 3) // 700 % 2)  # a few steps
    return t, np.clip(u, -0.05, 1.05)


def _dense(u, effects, delay_samples=0.0):
    """Regression matrix through the chain: one column per cell (the unit-mass model's
    relay output), the offset column, each run through the blocks (and the delay)."""
    iu = np.triu_indices(N_H)
    t = np.arange(u.size) * DT
    cols = []
    for k in range(iu[0].size + 1):
        if k < iu[0].size:
            w = np.zeros((N_H, N_H))
            w[iu[0][k], iu[1][k]] = 1.0
            h = PreisachModel(w, RANGE, 0.0, "interpolated").predict(u)
        else:
            h = np.ones(u.size)
        eff = dict(effects)
        if delay_samples:
            eff["delay"] = {"delay_s": delay_samples * DT}
        cols.append(apply_effects(eff, t, h))
    return np.column_stack(cols)


@pytest.mark.parametrize("effects,delay", [
    ({"vibration": {"frequency_hz": 300.0, "damping": 0.02}}, 0.0),
    ({"vibration": {"frequency_hz": 300.0, "damping": 0.02}, "lowpass": {"cutoff_hz": 800.0, "order": 2}}, 0.0),
    ({"creep": {"taus_s": [0.05], "amplitudes": [0.05], "normalized": True}, "lowpass": {"cutoff_hz": 500.0, "order": 1}}, 3.4),
])
def test_unconstrained_fit_equals_dense_least_squares_through_the_blocks(effects, delay):
    t, u = _input()
    rng = np.random.default_rng(1)
    y = np.sin(7 * u) + 0.3 * u + 0.01 * rng.standard_normal(u.size)
    A = _dense(u, effects, delay)
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    want = np.sqrt(np.mean((A @ coef - y) ** 2))
    b = _preisach.Behind(u, N_H, RANGE)
    res = b.solve(y, DT, _blocks(effects, delay), tol=1e-12, max_iter=2000)
    assert res["rmse"] == pytest.approx(want, rel=1e-6)
    # A plain fit that ignores the dynamics is measurably worse: the test can fail.
    plain = _preisach.Behind(u, N_H, RANGE).solve(y, DT, _blocks({}), tol=1e-12, max_iter=2000)
    assert np.sqrt(np.mean((A @ np.linalg.lstsq(_dense(u, {}), y, rcond=None)[0] - y) ** 2)) > 0
    assert plain["rmse"] != pytest.approx(want, rel=1e-3)


def test_extra_columns_and_weights_match_dense_weighted_least_squares():
    t, u = _input(seed=2)
    rng = np.random.default_rng(3)
    eff = {"lowpass": {"cutoff_hz": 600.0, "order": 1}}
    y = np.cos(5 * u) + 0.2 * t + 0.01 * rng.standard_normal(u.size)
    w = (1 + 0.3 * t) ** 2
    pre = np.gradient(u, DT) * 1e-3
    post = t.copy()
    A = _dense(u, eff)
    Apre = apply_effects(eff, t, pre)
    M = np.column_stack([A, Apre, post]) * np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(M, y * np.sqrt(w), rcond=None)
    want = np.sqrt(np.sum((M @ coef - y * np.sqrt(w)) ** 2) / np.sum(w))
    res = _preisach.Behind(u, N_H, RANGE).solve(y, DT, _blocks(eff), weights=w, pre=pre[None, :].copy(),
                                                 post=post[None, :].copy(), tol=1e-12, max_iter=3000)
    assert res["rmse"] == pytest.approx(want, rel=1e-6)
    assert res["extra"] == pytest.approx(list(coef[-2:]), rel=1e-4, abs=1e-9)


def test_noise_free_chain_is_recovered_with_masses_nonnegative():
    t, u = _input(seed=4)
    rng = np.random.default_rng(5)
    w = np.triu(rng.uniform(0.2, 1.0, (N_H, N_H)))
    truth = PreisachModel(w, RANGE, 0.3, "interpolated")
    eff = {"vibration": {"frequency_hz": 250.0, "damping": 0.03}}
    y = apply_effects(eff, t, truth.predict(u))
    core, rep = _preisach.fit_behind(u, y, N_H, RANGE, DT, _blocks(eff), None, 1e-12, 2000)
    m = PreisachModel._wrap(core, "interpolated")
    assert rep["rmse"] < 1e-8
    np.testing.assert_allclose(np.triu(m.weights), w, atol=1e-6)
    assert m.offset == pytest.approx(0.3, abs=1e-6)


def _walk(n=6000, seed=0):
    """A random walk with jumps, reaching beyond the range."""
    rng = np.random.default_rng(seed)
    steps = np.where(rng.uniform(size=n) < 0.01, rng.uniform(-0.6, 0.6, n), rng.normal(0, 0.01, n))
    return np.arange(n) * DT, np.clip(0.5 + np.cumsum(steps), -0.1, 1.1)


@pytest.mark.parametrize("source,effects", [
    (_input, {"vibration": {"frequency_hz": 300.0, "damping": 0.02}}),
    (_walk, {"lowpass": {"cutoff_hz": 500.0, "order": 2}}),
])
def test_masses_projection_equals_scipy_nnls_of_the_optimum_output(source, effects):
    """The masses >= 0 (twice on one problem: the second projection reuses what the first
    built) against scipy.optimize.nnls of the unfiltered relay columns fitted to the
    unconstrained optimum's hysteresis output (the offset free: two signed columns)."""
    from scipy.optimize import nnls
    t, u = source(seed=7)
    rng = np.random.default_rng(8)
    b = _preisach.Behind(u, N_H, RANGE)
    plain, A = _dense(u, {}), _dense(u, effects)
    cols = np.column_stack([plain[:, :-1], plain[:, -1], -plain[:, -1]])
    for k in range(2):
        y = np.sin((6 + k) * u) - 0.5 * u + 0.05 * rng.standard_normal(u.size)
        res = b.solve(y, DT, _blocks(effects), tol=1e-13, max_iter=5000, warm=False, nnls=True)
        h_star = plain @ np.linalg.lstsq(A, y, rcond=None)[0]
        want = cols @ nnls(cols, h_star, maxiter=50 * cols.shape[1])[0]
        got = PreisachModel._wrap(res["model"], "interpolated").predict(u)
        span = np.ptp(h_star)
        assert np.max(np.abs(got - want)) < 1e-5 * span
        # The bound is active (the unconstrained optimum has negative masses): the test can fail.
        assert np.sqrt(np.mean((want - h_star) ** 2)) > 1e-4 * span


def _unit(u):
    """``u`` mapped onto [-0.05, 1.05] (a little beyond the model range, as a fit takes it)."""
    return -0.05 + 1.1 * (u - u.min()) / np.ptp(u)


def _sim_stage(seed, n=6000):
    """The project's simulator (the paper stage, random seed) driven by a random walk."""
    from preisach.sim import Stage
    t, u = _walk(n, seed)
    y = Stage.preset("paper", seed=seed).run(10.0 * u)
    return u, y


def _rig(seed, n=6000):
    """The independent rig's training record (its first ``n`` samples, at 10 kHz)."""
    import rig
    rec = rig.make_case("none", seed)["train"]
    return _unit(rec["u"][:n]), rec["y"][:n]


def _independent(seed, n=6000):
    """The independent stage's training record (10 kHz)."""
    import independent_stage
    rec = independent_stage.make_stage(seed, ("lowpass",), fs=10e3, dur=n * DT)["train"]
    return _unit(rec["u"][:n]), rec["y"][:n]


#: The smoothness weight that makes the projection's optimum unique (in the solver's
#: scaled units), as the diagnosis's sessions take it.
TIE = _preisach.PROJECTION_TIE


def _neighbours(n_h):
    """The smoothness term's rows: a difference of two neighbouring cells' masses each
    (cells in ``np.triu_indices`` order)."""
    cells = {c: k for k, c in enumerate(zip(*np.triu_indices(n_h)))}
    rows = []
    for (i, j), k in cells.items():
        for nb in ((i + 1, j), (i, j + 1)):
            if nb in cells:
                r = np.zeros(len(cells))
                r[k], r[cells[nb]] = 1.0, -1.0
                rows.append(r)
    return np.array(rows)


@pytest.mark.parametrize("source", [_sim_stage, _rig, _independent])
@pytest.mark.parametrize("seed", [3, 11])
def test_kept_projection_is_the_nnls_optimum_on_simulated_records(source, seed):
    """Several projections in turn on one input (what the fit keeps is reused) from
    records of both simulators: the output and the masses equal scipy.optimize.nnls's on
    the dense relay columns with the smoothness term's rows appended (in original units
    the objective is ||C w + c - h*||^2 + N TIE ||G w||^2, N samples), the masses satisfy
    that problem's optimality conditions, and the structured fit of the same output with
    the same smoothness weight gives the same model."""
    from scipy.optimize import nnls
    u, y = source(seed)
    rng = np.random.default_rng(seed)
    b = _preisach.Behind(u, N_H, RANGE, tie=TIE)
    plain = _dense(u, {})
    G = _neighbours(N_H)
    ridge = np.sqrt(u.size * TIE) * np.column_stack([G, np.zeros((G.shape[0], 2))])
    cols = np.vstack([np.column_stack([plain[:, :-1], plain[:, -1], -plain[:, -1]]), ridge])
    iu = np.triu_indices(N_H)
    for _k in range(3):
        effects = {"lowpass": {"cutoff_hz": float(rng.uniform(200.0, 1500.0)), "order": int(rng.integers(1, 3))}}
        A = _dense(u, effects)
        z = y + float(rng.uniform(0.0, 0.3)) * np.ptp(y) * np.sin(float(rng.uniform(3.0, 9.0)) * u)
        res = b.solve(z, DT, _blocks(effects), tol=1e-13, max_iter=5000, warm=False, nnls=True)
        h_star = plain @ np.linalg.lstsq(A, z, rcond=None)[0]
        span = np.ptp(h_star)
        sol = nnls(cols, np.concatenate([h_star, np.zeros(G.shape[0])]), maxiter=50 * cols.shape[1])[0]
        model = PreisachModel._wrap(res["model"], "interpolated")
        got = model.predict(u)
        w = model.weights[iu]
        assert np.max(np.abs(got - cols[:u.size] @ sol)) < 1e-6 * span
        assert np.max(np.abs(w - sol[:-2])) < 1e-3 * np.max(sol[:-2])
        # Optimality: the objective's gradient (residual and smoothness term) is zero
        # for the offset and every cell with mass, and >= 0 for the cells at zero.
        g = plain.T @ (got - h_star)
        g[:-1] += u.size * TIE * (G.T @ (G @ w))
        tol = 1e-6 * np.max(np.abs(plain.T @ h_star))
        assert np.all(w >= 0.0)
        assert abs(g[-1]) < tol
        assert np.all(g[:-1] > -tol)
        assert np.all(np.abs(g[:-1][w > 1e-7 * w.max()]) < tol)
        fitted, _ = _preisach.fit(u, h_star, N_H, RANGE, reg=TIE, solver="structured", interpolated=True,
                                  diagonal_floor=0.0)
        assert np.max(np.abs(PreisachModel._wrap(fitted, "interpolated").predict(u) - got)) < 1e-6 * span


def test_sessions_sharing_a_projection_give_what_each_alone_gives():
    """Sessions on one input at other strides share the masses' projection (the first
    to project builds it): each projection equals that of a session with its own, bit
    for bit, whichever session built it; another input, grid or smoothness weight is
    refused, named."""
    t, u = _input(seed=3)
    y = np.sin(7 * u) + 0.2 * u
    eff = {"lowpass": {"cutoff_hz": 600.0, "order": 2}}
    a = _preisach.Behind(u, N_H, RANGE, 1, tie=TIE)
    b = _preisach.Behind(u, N_H, RANGE, 4, tie=TIE)
    b.share(a)
    yb = np.ascontiguousarray(y[: u.size // 4 * 4].reshape(-1, 4).mean(axis=1))
    got_b = b.solve(yb, 4 * DT, _blocks(eff), tol=1e-10, warm=False, nnls=True)  # b builds it
    got_a = a.solve(y, DT, _blocks(eff), tol=1e-10, warm=False, nnls=True)
    for sess, z, dt, got in ((a, y, DT, got_a), (b, yb, 4 * DT, got_b)):
        alone = _preisach.Behind(u, N_H, RANGE, 1 if sess is a else 4, tie=TIE)
        want = alone.solve(z, dt, _blocks(eff), tol=1e-10, warm=False, nnls=True)
        np.testing.assert_array_equal(got["model"].weights(), want["model"].weights())
        assert got["rmse_nnls"] == want["rmse_nnls"]
    for other in (_preisach.Behind(u[::-1].copy(), N_H, RANGE, tie=TIE),  # another input
                  _preisach.Behind(u, N_H + 1, RANGE, tie=TIE),  # another grid
                  _preisach.Behind(u, N_H, RANGE)):  # the plain projection
        with pytest.raises(ValueError, match="share: another input, start, grid or smoothness weight"):
            other.share(a)
    with pytest.raises(ValueError, match="tie: must be >= 0"):
        _preisach.Behind(u, N_H, RANGE, tie=-1.0)


def test_a_pooled_session_fits_as_a_new_one_and_each_problem_is_built_once(monkeypatch):
    """The run's pool (``preisach.diagnose.pool``) builds a problem (input content, grid,
    window, smoothness weight, memory at the start) once and hands out copies: a copy
    fits bit for bit as a session built anew, whatever another copy solved before;
    another window, input or start is another problem; the oldest problem goes when the
    pool is full."""
    from preisach.diagnose.pool import Sessions

    built = []
    real = _preisach.Behind

    def counting(u, n_h, u_range, stride=1, tie=0.0, initial_extrema=None):
        built.append((n_h, stride))
        return real(u, n_h, u_range, stride, tie=tie, initial_extrema=initial_extrema)
    monkeypatch.setattr(_preisach, "Behind", counting)
    t, u = _input(seed=5)
    y = np.sin(5 * u) + 0.1 * t
    yb = np.ascontiguousarray(y[: u.size // 4 * 4].reshape(-1, 4).mean(axis=1))
    eff = {"vibration": {"frequency_hz": 300.0, "damping": 0.05}}
    pool = Sessions(kept=2)
    first = pool.session(u, N_H, RANGE, 4, TIE)
    first.solve(yb[::-1].copy(), 4 * DT, _blocks(eff), tol=1e-10)  # a warm start of its own
    second = pool.session(u.copy(), N_H, RANGE, 4, TIE)  # the same content
    assert built == [(N_H, 4)]
    got = second.solve(yb, 4 * DT, _blocks(eff), tol=1e-10, nnls=True)
    want = real(u, N_H, RANGE, 4, tie=TIE).solve(yb, 4 * DT, _blocks(eff), tol=1e-10, nnls=True)
    assert (got["rmse"], got["iterations"], got["extra"]) == (want["rmse"], want["iterations"], want["extra"])
    np.testing.assert_array_equal(got["model"].weights(), want["model"].weights())
    pool.session(u, N_H, RANGE, 2, TIE)  # another window
    pool.session(u[::-1].copy(), N_H, RANGE, 4, TIE)  # another input: the first problem goes
    pool.session(u, N_H, RANGE, 4, TIE)
    assert built == [(N_H, 4), (N_H, 2), (N_H, 4), (N_H, 4)]
    after = pool.session(u, N_H, RANGE, 4, TIE, (0.9, 0.1))  # another start
    assert built[-1] == (N_H, 4) and len(built) == 5
    got = after.solve(yb, 4 * DT, _blocks(eff), tol=1e-10, nnls=True)
    want = real(u, N_H, RANGE, 4, tie=TIE, initial_extrema=[0.9, 0.1]).solve(yb, 4 * DT, _blocks(eff), tol=1e-10,
                                                                            nnls=True)
    assert got["rmse_nnls"] == want["rmse_nnls"] and got["rmse_nnls"] != second.solve(
        yb, 4 * DT, _blocks(eff), tol=1e-10, nnls=True)["rmse_nnls"]


def test_bad_arguments_are_named():
    t, u = _input(n=500)
    b = _preisach.Behind(u, N_H, RANGE)
    with pytest.raises(ValueError, match="z: length"):
        b.solve(u[:-1].copy(), DT, _blocks({}))
    with pytest.raises(ValueError, match=r"blocks\[0\] \(drift\): not a linear block in series"):
        b.solve(u, DT, _blocks({"drift": {"gain_per_s": 0.1}}))
    with pytest.raises(ValueError, match="dt: must be > 0"):
        b.solve(u, -DT, _blocks({}))
    with pytest.raises(ValueError, match="weights: negative"):
        b.solve(u, DT, _blocks({}), weights=-np.ones(u.size))
    with pytest.raises(ValueError, match="above: must be finite, got NaN"):
        b.solve(u, DT, _blocks({}), above=float("nan"))
    with pytest.raises(ValueError, match="above: must be >= 0"):
        b.solve(u, DT, _blocks({}), above=-1.0)
    with pytest.raises(ValueError, match="stride"):
        _preisach.Behind(u, N_H, RANGE, 0)
    with pytest.raises(ValueError, match="initial_extrema: NaN at index 1"):
        _preisach.Behind(u, N_H, RANGE, initial_extrema=[0.5, float("nan")])
    with pytest.raises(ValueError, match="share: another input, start"):
        _preisach.Behind(u, N_H, RANGE, initial_extrema=[0.5]).share(b)


@pytest.fixture(scope="module")
def drift_record():
    t, u = _input(n=9000, seed=6)
    w = np.triu(np.random.default_rng(7).uniform(0.2, 1.0, (N_H, N_H)))
    x = PreisachModel(w, RANGE, 0.1, "interpolated").predict(u)
    y = (1 + 0.02 * t) * x + 0.05 - 0.03 * t + 1e-4 * np.random.default_rng(8).standard_normal(t.size)
    return Record("train", t, u, y, DT), w


def test_adding_an_effect_never_fits_the_training_record_worse(drift_record):
    rec, _ = drift_record
    f = Fitter(rec, N_H, RANGE, stride=2)
    for base in ({}, {"creep": {"taus_s": [0.2], "amplitudes": [0.02], "normalized": True}}):
        j0 = f.J(base)
        # Nested: a drift with no gain adds an offset slope, which can only help (this
        # failed while the iteration stopped on a residual relative to the start).
        assert f.J(dict(base, drift={"gain_per_s": 0.0, "offset": 0.0, "offset_per_s": 0.0})) <= j0 * (1 + 1e-9)
    # The true drift takes the error down to the noise.
    j = f.J({"drift": {"gain_per_s": 0.02, "offset": 0.0, "offset_per_s": 0.0}})
    assert j < 0.01 * f.J({})
    # y = (1 + g t)(x + 0.05) + o'' t: the offset 0.05 stays in the model, o'' = -0.03 - 0.05 g.
    assert f.with_linear({"drift": {"gain_per_s": 0.02, "offset": 0.0, "offset_per_s": 0.0}})["drift"][
        "offset_per_s"] == pytest.approx(-0.03 - 0.05 * 0.02, abs=2e-3)


def test_a_chain_that_cannot_beat_a_ceiling_is_given_up_and_fitted_exactly_when_asked(drift_record):
    """``Fitter.J(eff, above)``: a chain whose fit cannot get below ``above`` (a low-pass
    far below the record's band, against the true drift's error) gives up, at an error
    above ``above`` and above the chain's own optimum (a fresh fitter's exact ``J``, the
    oracle); a lower ceiling reuses that answer, and ``J`` without one fits it exactly.
    (A tight tolerance: the fits run until their decrease flattens, as the diagnosis's
    low cutoffs do.)"""
    rec, _ = drift_record
    good = {"drift": {"gain_per_s": 0.02, "offset": 0.0, "offset_per_s": 0.0}}
    bad = {"lowpass": {"cutoff_hz": 0.5, "order": 2}}
    exact = Fitter(rec, N_H, RANGE, stride=2, tol=1e-12).J(bad)
    f = Fitter(rec, N_H, RANGE, stride=2, tol=1e-12)
    ceiling = f.J(good)
    assert exact > 10 * ceiling
    quit = f.J(bad, above=ceiling)
    assert quit > exact * (1 + 2e-5) and quit > ceiling
    n = f.evaluations
    assert f.J(bad, above=ceiling / 2) == quit and f.evaluations == n
    assert f.J(bad) == pytest.approx(exact, rel=2e-6) and f.evaluations == n + 1
    assert f.J(bad, above=ceiling) == f.J(bad) and f.evaluations == n + 1
    assert f.J(good, above=ceiling) == ceiling  # an exact value answers every ceiling
    # Several chains at once follow the same rule: a value given up above a ceiling is
    # refitted (in parallel) for a higher one, and reused for a lower one.
    g = Fitter(rec, N_H, RANGE, stride=2, tol=1e-12)
    mapped = []
    fit_all = g.trials.map
    g.trials.map = lambda fn, items: mapped.append(len(items)) or fit_all(fn, items)
    given_up = g.Jmany([bad, good], above=ceiling)[0]
    assert given_up > exact * (1 + 2e-5) and given_up > ceiling and mapped == [2]
    n = g.evaluations
    assert g.Jmany([bad], above=ceiling / 2) == [given_up] and g.evaluations == n and mapped[-1] == 0
    assert g.Jmany([bad, good])[0] == pytest.approx(exact, rel=2e-6) and g.evaluations == n + 1
    assert mapped[-1] == 1  # the given-up chain among the parallel fits


def _drifting_creeping_records():
    """Three records of a stage with creep (restarting with each) and drift (in absolute
    time), and a chain with both at wrong values."""
    w = np.triu(np.random.default_rng(9).uniform(0.2, 1.0, (N_H, N_H)))
    model = PreisachModel(w, RANGE, 0.1, "interpolated")
    truth = {"creep": {"taus_s": [0.3], "amplitudes": [0.05], "normalized": True},
             "drift": {"gain_per_s": 0.02, "offset": 0.0, "offset_per_s": -0.03}}
    recs = []
    t0 = 0.0
    for seed in (10, 11, 12):
        t, u = _input(n=9000, seed=seed)
        t = t + t0
        t0 = t[-1] + DT
        y = FitState(model, truth).predict(Record("r", t, u, np.zeros_like(t), DT))
        recs.append(Record("r", t, u, y, DT))
    st = FitState(model, {"creep": {"taus_s": [0.05], "amplitudes": [0.01], "normalized": True},
                          "drift": {"gain_per_s": 0.0, "offset": 0.0, "offset_per_s": 0.0}})
    return st, recs


def test_slow_calibration_folds_sharing_the_records_columns_calibrate_as_alone():
    """The two folds of a chain's calibration (the first record whole, the others' first
    or second halves) share each record's output and creep columns: each fold finds what
    it finds alone, and both recover the stage."""
    st, recs = _drifting_creeping_records()
    shared: dict = {}
    for k in (0, 1):
        data = [(recs[0], slice(None))] + [(r, slice(0, 4500) if k == 0 else slice(4500, None)) for r in recs[1:]]
        cal = calibrate_slow(st, data, shared)
        assert cal.effects == calibrate_slow(st, data).effects
        assert cal.effects["drift"]["gain_per_s"] == pytest.approx(0.02, rel=1e-2)
        assert cal.effects["creep"]["taus_s"][0] == pytest.approx(0.3, rel=0.3)
    assert sum(isinstance(key, tuple) for key in shared) >= 3 * 14  # a grid of time constants per record


@pytest.mark.parametrize("cal_rate", [5e3, 1e3])
def test_slow_calibration_recovers_drift_and_creep_across_records(cal_rate, monkeypatch):
    """Drift runs on in absolute time, creep restarts with every record: calibrated across
    records (masses and level fixed), both come back. The least squares runs on window
    averages (2 and 10 samples here): exact for noise-free data even with an input that
    jumps every sample (a creep element run on the averaged output instead was 10 % off)."""
    from preisach.diagnose import search

    monkeypatch.setattr(search, "CAL_RATE_HZ", cal_rate)
    st, recs = _drifting_creeping_records()
    cal = calibrate_slow(st, [(r, slice(None)) for r in recs])
    assert cal.effects["drift"]["gain_per_s"] == pytest.approx(0.02, rel=1e-3)
    assert cal.effects["drift"]["offset_per_s"] == pytest.approx(-0.03, rel=1e-3)
    # The time constant comes from a grid (which holds 0.3 s within a few percent).
    assert cal.effects["creep"]["taus_s"][0] == pytest.approx(0.3, rel=0.3)
    err = max(np.sqrt(np.mean((cal.predict(r) - r.y) ** 2)) for r in recs)
    before = max(np.sqrt(np.mean((st.predict(r) - r.y) ** 2)) for r in recs)
    assert err < 0.05 * before




def test_another_n_h_is_fitted_as_a_fitter_of_that_n_h_would_and_its_fitter_kept(drift_record):
    """``Fitter.state(eff, n_h=...)``: the chain with another number of levels, as a
    fitter of that n_h fits it, on a fitter kept for the next call (its sessions are the
    costly part)."""
    rec, _ = drift_record
    f = Fitter(rec, N_H, RANGE, stride=2)
    eff = {"drift": {"gain_per_s": 0.02, "offset": 0.0, "offset_per_s": 0.0}}
    fine = f.state(eff, n_h=N_H + 4)
    alone = Fitter(rec, N_H + 4, RANGE, stride=2).state(eff)
    assert fine.model.n_h == N_H + 4
    assert fine.train_rmse == pytest.approx(alone.train_rmse, rel=1e-6)
    assert f.other(N_H + 4) is f.other(N_H + 4)
    assert f.other(N_H + 2) is not f.other(N_H + 4)


def test_a_chain_asked_for_again_is_the_one_fitted_and_the_callers_own(drift_record):
    """``Fitter.state`` keeps the chains it fitted (a projection is the costly part): the
    same chain asked for again is the same fit, and what a caller changes in the one it
    got does not reach the next caller; another chain, or the same one with a step from
    rest, is fitted anew."""
    rec, _ = drift_record
    f = Fitter(rec, N_H, RANGE, stride=2)
    eff = {"drift": {"gain_per_s": 0.02, "offset": 0.0, "offset_per_s": 0.0}}
    a = f.state(eff)
    a.effects["drift"]["offset_per_s"] = 99.0
    a.effects["creep"] = {}
    b = f.state(eff)
    assert b.model is a.model and b.train_rmse == a.train_rmse
    assert set(b.effects) == {"drift"} and b.effects["drift"]["offset_per_s"] == pytest.approx(-0.03 - 0.05 * 0.02,
                                                                                                abs=2e-3)
    other = f.state({"drift": {"gain_per_s": 0.0, "offset": 0.0, "offset_per_s": 0.0}})
    assert other.model is not a.model and other.train_rmse > 2 * a.train_rmse
    f.rest = True
    assert f.state(eff).model is not a.model


@pytest.mark.parametrize("effects", [
    {"lowpass": {"cutoff_hz": 150.0, "order": 2}},
    {"vibration": {"frequency_hz": 300.0, "damping": 0.03},
     "drift": {"gain_per_s": 0.5, "offset": 0.0, "offset_per_s": 0.0}},
])
def test_a_fit_from_a_later_sample_counts_only_there_with_the_memory_and_dynamics_before(effects):
    """``Fitter(start=k)``: the profiled error of the samples from ``k`` on, the chain run
    over the whole record (the hysteresis memory and the blocks' state at ``k`` are the
    ones the samples before leave): dense least squares on the rows from ``k`` on of the
    regression matrix through the blocks over the whole record (the oracle)."""
    t, u = _input(n=6000, seed=4)
    rng = np.random.default_rng(5)
    y = np.sin(7 * u) + 0.3 * u + 0.01 * rng.standard_normal(u.size)
    k = 3500
    A = _dense(u, {n: p for n, p in effects.items() if n != "drift"})
    cols = [A]
    if "drift" in effects:  # y = (1 + g t)(chain) + o'' t
        q = 1 + effects["drift"]["gain_per_s"] * t
        cols = [A * q[:, None], t[:, None]]
    # (The samples before weigh ``PART_FLOOR``: they only keep the fit regular.)
    w = np.where(np.arange(u.size) >= k, 1.0, PART_FLOOR)
    M = np.column_stack(cols) * np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(M, y * np.sqrt(w), rcond=None)
    want = float(np.sum((M @ coef - y * np.sqrt(w)) ** 2) / np.sum(w))
    f = Fitter(Record("r", t, u, y, DT), N_H, RANGE, stride=1, tol=1e-13, start=k)
    assert f.J(effects) == pytest.approx(want, rel=1e-6)
    # ... and so count for nothing: the fit of the samples from k on alone.
    alone, *_ = np.linalg.lstsq(np.column_stack(cols)[k:], y[k:], rcond=None)
    assert want == pytest.approx(float(np.mean((np.column_stack(cols)[k:] @ alone - y[k:]) ** 2)), rel=1e-4)
    # The same samples cut out as a record of their own start from rest: another fit.
    cut = Fitter(Record("r", t[k:], u[k:], y[k:], DT), N_H, RANGE, stride=1, tol=1e-13)
    assert abs(cut.J(effects) / want - 1) > 1e-2
