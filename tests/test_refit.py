"""The hysteresis identified again behind a chain's linear part (``preisach._refit``).

Oracles: records simulated by the project's chain (``Chain.simulate``) and by the
independent stage of ``tests/independent_stage.py`` (SciPy filters, no project block),
with random parameters; the refitted chain's inverse run through the same simulator.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from independent_stage import draw_effects, true_hysteresis
from independent_stage import simulate as independent_simulate
from preisach import Chain, PreisachModel
from preisach._refit import hysteresis_output, refit_hysteresis

FS = 20e3


def _identification(model: PreisachModel, n_rev: int = 60, f_hz: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """An increasing-amplitude sine over the model's range (the paper's record), after a
    rest at its centre."""
    lo, hi = model.u_range
    n = int(n_rev / 2 / f_hz * FS)
    t = np.arange(n) / FS
    u = 0.5 * (lo + hi) - 0.5 * (hi - lo) * (t / t[-1]) * np.cos(2 * np.pi * f_hz * t)
    return np.arange(n) / FS, u


def _tracking_error(chain: Chain, simulate, model: PreisachModel, gain: float, f_hz: float) -> float:
    w = float(model.weights.sum())
    lo, hi = model.offset - w, model.offset + w
    c, a = 0.5 * (lo + hi), 0.3 * (hi - lo)
    n = int(3 * FS / f_hz)
    rest = 200
    r = gain * (c - a * np.cos(2 * np.pi * f_hz * np.maximum(np.arange(n) - rest, 0) / FS))
    u = chain.invert(r, FS)
    y = simulate(np.arange(n) / FS, u)
    skip = rest + int(FS / f_hz)
    return float(np.abs(r - y)[skip:-100].max() / (gain * a))


def test_hysteresis_output_undoes_the_linear_blocks():
    rng = np.random.default_rng(4)
    eff = draw_effects(rng, ("creep", "vibration", "delay"))
    post = Chain(None, eff).blocks
    t = np.arange(int(0.5 * FS)) / FS
    h = 1.0 + 0.5 * np.sin(2 * np.pi * 7 * t) ** 2
    y = Chain(None, eff).predict(t, h)
    got = hysteresis_output(post, y, FS)
    assert np.abs(got - h)[50:-50].max() < 2e-3


@pytest.mark.parametrize("seed", [1, 2])
def test_refit_behind_the_true_linear_part_tracks_on_the_project_simulator(seed):
    rng = np.random.default_rng(seed)
    truth = true_hysteresis(rng, n_h=80)
    eff = draw_effects(rng, ("creep", "vibration", "delay"))
    stage = Chain(truth, eff)
    t, u = _identification(truth)
    y = stage.simulate(t, u)
    coarse = Chain(PreisachModel.fit(u, y, 10, output="interpolated"), eff)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = refit_hysteresis(coarse, t, u, y, n_h=60)
    assert got.model.n_h == 60 and got.model.output == "interpolated"
    assert got.kinds() == coarse.kinds() and got.effects == coarse.effects
    gain = 1.0 + sum(eff["creep"]["amplitudes"])
    errs = [_tracking_error(c, stage.simulate, truth, gain, 5.0) for c in (coarse, got)]
    assert errs[1] < 0.02 and errs[1] < 0.5 * errs[0], errs


@pytest.mark.parametrize("seed", [3, 5])
def test_refit_behind_the_true_linear_part_tracks_on_the_independent_stage(seed):
    rng = np.random.default_rng(seed)
    truth = true_hysteresis(rng, n_h=80)
    eff = draw_effects(rng, ("vibration", "lowpass", "delay"))
    t, u = _identification(truth)
    sim_rng = np.random.default_rng(seed + 100)

    def simulate(tt: np.ndarray, uu: np.ndarray) -> np.ndarray:
        return independent_simulate(truth, eff, tt, uu, 0.0, sim_rng)

    y = simulate(t, u)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = refit_hysteresis(Chain(PreisachModel.fit(u, y, 10), eff), t, u, y, n_h=60)
    assert _tracking_error(got, simulate, truth, 1.0, 5.0) < 0.02


def test_refit_fits_the_hysteresis_input_behind_the_blocks_before_it():
    """An amplifier's gain and a low-pass before the hysteresis: the refitted model maps
    the hysteresis input (the chain's input through them), so the chain predicts the
    record."""
    rng = np.random.default_rng(8)
    truth = true_hysteresis(rng, n_h=80)
    lo, hi = truth.u_range
    pre = [{"type": "amplifier", "gain": 4.0}, {"type": "lowpass", "cutoff_hz": 3000.0, "order": 1}]
    post = Chain(None, {"vibration": {"frequency_hz": 900.0, "damping": 0.03}}).blocks
    stage = Chain.from_blocks(pre + Chain(truth).blocks + post)
    t, u = _identification(PreisachModel(truth.weights, (lo / 4, hi / 4), truth.offset))
    y = stage.simulate(t, u)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = Chain.from_blocks(pre + Chain(PreisachModel.fit(4 * u, y, 10)).blocks + post)
        got = refit_hysteresis(start, t, u, y, n_h=60)
    assert got.kinds() == ["amplifier", "lowpass", "hysteresis", "vibration"]
    assert abs(got.model.u_range[1] - 4 * u.max()) < 0.05 * (hi - lo)  # the model's input is the amplified one
    span = float(y.max() - y.min())
    assert np.sqrt(np.mean((got.predict(t, u) - y) ** 2)) < 0.01 * span


def test_refit_names_a_nan_in_the_record():
    chain = Chain(PreisachModel(np.eye(4), (0.0, 1.0), 0.0, "interpolated"))
    t = np.arange(100) / FS
    y = np.sin(t)
    y[17] = np.nan
    with pytest.raises(ValueError, match="y: .*17"):
        refit_hysteresis(chain, t, t, y)


def test_refit_refuses_a_chain_without_one_hysteresis_and_mismatched_lengths():
    t = np.arange(100) / FS
    with pytest.raises(ValueError, match="exactly one hysteresis"):
        refit_hysteresis(Chain(None, {"delay": {"delay_s": 1e-3}}), t, t, t)
    chain = Chain(PreisachModel(np.eye(4), (0.0, 1.0), 0.0, "interpolated"))
    with pytest.raises(ValueError, match="u, y"):
        refit_hysteresis(chain, t, t, t[:50])
