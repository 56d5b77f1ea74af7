"""Shared helpers: an independent NumPy relay grid (the oracle) and random models."""
from __future__ import annotations

import os

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

# Hypothesis budgets. ``ci`` (the default, and what `.ci/run` uses) keeps the property
# and fuzz tests to a small time budget; ``campaign`` is the longer run of
# benches/fuzz_campaign.py. Tests that set max_examples themselves keep their own.
settings.register_profile("ci", max_examples=30, deadline=None, derandomize=True,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                 HealthCheck.function_scoped_fixture])
settings.register_profile("dev", max_examples=100, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                                 HealthCheck.function_scoped_fixture])
settings.register_profile("campaign", max_examples=int(os.environ.get("FUZZ_EXAMPLES", "1000")), deadline=None,
                          database=None, suppress_health_check=list(HealthCheck))
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def relay_grid_predict(weights: np.ndarray, lo: float, hi: float, offset: float, u: np.ndarray,
                       state: np.ndarray | None = None) -> np.ndarray:
    """Plain relay grid (the paper's eq. 1 and 4): every relay explicit, thresholds at cell centres."""
    n = weights.shape[0]
    d = (hi - lo) / n
    thr = lo + (np.arange(n) + 0.5) * d
    beta = thr[:, None] * np.ones((1, n))
    alpha = np.ones((n, 1)) * thr[None, :]
    upper = np.triu(np.ones((n, n), dtype=bool))
    R = -np.ones((n, n)) if state is None else state.copy()
    w = np.where(upper, weights, 0.0)
    out = np.empty(len(u))
    for k, x in enumerate(u):
        R = np.where(x >= alpha, 1.0, np.where(x < beta, -1.0, R))
        out[k] = float(np.sum(w * R)) + offset
    return out


def random_weights(rng: np.random.Generator, n: int, zeros: float = 0.2) -> np.ndarray:
    w = rng.random((n, n))
    w[rng.random((n, n)) < zeros] = 0.0
    return np.triu(w)


def smooth_weights(n: int) -> np.ndarray:
    """A smooth Preisach density: a Gaussian ridge near the diagonal plus a diagonal part."""
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    c = (j - i) / n  # coercivity
    m = (i + j) / (2 * n) - 0.5  # interaction
    w = np.exp(-((c - 0.15) ** 2) / 0.02 - m**2 / 0.1) + 2.0 * (i == j)
    return np.triu(w) / n


def forc_input(lo: float, hi: float, n: int) -> np.ndarray:
    """First-order reversal curves through every level: observes every Everett value."""
    lv = lo + (hi - lo) * np.arange(n + 1) / n
    u = [lo - 0.1]
    for a in range(1, n + 1):
        u.extend(lv[: a + 1])
        u.extend(lv[a - 1 :: -1])
    u.append(hi + 0.05)
    return np.array(u)


def sweep_input(lo: float, hi: float, n_rev: int, n: int) -> np.ndarray:
    """The paper's identification input: a sine of increasing amplitude (Fig. 6a)."""
    t = np.linspace(0.0, 1.0, n)
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    return mid + 1.06 * half * np.linspace(0.02, 1.0, n) * np.sin(np.pi * n_rev * t)


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)
