"""The operator-based solver (solver="gradient"): the same optimum as clarabel on a
mid-size problem, and n_h beyond the interior-point solvers' limit."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from conftest import smooth_weights

from preisach import PreisachModel, _preisach


def _walk(rng: np.random.Generator, n: int, step: float) -> np.ndarray:
    x = np.cumsum(rng.normal(0, step, n)) % 2.4 - 0.2
    return np.where(x > 1.1, 2.2 - x, x)


def _objective(u, y, n, m):
    A, counts, target, within = _preisach.regression_rows(u, y, n, (0.0, 1.0))
    iu = np.triu_indices(n)
    x = np.concatenate([m.weights[iu], [m.offset]])
    r = A @ x - target
    return (float(counts @ r**2) + within) / counts.sum()


def test_gradient_solver_matches_clarabel_objective_mid_size():
    rng = np.random.default_rng(4)
    n = 30
    truth = PreisachModel(smooth_weights(n), (0.0, 1.0), offset=0.2)
    u = _walk(rng, 40_000, 0.03)
    y = truth.predict(u) + rng.normal(0, 0.05, u.size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mg = PreisachModel.fit(u, y, n, u_range=(0.0, 1.0), solver="gradient")
        mc = PreisachModel.fit(u, y, n, u_range=(0.0, 1.0), solver="clarabel")
    assert mg.report.solver == "gradient"
    assert not any("iteration cap" in w for w in mg.report.warnings)
    assert _objective(u, y, n, mg) == pytest.approx(_objective(u, y, n, mc), rel=1e-6)


def test_gradient_solver_fits_n_h_1000():
    n = 1000
    t = np.linspace(0.0, 1.0, 20_000)
    u = 0.5 + 0.53 * np.linspace(0.05, 1.0, t.size) * np.sin(np.pi * 40 * t)
    y = PreisachModel(smooth_weights(50), (0.0, 1.0)).predict(u)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = PreisachModel.fit(u, y, n, solver="gradient")
        with pytest.raises(ValueError, match="n_h: 1000 is too large"):
            PreisachModel.fit(u, y, n, solver="structured")
    assert m.n_h == n and m.report.solver == "gradient"
    assert np.all(np.isfinite(m.weights)) and np.all(m.weights >= 0)
    assert m.report.rmse < 0.05 * np.std(y)
