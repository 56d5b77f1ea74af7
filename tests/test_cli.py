"""The command line: the workflow commands, one-line errors, exit codes."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import smooth_weights, sweep_input

from preisach import PreisachModel
from preisach.cli import main


def _write(path, **cols):
    names = list(cols)
    np.savetxt(path, np.column_stack([cols[n] for n in names]), delimiter=",", header=",".join(names),
               comments="", fmt="%.17g")


@pytest.fixture
def record(tmp_path):
    truth = PreisachModel(smooth_weights(20), (0.0, 10.0), offset=1.0)
    u = sweep_input(0.0, 10.0, 44, 20000)
    t = np.arange(u.size) / 1e4
    p = tmp_path / "rec.csv"
    _write(p, t=t, u=u, y=truth.predict(u))
    return p, truth


def test_identify_then_predict_reproduces_the_record(tmp_path, record, capsys):
    p, truth = record
    model_path = tmp_path / "m.json"
    assert main(["identify", str(p), "--n-h", "20", "--range", "0", "10", "-o", str(model_path)]) == 0
    m = PreisachModel.load(model_path)
    np.testing.assert_allclose(m.weights, truth.weights, atol=1e-6 * truth.weights.max())
    out = tmp_path / "y.csv"
    assert main(["predict", str(model_path), str(p), "-o", str(out)]) == 0
    with open(out) as f:
        assert f.readline().strip() == "t,y"
    data = np.loadtxt(out, delimiter=",", skiprows=1)
    rec = np.loadtxt(p, delimiter=",", skiprows=1)
    np.testing.assert_allclose(data[:, 1], rec[:, 2], atol=1e-6)
    assert "RMSE" in capsys.readouterr().out


def test_npz_records_are_read(tmp_path, record):
    p, truth = record
    rec = np.loadtxt(p, delimiter=",", skiprows=1)
    z = tmp_path / "rec.npz"
    np.savez(z, t=rec[:, 0], u=rec[:, 1], y=rec[:, 2])
    assert main(["identify", str(z), "--n-h", "10", "-o", str(tmp_path / "m.json")]) == 0


@pytest.mark.parametrize("argv", [
    ["identify"],
    ["identify", "x.csv", "-o", "m.json"],
    ["identify", "x.csv", "--n-h", "0", "-o", "m.json"],
    ["identify", "x.csv", "--n-h", "abc", "-o", "m.json"],
    ["nonsense"],
    ["invert", "m.json", "r.csv", "-o", "u.csv", "--method", "magic"],
])
def test_usage_errors_are_one_line_with_exit_code_2(argv, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_bad_data_is_one_line_with_exit_code_1(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,u,y\n0,1,2\n1,nan,3\n")
    assert main(["identify", str(bad), "--n-h", "5", "-o", str(tmp_path / "m.json")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "NaN in column u at row 1" in err
    missing = tmp_path / "missing.csv"
    missing.write_text("t,u\n0,1\n")
    assert main(["identify", str(missing), "--n-h", "5", "-o", str(tmp_path / "m.json")]) == 1
    assert "missing column(s) y" in capsys.readouterr().err
    assert main(["identify", str(tmp_path / "nope.csv"), "--n-h", "5", "-o", "m.json"]) == 1
    corrupt = tmp_path / "m.json"
    corrupt.write_text(json.dumps({"format": "preisach-model", "version": 1, "n_h": 2, "weights": [[1.0]]}))
    assert main(["predict", str(corrupt), str(bad), "-o", str(tmp_path / "o.csv")]) == 1
    assert "corrupt model file" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()


def test_console_script_and_module_entry_points_show_help_with_an_example():
    script = Path(sys.executable).parent / "preisach"  # installed beside the interpreter
    for cmd in ([str(script)], [sys.executable, "-m", "preisach"]):
        for sub in ["identify", "predict", "invert", "simulate", "diagnose"]:
            r = subprocess.run(cmd + [sub, "--help"], capture_output=True, text=True, timeout=60)
            assert r.returncode == 0, r.stderr
            assert "example:" in r.stdout
