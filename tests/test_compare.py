"""`preisach compare` and `preisach.compare`: MATLAB's NRMSE fit, RMSE and max error per
record, on records from the project's simulator and from an independent NumPy relay grid
behind SciPy filters; the figure of measured against model."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
from conftest import random_weights, relay_grid_predict, sweep_input
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import preisach
from preisach import Chain, PreisachModel, compare, fit_percent
from preisach.cli import main
from preisach.io import write_csv

signal = pytest.importorskip("scipy.signal")


# --- the fit figure ------------------------------------------------------------------

finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, st.integers(3, 40), elements=finite), st.floats(-3, 3))
def test_fit_percent_is_matlabs_nrmse_on_scaled_errors(y, c):
    """y_hat = y + c (y - mean y) has ‖y - y_hat‖ = |c| ‖y - mean y‖: fit = 100 (1 - |c|)."""
    if np.ptp(y) < 1e-3:
        return
    assert fit_percent(y, y) == 100.0
    assert fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0, abs=1e-9)
    assert fit_percent(y, y + c * (y - y.mean())) == pytest.approx(100 * (1 - abs(c)), abs=1e-7)


def test_fit_percent_of_a_constant_record_is_matlabs_division():
    assert fit_percent([2.0, 2.0], [2.0, 2.0]) != fit_percent([2.0, 2.0], [2.0, 2.0])  # nan
    assert fit_percent([2.0, 2.0], [1.0, 2.0]) == float("-inf")
    with pytest.raises(ValueError, match="y_hat: length 1 does not match y"):
        fit_percent([1.0, 2.0], [1.0])


# --- two independent sources of records ------------------------------------------------

def _simulator_record(seed: int) -> dict[str, np.ndarray]:
    """The project's simulated `paper` stage, 100 kHz, an increasing-amplitude sine."""
    rng = np.random.default_rng(seed)
    n = 6000
    t = np.arange(n) / 1e5
    u = 3.75 + rng.uniform(2.5, 3.7) * np.linspace(0.1, 1, n) * np.sin(2 * np.pi * rng.uniform(30, 60) * t)
    stage = preisach.sim.Stage.preset("paper", seed=int(seed))
    return {"t": t, "u": u, "y": stage.run(u)}


def _scipy_record(seed: int) -> dict[str, np.ndarray]:
    """An independent stage: a NumPy relay grid (random masses) behind a SciPy
    second-order low-pass, plus noise."""
    rng = np.random.default_rng(seed)
    n_h = int(rng.integers(6, 12))
    w = random_weights(rng, n_h)
    u = sweep_input(0.0, 1.0, int(rng.integers(20, 40)), 3000)
    h = relay_grid_predict(w, 0.0, 1.0, float(rng.normal()), u)
    b, a = signal.butter(2, float(rng.uniform(0.05, 0.3)))
    y = signal.lfilter(b, a, h - h[0]) + h[0] + rng.normal(0, 0.01, u.size)
    return {"t": np.arange(u.size) / 1e4, "u": u, "y": y}


def _fit(rec: dict[str, np.ndarray], n_h: int) -> PreisachModel:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", preisach.PreisachWarning)
        return PreisachModel.fit(rec["u"], rec["y"], n_h)


@pytest.mark.parametrize("make, seed", [(_simulator_record, 1), (_simulator_record, 2),
                                        (_scipy_record, 3), (_scipy_record, 4)])
def test_compare_figures_against_an_independent_relay_grid(make, seed):
    rec = make(seed)
    model = _fit(rec, 10)
    res = compare(model, rec, name="r")
    # The model's output through the NumPy relay grid, not through the code under test.
    y_hat = relay_grid_predict(model.weights, *model.u_range, model.offset, rec["u"])
    e = rec["y"] - y_hat
    assert res.rmse == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-9)
    assert res.max_error == pytest.approx(np.max(np.abs(e)), rel=1e-9)
    dev = rec["y"] - np.mean(rec["y"])
    assert res.fit_percent == pytest.approx(100 * (1 - np.sqrt(np.sum(e**2) / np.sum(dev**2))), rel=1e-9)
    assert 50 < res.fit_percent < 100
    np.testing.assert_allclose(res.residual, e, atol=1e-9)


def test_compare_runs_a_chain_on_time_and_input(tmp_path):
    rec = _scipy_record(5)
    model = _fit(rec, 8)
    chain = Chain(model, {"delay": {"delay_s": 3e-4}})
    res = compare(chain, rec)
    np.testing.assert_array_equal(res.y_hat, chain.predict(rec["t"], rec["u"]))
    assert res.name == "record"
    write_csv(tmp_path / "r.csv", rec)
    assert compare(chain, tmp_path / "r.csv").name == "r.csv"


def test_compare_cli_table_json_and_plot(tmp_path, capsys):
    recs = [_simulator_record(6), _scipy_record(7)]
    paths = []
    for i, r in enumerate(recs):
        paths.append(str(tmp_path / f"rec{i}.csv"))
        write_csv(paths[-1], r)
    model = _fit(recs[0], 12)
    model.save(tmp_path / "m.json")
    plot, out = tmp_path / "c.png", tmp_path / "c.json"
    assert main(["compare", str(tmp_path / "m.json"), *paths, "--json", str(out), "--plot", str(plot)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[:3] == ["record", "samples", "fit"]
    doc = json.loads(out.read_text())
    assert [r["record"] for r in doc["records"]] == ["rec0.csv", "rec1.csv"]
    for r, row, line in zip(recs, doc["records"], lines[1:3]):
        e = r["y"] - model.predict(r["u"])
        assert row["samples"] == r["u"].size
        assert row["rmse"] == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-12)
        assert row["max_error"] == pytest.approx(np.abs(e).max(), rel=1e-12)
        assert line.split()[2] == f"{row['fit_percent']:.2f}"
    mpl_image = pytest.importorskip("matplotlib.image")
    one = tmp_path / "one.png"
    assert main(["compare", str(tmp_path / "m.json"), paths[0], "--plot", str(one)]) == 0
    assert mpl_image.imread(plot).shape[0] > 1.5 * mpl_image.imread(one).shape[0]  # a row per record


def test_compare_accepts_a_chain_file(tmp_path, capsys):
    rec = _scipy_record(8)
    chain = Chain(_fit(rec, 8), {"delay": {"delay_s": 2e-4}})
    chain.save(tmp_path / "c.json")
    write_csv(tmp_path / "r.csv", rec)
    assert main(["compare", str(tmp_path / "c.json"), str(tmp_path / "r.csv"), "--json", str(tmp_path / "o.json")]) == 0
    row = json.loads((tmp_path / "o.json").read_text())["records"][0]
    assert row["rmse"] == pytest.approx(np.sqrt(np.mean((rec["y"] - chain.predict(rec["t"], rec["u"])) ** 2)))


def test_compare_errors_are_one_line(tmp_path, capsys):
    rec = _scipy_record(9)
    _fit(rec, 6).save(tmp_path / "m.json")
    write_csv(tmp_path / "noy.csv", {"t": rec["t"], "u": rec["u"]})
    assert main(["compare", str(tmp_path / "m.json"), str(tmp_path / "noy.csv")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "missing column(s) y" in err
    assert main(["compare", str(tmp_path / "m.json")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
