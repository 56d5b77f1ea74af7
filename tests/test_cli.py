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
from lti_reference import apply_effects

from preisach import PreisachModel, PreisachWarning
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
    ["compare", "-1e3", "-1e3", "--n-h", "\n"],  # found by the fuzz campaign: a line break in an argument
    ["identify", "x\ny.csv", "--n-h", "a\r\nb", "-o", "m.json"],
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
    assert "m.json: corrupt model: 'weights' must be a list of 2 rows" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()


def test_console_script_and_module_entry_points_show_help_with_an_example():
    script = Path(sys.executable).parent / "preisach"  # installed beside the interpreter
    for cmd in ([str(script)], [sys.executable, "-m", "preisach"]):
        for sub in ["identify", "predict", "invert", "simulate", "diagnose"]:
            r = subprocess.run(cmd + [sub, "--help"], capture_output=True, text=True, timeout=60)
            assert r.returncode == 0, r.stderr
            assert "example:" in r.stdout


# --------------------------------------------------------------------------- any model, chain or stage
def _files(tmp_path, truth):
    """The same model as a version-1 file, a version-2 file, a chain with effects and a
    stage with noise."""
    from preisach import Chain
    from preisach.sim import Stage

    v1 = tmp_path / "v1.json"
    w = truth.weights
    v1.write_text(json.dumps({"format": "preisach-model", "version": 1, "n_h": truth.n_h,
                              "u_range": list(truth.u_range), "offset": truth.offset, "output": truth.output,
                              "weights": [w[i, i:].tolist() for i in range(truth.n_h)]}))
    v2 = tmp_path / "v2.json"
    truth.save(v2)
    chain = tmp_path / "chain.json"
    Chain(truth, {"delay": {"delay_s": 5e-4}, "lowpass": {"cutoff_hz": 300.0}}).save(chain)
    stage = tmp_path / "stage.json"
    Stage(Chain(truth).blocks + [{"type": "noise", "std": 0.01, "seed": 3}], sample_rate_hz=1e3).save(stage)
    return v1, v2, chain, stage


def test_predict_and_simulate_take_any_model_chain_or_stage(tmp_path, record):
    p, truth = record
    v1, v2, chain, stage = _files(tmp_path, truth)
    rec = np.loadtxt(p, delimiter=",", skiprows=1)
    out = {}
    for f in (v1, v2, chain, stage):
        for cmd in ("predict", "simulate"):
            o = tmp_path / f"{f.stem}_{cmd}.csv"
            assert main([cmd, str(f), str(p), "-o", str(o)]) == 0
            data = np.loadtxt(o, delimiter=",", skiprows=1)
            np.testing.assert_array_equal(data[:, 0], rec[:, 0])  # the input's own time
            out[f.stem, cmd] = data[:, -1]
    y = truth.predict(rec[:, 1])
    for f in ("v1", "v2"):
        np.testing.assert_allclose(out[f, "predict"], y, atol=1e-12)
        np.testing.assert_allclose(out[f, "simulate"], y, atol=1e-12)
    # predict is deterministic (the stage's noise off); simulate adds it.
    np.testing.assert_allclose(out["stage", "predict"], y, atol=1e-12)
    assert 0.005 < np.std(out["stage", "simulate"] - y) < 0.015
    # The chain's effects at the record's own rate (the SciPy reference).
    want = apply_effects({"lowpass": {"cutoff_hz": 300.0}, "delay": {"delay_s": 5e-4}}, rec[:, 0], y)
    np.testing.assert_allclose(out["chain", "predict"], want, atol=1e-9)


def test_simulate_runs_at_the_input_rate_and_names_a_bad_time_row(tmp_path, capsys):
    from preisach.sim import Stage

    stage = tmp_path / "stage.json"
    Stage([{"type": "vibration", "modes": [{"frequency_hz": 780.0, "damping": 0.05}]}]).save(stage)
    for fs in (10e3, 100e3):
        t = np.arange(int(0.01 * fs)) / fs
        _write(tmp_path / "in.csv", t=t, u=(t >= 0.005).astype(float))
        assert main(["simulate", str(stage), str(tmp_path / "in.csv"), "-o", str(tmp_path / "o.csv")]) == 0
        assert f"at the input's {fs:g} Hz" in capsys.readouterr().out
        y = np.loadtxt(tmp_path / "o.csv", delimiter=",", skiprows=1)[:, 2]
        # First peak of the ringing half a period (of the damped mode) after the step.
        k = int(np.argmax(y))
        assert abs(t[k] - 0.005 - 0.5 / (780.0 * np.sqrt(1 - 0.05 ** 2))) <= 1.5 / fs
    t[40] = t[39]
    _write(tmp_path / "bad.csv", t=t, u=np.ones(t.size))
    assert main(["simulate", str(stage), str(tmp_path / "bad.csv"), "-o", str(tmp_path / "o.csv")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "must increase strictly, but row 40" in err


def test_invert_takes_a_model_of_either_version_and_a_chain(tmp_path, record, capsys):
    from preisach import Chain

    p, truth = record
    v1, v2, chain, stage = _files(tmp_path, truth)
    rec = np.loadtxt(p, delimiter=",", skiprows=1)
    _write(tmp_path / "ref.csv", t=rec[:, 0], r=rec[:, 2])
    got = []
    for f in (v1, v2):
        assert main(["invert", str(f), str(tmp_path / "ref.csv"), "-o", str(tmp_path / "u.csv")]) == 0
        got.append(np.loadtxt(tmp_path / "u.csv", delimiter=",", skiprows=1)[:, 1])
    np.testing.assert_array_equal(got[0], got[1])
    # A chain with effects: the chain inverse at the record's rate.
    assert main(["invert", str(chain), str(tmp_path / "ref.csv"), "-o", str(tmp_path / "u.csv")]) == 0
    u = np.loadtxt(tmp_path / "u.csv", delimiter=",", skiprows=1)[:, 1]
    # The measured output as the reference touches the ends of the reachable range.
    with pytest.warns(PreisachWarning, match="reference samples ask the hysteresis for an output beyond"):
        u_py = Chain.load(chain).invert(rec[:, 2], 1e4)
    np.testing.assert_allclose(u, u_py, rtol=0, atol=1e-12)
    out = capsys.readouterr()
    assert "chain inverse" in out.out
    assert out.err.count("warning: ") == 1 and "reachable range" in out.err
    # A stage's noise is left out: the same input as for the model alone.
    assert main(["invert", str(stage), str(tmp_path / "ref.csv"), "-o", str(tmp_path / "u.csv")]) == 0
    u = np.loadtxt(tmp_path / "u.csv", delimiter=",", skiprows=1)[:, 1]
    np.testing.assert_allclose(u, truth.invert(rec[:, 2], method="continuous"), rtol=0, atol=1e-9)
    assert main(["invert", str(v2), str(tmp_path / "ref.csv"), "-o", str(tmp_path / "u.csv"), "--bandwidth", "9"]) == 2
    assert "--bandwidth is for a chain" in capsys.readouterr().err


@pytest.mark.parametrize("block,msg", [
    ({"type": "warp"}, "blocks[1] (warp): unknown block type 'warp'"),
    ({"type": "lowpass"}, "blocks[1] (lowpass): missing field `cutoff_hz`"),
    ({"type": "lowpass", "cutoff_hz": float("nan")}, "blocks[1] (lowpass): cutoff_hz: must be finite, got nan"),
    ({"type": "creep", "taus_s": [-0.1], "amplitudes": [0.01]}, "blocks[1] (creep): taus_s[0]: must be > 0, got -0.1"),
    ({"type": "vibration", "modes": [{"frequency_hz": 700.0, "damping": 0}]},
     "blocks[1] (vibration): modes[0].damping: must be > 0, got 0"),
    ({"type": "lowpass", "cutoff_hz": 6000.0}, "blocks[1] (lowpass): cutoff_hz: must be below Nyquist (5000 Hz)"),
])
def test_bad_chain_files_are_one_line_errors_naming_block_and_field(tmp_path, record, capsys, block, msg):
    from preisach import Chain

    p, truth = record
    d = Chain(truth).to_dict()
    d["blocks"].append(block)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(d))
    assert main(["simulate", str(bad), str(p), "-o", str(tmp_path / "o.csv")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and msg in err, err
    assert not (tmp_path / "o.csv").exists()


def test_a_rate_without_hysteresis_before_it_is_refused(tmp_path, record, capsys):
    p, _ = record
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "preisach-chain", "version": 2,
                               "blocks": [{"type": "rate", "gain_s": 1e-3, "tau_s": 1e-3}]}))
    assert main(["predict", str(bad), str(p), "-o", str(tmp_path / "o.csv")]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "blocks[0] (rate): needs a hysteresis block before it" in err


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


def test_invert_reports_clipped_references_in_one_line_on_stderr(tmp_path, record, capsys):
    p, truth = record
    model_path = tmp_path / "m.json"
    truth.save(model_path)
    # Oracle: the reachable output is the model's output at the ends of u_range.
    y_lo, y_hi = truth.predict([0.0])[0], truth.predict([10.0])[0]
    r = np.linspace(y_lo, y_hi, 200)
    r[[50, 51, 120]] = [y_hi + 1.0, y_lo - 1.0, y_hi + 0.5]
    ref = tmp_path / "r.csv"
    _write(ref, t=np.arange(r.size) / 1e4, r=r)
    assert main(["invert", str(model_path), str(ref), "-o", str(tmp_path / "u.csv")]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("warning: 3 of 200 reference samples")
    assert "first at index 50," in err[0]
    u = np.loadtxt(tmp_path / "u.csv", delimiter=",", skiprows=1)[:, 1]
    np.testing.assert_allclose(u[[50, 51, 120]], [10.0, 0.0, 10.0], atol=1e-12)


def test_invert_names_the_file_of_a_chain_that_cannot_be_inverted(tmp_path, capsys):
    from preisach.sim import Stage

    stage = tmp_path / "stage.json"
    Stage.preset("paper").save(stage)  # its hysteresis is parametric: no inverse
    t = np.arange(50) / 1e4
    np.savetxt(tmp_path / "ref.csv", np.column_stack([t, np.linspace(1.0, 2.0, 50)]), delimiter=",",
               header="t,r", comments="")
    assert main(["invert", str(stage), str(tmp_path / "ref.csv"), "-o", str(tmp_path / "u.csv")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"preisach: error: {stage}: blocks[") and "cannot be inverted" in err[0]
    assert not (tmp_path / "u.csv").exists()
