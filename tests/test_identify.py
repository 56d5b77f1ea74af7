"""Identification: exact recovery, the two solvers against each other and against SciPy's
NNLS on the same rows, the report and the paper's pitfalls, bad input."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import forc_input, random_weights, relay_grid_predict, smooth_weights, sweep_input
from hypothesis import given, settings
from hypothesis import strategies as st

from preisach import PreisachModel, PreisachWarning, _preisach


def _objective(A, counts, target, within, x, n_samples=None):
    """Mean squared residual over the samples, from merged rows (counts = samples per
    row; pseudo-rows of the interpolated model have count 1, so pass n_samples)."""
    r = A @ x - target
    n = counts.sum() if n_samples is None else n_samples
    return (float(counts @ r**2) + within) / n


def _scipy_objective(u, y, n, rng_):
    """The optimum of SciPy's NNLS on the merged rows (offset split into two
    non-negative columns, rows scaled by the square root of their count)."""
    from scipy.optimize import nnls

    A, counts, target, within = _preisach.regression_rows(u, y, n, rng_)
    sw = np.sqrt(counts)[:, None]
    A2 = np.hstack([A, -A[:, -1:]]) * sw
    x, _ = nnls(A2, target * sw[:, 0], maxiter=50 * A2.shape[1])
    return (A, counts, target, within), _objective(A, counts, target, within, np.concatenate([x[:-2], [x[-2] - x[-1]]]))


def test_identification_recovers_known_masses_and_offset_noise_free(rng):
    for n in [6, 15]:
        w = random_weights(rng, n)
        truth = PreisachModel(w, (-1.0, 1.0), offset=-0.4)
        u = forc_input(-1.0, 1.0, n)
        for solver in ["active", "clarabel", "structured"]:
            m = PreisachModel.fit(u, truth.predict(u), n, u_range=(-1.0, 1.0), solver=solver, diagonal_floor=0)
            scale = w.max()
            assert np.max(np.abs(m.weights - w)) <= 1e-6 * scale
            assert abs(m.offset + 0.4) <= 1e-6 * scale
            assert m.report.solver == solver


def test_sweep_with_n_h_reversals_identifies_a_smooth_model():
    n = 20
    truth = PreisachModel(smooth_weights(n), (0.0, 10.0), offset=1.0)
    u = sweep_input(0.0, 10.0, 2 * n + 2, 40000)
    y = truth.predict(u)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # enough reversals, range exceeded: no pitfall
        m = PreisachModel.fit(u, y, n, u_range=(0.0, 10.0))
    assert m.report.rmse < 1e-9 * np.ptp(y)
    assert np.max(np.abs(m.weights - truth.weights)) < 1e-6 * truth.weights.max()


def test_solvers_agree_and_match_or_beat_scipy_nnls_on_the_same_rows(rng):
    n = 12
    truth = PreisachModel(random_weights(rng, n), (0, 1))
    u = np.clip(np.cumsum(rng.normal(0, 0.08, 6000)) % 1.4 - 0.2, -0.2, 1.2)
    y = truth.predict(u) + rng.normal(0, 0.05, u.size)
    (A, counts, target, within), f_scipy = _scipy_objective(u, y, n, (0.0, 1.0))
    iu = np.triu_indices(n)
    fs = {}
    for solver in ["active", "clarabel", "structured"]:
        with pytest.warns(PreisachWarning, match="far beyond"):  # the input spans -0.2 .. 1.2 on purpose
            m = PreisachModel.fit(u, y, n, u_range=(0.0, 1.0), solver=solver, diagonal_floor=0)
        xm = np.concatenate([m.weights[iu], [m.offset]])
        fs[solver] = _objective(A, counts, target, within, xm)
        assert fs[solver] <= f_scipy * (1 + 1e-9)
        assert m.report.rmse == pytest.approx(np.sqrt(fs[solver]), rel=1e-9)
    assert fs["clarabel"] == pytest.approx(fs["structured"], rel=1e-7)
    assert fs["active"] == pytest.approx(fs["clarabel"], rel=1e-7)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(2, 24), seed=st.integers(0, 2**31), sweep=st.booleans(), relay_grid=st.booleans(),
       noise=st.sampled_from([0.0, 0.01, 0.1]))
def test_active_solver_reaches_scipy_nnls_optimum_on_random_problems(n, seed, sweep, relay_grid, noise):
    """The active-set solver (its sparse LDLᵀ steps) against SciPy's NNLS on the same rows:
    random n_h, masses, inputs (sweeps or random walks) and noise, the data from the
    project's model or from the independent NumPy relay grid."""
    rng = np.random.default_rng(seed)
    w = random_weights(rng, n, zeros=rng.uniform(0.0, 0.6))
    offset = float(rng.normal())
    if sweep:
        u = sweep_input(0.0, 1.0, int(rng.integers(n, 3 * n + 2)), 3000)
    else:
        u = np.clip(np.cumsum(rng.normal(0, 0.06, 3000)) % 1.4 - 0.2, -0.2, 1.2)
    y = relay_grid_predict(w, 0.0, 1.0, offset, u) if relay_grid else PreisachModel(w, (0, 1), offset=offset).predict(u)
    y = y + rng.normal(0, noise, u.size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = PreisachModel.fit(u, y, n, u_range=(0.0, 1.0), solver="active", diagonal_floor=0)
    (A, counts, target, within), f_scipy = _scipy_objective(u, y, n, (0.0, 1.0))
    iu = np.triu_indices(n)
    f = _objective(A, counts, target, within, np.concatenate([m.weights[iu], [m.offset]]))
    # (Relative to the output's variance where the optimum is an exact fit.)
    assert f <= f_scipy * (1 + 1e-9) + 1e-10 * np.var(y)
    assert np.all(m.weights >= 0)
    if m.report.solver == "active":  # (it may hand a degenerate problem to the interior point)
        assert m.report.rmse == pytest.approx(np.sqrt(f), rel=1e-9, abs=1e-12)


def test_cli_names_what_to_use_for_the_removed_gradient_solver(tmp_path, capsys):
    from preisach.cli import main

    u = sweep_input(0.0, 1.0, 10, 500)
    rec = tmp_path / "r.csv"
    np.savetxt(rec, np.c_[np.arange(u.size) * 1e-3, u, u], delimiter=",", header="t,u,y", comments="")
    assert main(["identify", str(rec), "--n-h", "5", "--solver", "gradient", "-o", str(tmp_path / "m.json")]) == 1
    err = capsys.readouterr().err
    assert "'gradient' has been removed; use 'auto'" in err and len(err.strip().splitlines()) == 1


def test_merged_rows_are_exact():
    """Merging samples with identical relay state does not change the objective."""
    rng = np.random.default_rng(3)
    n = 6
    u = rng.uniform(-0.1, 1.1, 500)
    y = rng.normal(size=500)
    A, counts, target, within = _preisach.regression_rows(u, y, n, (0.0, 1.0))
    assert A.shape[0] < 500 and counts.sum() == 500
    # Expand back: every sample's row is its state's row.
    x = rng.random(A.shape[1])
    # The per-sample objective through the relay grid definition (R = ±1).
    W = np.zeros((n, n))
    W[np.triu_indices(n)] = x[:-1]
    pred = relay_grid_predict(W, 0.0, 1.0, x[-1], u)
    full = float(np.mean((pred - y) ** 2))
    assert _objective(A, counts, target, within, x) == pytest.approx(full, rel=1e-10)


def test_regularization_makes_weights_smoother(rng):
    n = 10
    truth = PreisachModel(random_weights(rng, n), (0, 1))
    u = rng.uniform(-0.1, 1.1, 4000)
    y = truth.predict(u)
    rough = lambda w: float(np.sum(np.diff(w, axis=1)[np.triu_indices(n, 0, n - 1)] ** 2))
    a = PreisachModel.fit(u, y, n, u_range=(0, 1))
    b = PreisachModel.fit(u, y, n, u_range=(0, 1), reg=1.0)
    assert rough(b.weights) < 0.5 * rough(a.weights)


def test_default_range_sits_slightly_inside_the_input_range():
    u = sweep_input(-3.0, 7.0, 30, 5000)
    y = np.tanh(u)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = PreisachModel.fit(u, y, 10)
    lo, hi = m.u_range
    assert u.min() < lo < u.min() + 0.01 * np.ptp(u)
    assert u.max() - 0.01 * np.ptp(u) < hi < u.max()


def test_pitfalls_are_warned_and_reported():
    u = sweep_input(0.0, 1.0, 6, 3000)
    y = u**2
    with pytest.warns(PreisachWarning, match="does not exceed"), pytest.warns(PreisachWarning, match="reversals"):
        m = PreisachModel.fit(u, y, 20, u_range=(-0.5, 1.5))
    assert m.report.reversals < 20
    assert m.report.cells_never_excited > 0
    assert any("does not exceed" in w for w in m.report.warnings)
    with pytest.warns(PreisachWarning, match="far beyond"):
        PreisachModel.fit(u, y, 3, u_range=(0.4, 0.6))


@pytest.mark.parametrize("kwargs, match", [
    (dict(u=[0.0, np.nan], y=[0.0, 1.0], n_h=3), "u: NaN at index 1"),
    (dict(u=[0.0, 1.0], y=[0.0, np.inf], n_h=3), "y: inf at index 1"),
    (dict(u=[], y=[], n_h=3), "u: empty"),
    (dict(u=[0.0, 1.0, 2.0], y=[0.0, 1.0], n_h=3), "y: length 2 does not match u"),
    (dict(u=[0.0, 1.0], y=[0.0, 1.0], n_h=0), "n_h: must be >= 1"),
    (dict(u=[0.0, 1.0], y=[0.0, 1.0], n_h=3, u_range=(1.0, 0.0)), "u_range: lo must be below hi"),
    (dict(u=[0.0, 1.0], y=[0.0, 1.0], n_h=1_000_000), "n_h: .*too large"),
    (dict(u=[0.0, 1.0], y=[0.0, 1.0], n_h=601), "n_h: 601 is too large .*n_h <= 600"),
    (dict(u=[0.0, 1.0], y=[0.0, 1.0], n_h=3, reg=-1.0), "reg"),
    (dict(u=[0.0, 1.0], y=[0.0, 1.0], n_h=3, solver="magic"), "solver"),
    (dict(u=[0.0, 1.0], y=[0.0, 1.0], n_h=3, solver="gradient"), "solver: 'gradient' has been removed; use 'auto'"),
    (dict(u=[1.0, 1.0], y=[0.0, 1.0], n_h=3), "u: input is constant"),
])
def test_bad_fit_input_raises_valueerror_naming_the_argument(kwargs, match):
    with pytest.raises(ValueError, match=match):
        PreisachModel.fit(**kwargs)


def test_merged_interpolated_rows_reproduce_the_per_sample_objective():
    """Interpolated rows merge into two pseudo-rows per (extrema, cell) group: exact."""
    rng = np.random.default_rng(8)
    n = 7
    u = np.concatenate([sweep_input(0.0, 1.0, 30, 3000), rng.uniform(-0.1, 1.1, 300)])
    y = rng.normal(size=u.size)
    A, counts, target, within = _preisach.regression_rows(u, y, n, (0.0, 1.0), interpolated=True)
    assert A.shape[0] < u.size / 2
    for _ in range(3):
        w = np.triu(rng.random((n, n)))
        off = rng.normal()
        m = PreisachModel(w, (0.0, 1.0), offset=off)
        x = np.concatenate([w[np.triu_indices(n)], [off]])
        direct = float(np.mean((m.predict(u, output="interpolated") - y) ** 2))
        assert _objective(A, counts, target, within, x, u.size) == pytest.approx(direct, rel=1e-9)


def test_interpolated_fit_recovers_an_interpolated_model():
    n = 12
    truth = PreisachModel(smooth_weights(n), (0.0, 10.0), offset=0.5, output="interpolated")
    u = sweep_input(0.0, 10.0, 2 * n + 4, 30000)
    m = PreisachModel.fit(u, truth.predict(u), n, u_range=(0.0, 10.0), output="interpolated")
    assert m.output == "interpolated"
    assert np.max(np.abs(m.weights - truth.weights)) < 1e-6 * truth.weights.max()


# --- the diagonal floor -------------------------------------------------------------

@settings(max_examples=15, deadline=None)
@given(n=st.integers(2, 16), seed=st.integers(0, 2**31), noise=st.sampled_from([0.0, 0.01, 0.1]),
       fraction=st.sampled_from([0.01, 0.1, 0.5]), interpolated=st.booleans())
def test_diagonal_floor_fit_is_the_least_squares_optimum_with_the_diagonal_bounded_below(
        n, seed, noise, fraction, interpolated):
    """Oracle: SciPy's bounded least squares (``lsq_linear``) on the same merged rows, the
    excited diagonal masses bounded below by ``fraction * ptp(y) / (2 n_h)``, the rest by
    0, the offset free. The data come from models with zero diagonals (where the floor
    binds) and random masses elsewhere."""
    from scipy.optimize import lsq_linear

    rng = np.random.default_rng(seed)
    w = random_weights(rng, n, zeros=rng.uniform(0.0, 0.5))
    w[np.diag_indices(n)] = 0.0
    out = "interpolated" if interpolated else "stepwise"
    u = sweep_input(0.0, 1.0, int(rng.integers(n + 2, 3 * n + 4)), 3000)
    y = PreisachModel(w, (0, 1), offset=float(rng.normal()), output=out).predict(u) + rng.normal(0, noise, u.size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = PreisachModel.fit(u, y, n, u_range=(0.0, 1.0), output=out, diagonal_floor=fraction)
    floor = fraction * np.ptp(y) / (2 * n)  # the sweep reaches every level
    iu = np.triu_indices(n)
    lb = np.where(iu[0] == iu[1], floor, 0.0)
    assert np.all(m.weights[iu] >= lb * (1 - 1e-12))
    if interpolated:
        # One row per sample (the oracle builds them from the interpolated model itself).
        basis = np.eye(len(iu[0]))
        A = np.stack([PreisachModel(_dense(n, e, iu), (0, 1), output=out).predict(u) for e in basis], axis=1)
        A = np.hstack([A, np.ones((u.size, 1))])
        counts, target, within, n_samples = np.ones(u.size), y, 0.0, u.size
    else:
        A, counts, target, within = _preisach.regression_rows(u, y, n, (0.0, 1.0))
        n_samples = None
    sw = np.sqrt(counts)[:, None]
    bounds = (np.append(lb, -np.inf), np.full(lb.size + 1, np.inf))
    x = lsq_linear(A * sw, target * sw[:, 0], bounds=bounds, tol=1e-14, max_iter=10_000).x
    f_scipy = _objective(A, counts, target, within, x, n_samples)
    f = _objective(A, counts, target, within, np.concatenate([m.weights[iu], [m.offset]]), n_samples)
    assert f <= f_scipy * (1 + 1e-7) + 1e-10 * np.var(y)
    assert m.report.rmse == pytest.approx(np.sqrt(f), rel=1e-7, abs=1e-12)


def _dense(n, packed, iu):
    w = np.zeros((n, n))
    w[iu] = packed
    return w


def test_diagonal_floor_leaves_a_model_above_it_unchanged(rng):
    # A smooth model whose diagonal masses lie above the default floor: the bound does not
    # bind, so the fit recovers the masses exactly (noise-free), as without the floor.
    n = 20
    truth = PreisachModel(smooth_weights(n), (0.0, 10.0), offset=1.0)
    u = sweep_input(0.0, 10.0, 2 * n + 2, 40000)
    y = truth.predict(u)
    floor = 0.01 * np.ptp(y) / (2 * n)
    assert np.diag(truth.weights).min() > 2 * floor
    for f in (0.0, 0.01):
        m = PreisachModel.fit(u, y, n, u_range=(0.0, 10.0), diagonal_floor=f)
        assert np.max(np.abs(m.weights - truth.weights)) < 1e-6 * truth.weights.max()


@pytest.mark.parametrize("bad", [-0.1, 1.0, float("nan"), "0.1", True])
def test_bad_diagonal_floor_raises_valueerror_naming_it(bad):
    u = sweep_input(0.0, 1.0, 12, 500)
    with pytest.raises(ValueError, match="diagonal_floor"):
        PreisachModel.fit(u, u, 4, diagonal_floor=bad)
