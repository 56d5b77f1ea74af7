"""`preisach import-mat`: dSPACE-style structs and plain variables round trip to CSV."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

sio = pytest.importorskip("scipy.io")

from preisach.cli import main  # noqa: E402
from preisach.io import read_record  # noqa: E402
from preisach.matlab import list_channels, read_mat  # noqa: E402

N = 500
T = np.arange(N) / 1e4
U = 3.75 + 3 * np.sin(2 * np.pi * 20 * T)
Y = 0.2 * (5 * U + 0.3 * np.cos(2 * np.pi * 20 * T))


def _dspace_struct(names=("Model Root/Plant/u_dac", "Model Root/Plant/y_sensor", "Model Root/ctrl/err"),
                   data=(U, Y, Y - U)):
    """A capture as ControlDesk writes it: X (time) and Y (channels with Name and Data)."""
    X = np.zeros((1,), dtype=[("Name", "O"), ("Type", "O"), ("Data", "O"), ("Unit", "O")])
    X[0] = ("Time", "Time", T, "s")
    Ys = np.zeros((1, len(names)), dtype=[("Name", "O"), ("Type", "O"), ("Data", "O"), ("Path", "O")])
    for k, (n, d) in enumerate(zip(names, data)):
        Ys[0, k] = (n, "Data", d, "/".join(n.split("/")[:-1]))
    return {"X": X, "Y": Ys, "Description": "trace", "RTProgram": {"Name": "stage"}}


@pytest.fixture
def dspace_mat(tmp_path):
    p = tmp_path / "capture.mat"
    sio.savemat(p, {"capture_001": _dspace_struct()})
    return p


@pytest.fixture
def plain_mat(tmp_path):
    p = tmp_path / "plain.mat"
    sio.savemat(p, {"t": T, "M": np.column_stack([U, Y]), "uu": U.reshape(-1, 1), "gain": 5.0, "note": "lab"})
    return p


def test_dspace_capture_channels_and_round_trip(dspace_mat, tmp_path, capsys):
    chs = list_channels(dspace_mat)
    assert [c.name for c in chs] == ["Time", "Model Root/Plant/u_dac", "Model Root/Plant/y_sensor",
                                     "Model Root/ctrl/err"]
    assert main(["import-mat", str(dspace_mat), "--list"]) == 0
    out = capsys.readouterr().out
    assert "u_dac" in out and "   0  Time" in out
    # By leaf name (case-insensitive), the time axis from X by default.
    o = tmp_path / "rec.csv"
    assert main(["import-mat", str(dspace_mat), "--u", "U_DAC", "--y", "Model Root/Plant/y_sensor", "-o", str(o)]) == 0
    rec = read_record(o, ["t", "u", "y"])
    np.testing.assert_array_equal(rec["t"], T)
    np.testing.assert_array_equal(rec["u"], U)
    np.testing.assert_array_equal(rec["y"], Y)
    # By index, same result.
    o2 = tmp_path / "rec2.csv"
    assert main(["import-mat", str(dspace_mat), "--t", "0", "--u", "1", "--y", "2", "-o", str(o2)]) == 0
    assert o.read_text() == o2.read_text()


def test_plain_variables_vectors_and_matrix_columns(plain_mat, tmp_path):
    names = [c.name for c in list_channels(plain_mat)]
    assert names == ["t", "M(:,1)", "M(:,2)", "uu"]  # scalars and strings are not signals
    rec = read_mat(plain_mat, u="M(:,1)", y="M(:,2)", t="t")
    np.testing.assert_array_equal(rec["u"], U)
    np.testing.assert_array_equal(rec["y"], Y)
    # A column vector is a channel; --fs builds the time axis; y is optional.
    o = tmp_path / "u.csv"
    assert main(["import-mat", str(plain_mat), "--u", "uu", "--fs", "10000", "-o", str(o)]) == 0
    rec = read_record(o, ["t", "u"])
    assert "y" not in rec
    np.testing.assert_allclose(rec["t"], T)


def test_matrix_stored_with_signals_along_rows(tmp_path):
    p = tmp_path / "rows.mat"
    sio.savemat(p, {"D": np.vstack([T, U, Y])})  # 3 x N
    rec = read_mat(p, t="D(:,1)", u="D(:,2)", y="D(:,3)")
    np.testing.assert_array_equal(rec["y"], Y)


def test_missing_name_and_bad_index_name_the_channel_and_list_the_available(dspace_mat, capsys):
    assert main(["import-mat", str(dspace_mat), "--u", "u_cmd", "-o", "x.csv"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert "'u_cmd'" in err and "--u" in err and "1:Model Root/Plant/u_dac" in err and "0:Time" in err
    assert main(["import-mat", str(dspace_mat), "--u", "1", "--y", "9", "-o", "x.csv"]) == 1
    err = capsys.readouterr().err
    assert "--y" in err and "index 9" in err and "0..3" in err and "y_sensor" in err


def test_plain_file_without_time_channel_says_how(plain_mat, capsys):
    assert main(["import-mat", str(plain_mat), "--u", "uu", "-o", "x.csv"]) == 1
    err = capsys.readouterr().err
    assert "--t" in err and "--fs" in err


def test_ambiguous_leaf_name(tmp_path):
    p = tmp_path / "amb.mat"
    sio.savemat(p, {"c": _dspace_struct(names=("A/y", "B/y", "A/u"), data=(Y, Y, U))})
    with pytest.raises(ValueError, match="ambiguous"):
        read_mat(p, u="A/u", y="y")
    rec = read_mat(p, u="A/u", y="B/y")
    np.testing.assert_array_equal(rec["y"], Y)


def test_mismatched_lengths_and_nan(tmp_path):
    p = tmp_path / "bad.mat"
    sio.savemat(p, {"t": T, "u": U, "short": Y[:10], "nany": np.where(T > 0.01, np.nan, Y)})
    with pytest.raises(ValueError, match=r"'short' has 10 samples"):
        read_mat(p, t="t", u="u", y="short")
    with pytest.raises(ValueError, match=r"'nany' has NaN at sample"):
        read_mat(p, t="t", u="u", y="nany")


def test_v73_and_garbage_files_are_clear_errors(tmp_path, capsys):
    v73 = tmp_path / "v73.mat"
    head = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Jan  1 00:00:00 2024 HDF5 schema 1.00 ."
    v73.write_bytes(head.ljust(512, b" ") + b"\x89HDF\r\n\x1a\n" + b"\0" * 64)
    assert main(["import-mat", str(v73), "--list"]) == 1
    err = capsys.readouterr().err
    assert "v7.3" in err and "-v7" in err and err.count("\n") == 1
    junk = tmp_path / "junk.mat"
    junk.write_bytes(b"not a mat file at all" * 10)
    assert main(["import-mat", str(junk), "--list"]) == 1
    assert "not a readable MAT file" in capsys.readouterr().err
    assert main(["import-mat", str(tmp_path / "missing.mat"), "--list"]) == 1
    assert "no such file" in capsys.readouterr().err


def test_usage_errors_exit_2(dspace_mat, capsys):
    assert main(["import-mat", str(dspace_mat), "-o", "x.csv"]) == 2
    assert "--u" in capsys.readouterr().err
    assert main(["import-mat", str(dspace_mat), "--u", "1", "--t", "0", "--fs", "1e4", "-o", "x.csv"]) == 2


def test_missing_scipy_is_one_clear_line(tmp_path):
    p = tmp_path / "a.mat"
    sio.savemat(p, {"t": T})
    code = ("import sys; sys.modules['scipy'] = None; sys.modules['scipy.io'] = None\n"
            "from preisach.cli import main\n"
            f"raise SystemExit(main(['import-mat', {str(p)!r}, '--list']))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert r.stderr.strip() == "preisach: error: reading .mat files needs SciPy: pip install 'preisach[mat]'"


def test_single_channel_capture_and_mat_v4(tmp_path):
    p = tmp_path / "one.mat"
    sio.savemat(p, {"cap": _dspace_struct(names=("Plant/u",), data=(U,))})
    assert [c.name for c in list_channels(p)] == ["Time", "Plant/u"]
    rec = read_mat(p, u="u")
    np.testing.assert_array_equal(rec["t"], T)
    assert set(rec) == {"t", "u"}
    p4 = tmp_path / "v4.mat"
    sio.savemat(p4, {"t": T.reshape(-1, 1), "u": U.reshape(-1, 1), "y": Y.reshape(-1, 1)}, format="4")
    rec = read_mat(p4, t="t", u="u", y="y")
    np.testing.assert_array_equal(rec["y"], Y)
