"""The command line: the workflow commands, one-line errors, exit codes."""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import smooth_weights, sweep_input

from preisach import PreisachModel
from preisach.cli import build_parser, main


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
    ["invert", "m.json", "r.csv", "-o", "u.csv", "--lookahead", "10"],
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


# --- argument edges -----------------------------------------------------------------

@pytest.mark.parametrize("lo, hi", [("-1e3", "1e3"), ("-1.5E-3", "2"), ("-.5", "-0.25"), ("-7", "-1e-1")])
def test_range_takes_negative_numbers_in_any_float_spelling(lo, hi):
    a = build_parser().parse_args(["identify", "d.csv", "--n-h", "5", "--range", lo, hi, "-o", "m.json"])
    assert a.range == [float(lo), float(hi)]


def test_identify_with_a_negative_exponent_range_end_to_end(tmp_path):
    truth = PreisachModel(smooth_weights(8), (-1e3, 1e3))
    u = sweep_input(-1e3, 1e3, 20, 4000)
    p = tmp_path / "neg.csv"
    _write(p, t=np.arange(u.size) / 1e4, u=u, y=truth.predict(u))
    assert main(["identify", str(p), "--n-h", "8", "--range", "-1e3", "1e3", "-o", str(tmp_path / "m.json")]) == 0
    np.testing.assert_allclose(PreisachModel.load(tmp_path / "m.json").weights, truth.weights,
                               atol=1e-6 * truth.weights.max())


@pytest.mark.parametrize("rng_args, where", [(["100", "200"], "outside the range"),
                                             (["-1e3", "1e3"], "inside one of its n_h = 20 cells")])
def test_a_range_in_which_no_relay_switches_is_an_error(tmp_path, record, capsys, rng_args, where):
    p, _ = record  # input 0 .. 10
    out = tmp_path / "m.json"
    assert main(["identify", str(p), "--n-h", "20", "--range", *rng_args, "-o", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.count("--range") == 1 and where in err
    assert not out.exists()


@pytest.mark.parametrize("body, row", [("0,1,2\n0,2,3\n0,3,4\n", "row 1 (line 3)"),
                                      ("0,1,2\n1e-4,2,3\n2e-4,3,4\n1e-4,4,5\n", "row 3 (line 5)")])
def test_identify_rejects_a_time_column_that_does_not_increase(tmp_path, capsys, body, row):
    p = tmp_path / "t.csv"
    p.write_text("t,u,y\n" + body)
    assert main(["identify", str(p), "--n-h", "2", "-o", str(tmp_path / "m.json")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "column t must increase strictly" in err and row in err


@pytest.mark.parametrize("text", ["t,u,y\n", "t,u,y\n\n  \n"])
def test_a_csv_with_only_a_header_is_one_clear_line(tmp_path, capsys, text):
    p = tmp_path / "h.csv"
    p.write_text(text)
    assert main(["identify", str(p), "--n-h", "3", "-o", str(tmp_path / "m.json")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "empty record" in err and "Traceback" not in err


def test_help_shows_every_default():
    parser = build_parser()
    subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for name, sub in subs.choices.items():
        text = " ".join(sub.format_help().split())
        for action in sub._actions:
            if action.default in (None, False, argparse.SUPPRESS) or action.required:
                continue
            assert f"(default: {action.default})" in text or "(default:" in (action.help or ""), (name, action.dest)
    assert "(default: continuous)" in " ".join(subs.choices["invert"].format_help().split())
    assert "(default: auto)" in " ".join(subs.choices["identify"].format_help().split())


def test_invert_default_is_the_continuous_inverse(tmp_path, record):
    p, truth = record
    model_path = tmp_path / "m.json"
    truth.save(model_path)
    ref = tmp_path / "r.csv"
    r = truth.predict(sweep_input(1.0, 9.0, 4, 3000))
    _write(ref, t=np.arange(r.size) / 1e4, r=r)
    assert main(["invert", str(model_path), str(ref), "-o", str(tmp_path / "u.csv")]) == 0
    u = np.loadtxt(tmp_path / "u.csv", delimiter=",", skiprows=1)[:, 1]
    np.testing.assert_array_equal(u, truth.invert(r, method="continuous"))


# --- outputs and optional dependencies are checked before any work --------------------

def _no_work(monkeypatch):
    """Make every command's work fail loudly, to show a check came before it."""
    import preisach.cli as cli

    def boom(*_a, **_k):
        raise AssertionError("work started before the output check")

    for name in ("_cmd_identify", "_cmd_diagnose", "_cmd_compare", "_cmd_predict", "_cmd_export_mat"):
        monkeypatch.setattr(cli, name, boom)


@pytest.mark.parametrize("argv, flag", [
    (["diagnose", "train.csv", "--holdout", "h.csv", "--json", "{bad}/x.json"], "--json"),
    (["diagnose", "train.csv", "--holdout", "h.csv", "--json", "{ok}/r.json", "--save-model", "{bad}/a.json"],
     "--save-model"),
    (["diagnose", "train.csv", "--holdout", "h.csv", "--json", "{ok}/r.json", "--plots", "{file}/sub"], "--plots"),
    (["identify", "d.csv", "--n-h", "3", "-o", "{bad}/m.json"], "-o"),
    (["compare", "m.json", "d.csv", "--plot", "{bad}/c.png"], "--plot"),
    (["compare", "m.json", "d.csv", "--json", "{ok}"], "--json"),
])
def test_unwritable_outputs_fail_before_any_work_naming_the_users_path(tmp_path, monkeypatch, capsys, argv, flag):
    _no_work(monkeypatch)
    (tmp_path / "afile").write_text("x")
    subst = {"bad": str(tmp_path / "missing" / "dir"), "ok": str(tmp_path), "file": str(tmp_path / "afile")}
    argv = [a.format(**subst) for a in argv]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"preisach: error: {flag}:")
    assert str(tmp_path) in err and ".tmp" not in err


def test_a_failed_write_names_the_users_path_not_a_temporary_file(tmp_path):
    from preisach.io import write_csv

    target = tmp_path / "gone" / "x.csv"
    with pytest.raises(ValueError, match="cannot write") as exc:
        write_csv(target, {"t": np.zeros(2)})
    assert str(target) in str(exc.value) and ".tmp" not in str(exc.value)
    assert not list(tmp_path.rglob("*.tmp"))


@pytest.mark.parametrize("argv", [
    ["diagnose", "missing-train.csv", "--holdout", "h.csv", "--json", "{d}/r.json", "--plots", "{d}/plots"],
    ["compare", "missing-model.json", "d.csv", "--plot", "{d}/c.png"],
])
def test_missing_matplotlib_is_reported_before_any_work(tmp_path, argv):
    argv = [a.format(d=tmp_path) for a in argv]
    code = ("import sys; sys.modules['matplotlib'] = None\n"
            "from preisach.cli import main\n"
            f"raise SystemExit(main({argv!r}))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == [f"preisach: error: {argv[-2]}: plots need matplotlib: "
                                             "pip install 'preisach[plot]'"]
    assert not list(tmp_path.iterdir())
