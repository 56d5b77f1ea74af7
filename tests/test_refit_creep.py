"""Creep fitted behind a chain's refitted hysteresis (``preisach._refit.refit_creep``,
``refit_hysteresis(creep_records=...)``).

Oracles: the project's chain with random creep (``Chain.simulate``) and the independent
rig of ``tests/rig.py`` (class ``creep``: SciPy filters, a Prandtl-Ishlinskii
hysteresis, no project block), both with random parameters; the compensated output is
the simulator's response to the chain inverse; ``scipy.optimize.nnls`` for the solver.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from independent_stage import true_hysteresis
from preisach import Chain, PreisachModel
from preisach._preisach import nnls
from preisach._refit import creep_bank, refit_creep, refit_hysteresis
from rig import make_case, records
from scipy.optimize import nnls as scipy_nnls

FS = 5e3


def _ident(model: PreisachModel, fs: float, n_rev: int = 40, f_hz: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = model.u_range
    t = np.arange(int(n_rev / 2 / f_hz * fs)) / fs
    return t, 0.5 * (lo + hi) - 0.5 * (hi - lo) * (t / t[-1]) * np.cos(2 * np.pi * f_hz * t)


def _holds(model: PreisachModel, fs: float, hold_s: float) -> tuple[np.ndarray, np.ndarray]:
    """From rest at the bottom of the range, steps held ``hold_s`` each."""
    lo, hi = model.u_range
    levels = lo + (hi - lo) * np.array([0.0, 0.7, 0.3, 0.8])
    u = np.repeat(levels, int(hold_s * fs))
    return np.arange(u.size) / fs, u


def _error(chain: Chain, simulate, centre: float, amp: float, fs: float, f_hz: float = 2.0) -> float:
    """Peak tracking error over two periods of a sine started from rest (after one)."""
    n = int(3 * fs / f_hz)
    r = centre - amp * np.cos(2 * np.pi * f_hz * np.arange(n) / fs)
    y = simulate(np.arange(n) / fs, chain.invert(r, fs))
    return float(np.abs(r - y)[int(fs / f_hz):].max() / amp)


def _fit(start: Chain, rec, creep_recs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = refit_hysteresis(start, *rec, n_h=40)
        crept = refit_hysteresis(start, *rec, n_h=40, creep_records=creep_recs)
    return plain, crept


@pytest.mark.parametrize("seed", [1, 2])
def test_creep_fitted_on_held_steps_improves_compensation_on_the_project_simulator(seed):
    rng = np.random.default_rng(seed)
    truth = true_hysteresis(rng, n_h=60)
    taus = sorted(np.exp(rng.uniform(np.log(0.03), np.log(1.5), 2)))
    creep = {"taus_s": [float(x) for x in taus], "amplitudes": [float(x) for x in rng.uniform(0.02, 0.05, 2)]}
    stage = Chain(truth, {"creep": creep})
    t, u = _ident(truth, FS)
    th, uh = _holds(truth, FS, 2.0)
    rec, hold = (t, u, stage.simulate(t, u)), (th, uh, stage.simulate(th, uh))
    plain, crept = _fit(Chain(PreisachModel.fit(u, rec[2], 10)), rec, [hold])
    assert "creep" in crept.kinds() and "creep" not in plain.kinds()
    lo, hi = float(rec[2].min()), float(rec[2].max())
    errs = [_error(c, stage.simulate, 0.5 * (lo + hi), 0.3 * (hi - lo), FS) for c in (plain, crept)]
    assert errs[1] < 0.6 * errs[0], errs


def test_creep_fitted_between_the_hysteresis_and_a_mode_and_a_delay():
    """The blocks after the creep (a mode, a delay) are inverted out of the target and kept
    after the fitted bank."""
    rng = np.random.default_rng(3)
    truth = true_hysteresis(rng, n_h=60)
    after = {"vibration": {"frequency_hz": 400.0, "damping": 0.05}, "delay": {"delay_s": 1e-3}}
    creep = {"taus_s": [0.08, 0.6], "amplitudes": [0.03, 0.03]}
    stage = Chain(truth, {"creep": creep, **after})
    t, u = _ident(truth, FS)
    th, uh = _holds(truth, FS, 1.5)
    rec, hold = (t, u, stage.simulate(t, u)), (th, uh, stage.simulate(th, uh))
    plain, crept = _fit(Chain(PreisachModel.fit(u, rec[2], 10), after), rec, [hold])
    assert crept.kinds() == ["hysteresis", "creep", "vibration", "delay"]
    lo, hi = float(rec[2].min()), float(rec[2].max())
    errs = [_error(c, stage.simulate, 0.5 * (lo + hi), 0.3 * (hi - lo), FS) for c in (plain, crept)]
    assert errs[1] < 0.6 * errs[0], errs


@pytest.mark.parametrize("seed", [1, 2])
def test_creep_fit_improves_compensation_on_the_independent_rig(seed):
    case = make_case("creep", seed)
    fs, rig = case["fs"], case["rig"]
    train, hold = records(case)
    rec = (train["t"], train["u"], train["y"])
    steps = hold[0]
    plain, crept = _fit(Chain(PreisachModel.fit(train["u"], train["y"], 10)), rec,
                        [(steps["t"], steps["u"], steps["y"])])

    def simulate(tt: np.ndarray, uu: np.ndarray) -> np.ndarray:
        return rig.record(np.clip(uu, 0.0, 10.0), fs, rng=np.random.default_rng(seed))["y"]

    lo, hi = np.percentile(train["y"], [5, 95])
    errs = [_error(c, simulate, 0.5 * (lo + hi), 0.3 * (hi - lo), fs) for c in (plain, crept)]
    assert errs[1] < errs[0] and errs[1] < 0.04, errs


def test_refit_creep_recovers_a_creep_element_behind_a_known_hysteresis():
    rng = np.random.default_rng(7)
    truth = true_hysteresis(rng, n_h=40)
    model = PreisachModel(truth.weights, truth.u_range, truth.offset, "interpolated")
    stage = Chain(model, {"creep": {"taus_s": [0.3], "amplitudes": [0.04], "normalized": True}})
    th, uh = _holds(truth, FS, 2.0)
    got = refit_creep(Chain(model), [(th, uh, stage.simulate(th, uh))], taus_s=[0.1, 0.3, 1.0])
    c = got.effects["creep"]
    assert got.kinds() == ["hysteresis", "creep"]
    amps = dict(zip(c["taus_s"], c["amplitudes"]))
    assert abs(amps.get(0.3, 0.0) - 0.04) < 0.004 and sum(amps.values()) < 0.046, amps


def test_refit_creep_without_creep_in_the_data_keeps_it_negligible():
    rng = np.random.default_rng(9)
    model = PreisachModel(true_hysteresis(rng, n_h=40).weights, (0.0, 1.0), 0.0, "interpolated")
    th, uh = _holds(model, FS, 1.0)
    got = refit_creep(Chain(model, {"creep": {"taus_s": [0.5], "amplitudes": [0.05]}}),
                      [(th, uh, Chain(model).simulate(th, uh))])
    assert sum(got.effects.get("creep", {"amplitudes": [0.0]})["amplitudes"]) < 1e-3


def test_creep_bank_spans_ten_ms_to_the_longest_record():
    taus = creep_bank(4.0)
    assert taus[0] == pytest.approx(0.01) and taus[-1] == pytest.approx(4.0)
    assert np.allclose(np.diff(np.log10(taus)), np.diff(np.log10(taus))[0])
    assert creep_bank(0.001).size == 2


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 8))
def test_nnls_matches_scipy(seed, n):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((3 * n + 2, n))
    a[:, -1] = a[:, 0] * 0.999 + 1e-3 * a[:, -1]  # nearly collinear, like neighbouring creep elements
    b = rng.standard_normal(a.shape[0])
    x = nnls(a, b)
    ref = scipy_nnls(a, b)[0]
    assert (x >= 0).all()
    assert np.linalg.norm(a @ x - b) <= np.linalg.norm(a @ ref - b) * (1 + 1e-7) + 1e-9


def test_nnls_names_bad_input():
    a = np.ones((4, 2))
    with pytest.raises(ValueError, match="a: expected len"):
        nnls(a, np.ones(3))
    with pytest.raises(ValueError, match="b: .*NaN"):
        nnls(a, np.array([1.0, np.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match="a: .*inf"):
        nnls(np.array([[1.0, np.inf]] * 4), np.ones(4))
    with pytest.raises(ValueError, match="a: expected"):
        nnls(np.ones((0, 2)), np.ones(0))


def test_refit_creep_refuses_bad_arguments():
    chain = Chain(PreisachModel(np.eye(4), (0.0, 1.0), 0.0, "interpolated"))
    t = np.arange(100) / FS
    with pytest.raises(ValueError, match="records"):
        refit_creep(chain, [])
    with pytest.raises(ValueError, match="taus_s"):
        refit_creep(chain, [(t, t, t)], taus_s=[0.1, -1.0])
    y = t.copy()
    y[5] = np.nan
    with pytest.raises(ValueError, match=r"records\[0\]\.y: .*5"):
        refit_creep(chain, [(t, t, y)])
    with pytest.raises(ValueError, match=r"creep_records\[0\]\.u"):
        refit_hysteresis(chain, t, t, t, creep_records=[(t, t[:50], t)])
