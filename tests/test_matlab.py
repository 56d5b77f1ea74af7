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
    assert r.stderr.strip() == "preisach: error: MAT files need SciPy: pip install 'preisach[mat]'"


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


# --- real captures: lost characters, the capture's sample period, pipes -------------------

LOST = "P\x86drag"  # "Pådrag" whose "å" (0x86 in the capture's code page) became a C1 control byte


def _capture(path, names, data, t, period=None, downsampling=1):
    cap = _dspace_struct(names=names, data=data)
    X = np.zeros((1,), dtype=[("Name", "O"), ("Type", "O"), ("Data", "O"), ("Unit", "O")])
    X[0] = ("Time", "Time", t, "s")
    cap["X"] = X
    if period is not None:
        cap["Capture"] = {"SamplingPeriod": period, "Downsampling": downsampling, "Length": t.size}
    sio.savemat(path, {"trace_1": cap})
    return path


@pytest.fixture
def lost_mat(tmp_path):
    names = (f"Model Root/Ctrl/{LOST}", f"Model Root/Plant/{LOST}", "Model Root/Plant/y_sensor")
    return _capture(tmp_path / "lost.mat", names, (U, 2 * U, Y), T)


def test_list_prints_printable_names(lost_mat, capsys):
    assert main(["import-mat", str(lost_mat), "--list"]) == 0
    out = capsys.readouterr().out
    assert all(c.isprintable() for line in out.splitlines() for c in line)
    assert "Model Root/Ctrl/P?drag" in out and "Model Root/Plant/P?drag" in out


@pytest.mark.parametrize("typed", ["Model Root/Ctrl/Pådrag", "model root/ctrl/PADRAG", "Model Root/Ctrl/Pdrag",
                                   "Model Root/Ctrl/P?drag", "Ctrl/Pådrag", "ctrl/pdrag", f"Model Root/Ctrl/{LOST}"])
def test_a_name_with_a_lost_character_matches_what_a_user_types(lost_mat, typed):
    rec = read_mat(lost_mat, u=typed, y="y_sensor")
    np.testing.assert_array_equal(rec["u"], U)


def test_a_leaf_shared_by_two_paths_is_ambiguous_and_lists_printable_names(lost_mat, capsys):
    assert main(["import-mat", str(lost_mat), "--u", "Pådrag", "-o", "x.csv"]) == 1
    err = capsys.readouterr().err
    assert "ambiguous" in err and "1:Model Root/Ctrl/P?drag" in err and "2:Model Root/Plant/P?drag" in err
    assert all(c.isprintable() for c in err.strip())


def test_printable_and_fold_rules():
    from preisach.matlab import printable

    assert printable("a\x00b\x1fc\x7fd\x86e\u200bf") == "a?b?c?d?e?f"
    assert printable("Pådrag µm") == "Pådrag µm"


@pytest.mark.parametrize("period, down", [(1e-4, 1), (5e-5, 2)])
def test_the_sample_rate_comes_from_the_captures_own_period(tmp_path, capsys, period, down):
    # X.Data in single precision from t0 = 100 s: its spacing reads as 9.92e-5 or 1.07e-4 s.
    t32 = (100.0 + np.arange(N) * 1e-4).astype(np.float32)
    assert abs(1.0 / np.median(np.diff(t32.astype(np.float64))) - 1e4) > 50
    p = _capture(tmp_path / "c.mat", ("Plant/u", "Plant/y"), (U, Y), t32, period=period, downsampling=down)
    o = tmp_path / "r.csv"
    assert main(["import-mat", str(p), "--u", "u", "--y", "y", "-o", str(o)]) == 0
    assert "10000 Hz" in capsys.readouterr().out
    rec = read_record(o, ["t", "u", "y"])
    np.testing.assert_allclose(rec["t"], 100.0 + np.arange(N) * 1e-4, rtol=0, atol=1e-12)


def test_a_time_axis_that_disagrees_with_the_period_is_kept_as_stored(tmp_path):
    t = np.concatenate([T[:200], T[200:] + 0.5])  # a gap of 0.5 s
    p = _capture(tmp_path / "gap.mat", ("Plant/u",), (U,), t, period=1e-4)
    np.testing.assert_array_equal(read_mat(p, u="u")["t"], t)


def test_without_a_period_the_rate_is_the_mean_spacing(tmp_path, capsys):
    t = T + 1e-7 * np.random.default_rng(0).standard_normal(N)  # jittered stamps
    p = _capture(tmp_path / "j.mat", ("Plant/u",), (U,), t)
    assert main(["import-mat", str(p), "--u", "u", "-o", str(tmp_path / "r.csv")]) == 0
    rate = float(capsys.readouterr().out.split(", ")[-1].split()[0])
    assert rate == pytest.approx((N - 1) / (t[-1] - t[0]), rel=1e-5)


@pytest.mark.parametrize("argv, err", [
    (["--u", "1", "--y", "1"], "--y: channel 1 ('Model Root/Plant/u_dac') is already --u"),
    (["--u", "u_dac", "--y", "Model Root/Plant/u_dac"], "--y: channel 1"),
    (["--u", "1", "--y", "2", "--t", "1"], "--t: channel 1"),
])
def test_one_channel_for_two_columns_is_rejected(dspace_mat, tmp_path, capsys, argv, err):
    assert main(["import-mat", str(dspace_mat), *argv, "-o", str(tmp_path / "x.csv")]) == 1
    assert err in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()


def test_a_closed_pipe_ends_the_listing_quietly(tmp_path):
    """`preisach import-mat FILE --list | head`: the reader goes away; no traceback, and
    the shell's code for SIGPIPE."""
    p = tmp_path / "many.mat"
    sio.savemat(p, {f"channel_with_a_long_name_{i:04d}": U[:50] for i in range(3000)})
    with subprocess.Popen([sys.executable, "-m", "preisach", "import-mat", str(p), "--list"],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE) as proc:
        assert proc.stdout is not None and proc.stderr is not None
        proc.stdout.close()  # the reader is gone before the first line
        err = proc.stderr.read().decode()
        assert proc.wait(timeout=120) == 141
    assert err == ""


# --- models to MATLAB ------------------------------------------------------------------

def _relay_loop(S, u):
    """The MATLAB loop of docs/guide/matlab.md, line for line in NumPy (1-based
    indices become 0-based): cell centres as thresholds, all relays -1 at the start."""
    n = int(S["n_h"].item())
    lo, hi = S["u_range"].ravel()
    offset = S["offset"].item()
    d = (hi - lo) / n
    thr = lo + (np.arange(1, n + 1) - 0.5) * d
    B, A = np.meshgrid(thr, thr, indexing="ij")  # ndgrid: beta down the rows, alpha across
    R = -np.ones((n, n))
    W = np.triu(S["weights"])
    y = np.zeros(u.size)
    for k in range(u.size):
        R[u[k] >= A] = 1
        R[u[k] < B] = -1
        y[k] = np.sum(W * R) + offset
    return y


@pytest.mark.parametrize("seed", range(4))
def test_exported_matrices_run_in_the_documented_matlab_loop_reproduce_predict(tmp_path, seed):
    from conftest import random_weights

    from preisach import PreisachModel

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 16))
    lo = float(rng.uniform(-5, 5))
    hi = lo + float(rng.uniform(0.1, 10))
    model = PreisachModel(random_weights(rng, n, zeros=0.3), (lo, hi), offset=float(rng.normal()))
    model.save(tmp_path / "m.json")
    assert main(["export-mat", str(tmp_path / "m.json"), "-o", str(tmp_path / "m.mat")]) == 0
    S = sio.loadmat(tmp_path / "m.mat")
    assert S["weights"].shape == (n, n) and S["levels"].shape == (1, n + 1)
    np.testing.assert_array_equal(S["weights"], model.weights)
    np.testing.assert_array_equal(S["levels"].ravel(), model.levels)
    assert S["u_range"].ravel().tolist() == [lo, hi] and S["offset"].item() == model.offset
    assert str(S["output"][0]) == "stepwise"
    u = np.concatenate([[lo - 1], rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), 300)])
    np.testing.assert_allclose(_relay_loop(S, u), model.predict(u), rtol=0, atol=1e-10)


def test_the_documented_matlab_loop_is_the_one_tested():
    from pathlib import Path

    doc = Path(__file__).resolve().parents[1] / "docs" / "guide" / "matlab.md"
    text = doc.read_text(encoding="utf-8")
    for line in ("thr = S.u_range(1) + ((1:n) - 0.5) * d;", "[B, A] = ndgrid(thr, thr);", "R = -ones(n);",
                 "R(u(k) >= A) = 1;", "R(u(k) < B) = -1;", "y(k) = sum(W(:) .* R(:)) + S.offset;"):
        assert line in text, line


def test_a_chain_exports_its_hysteresis_and_its_blocks(tmp_path, capsys):
    from conftest import smooth_weights

    from preisach import Chain, PreisachModel

    model = PreisachModel(smooth_weights(6), (0, 10), 0.5, "interpolated")
    chain = Chain(model, {"delay": {"delay_s": 2e-4}, "vibration": {"frequency_hz": 780.0, "damping": 0.02}})
    chain.save(tmp_path / "c.json")
    assert main(["export-mat", str(tmp_path / "c.json"), "-o", str(tmp_path / "c.mat")]) == 0
    out = capsys.readouterr().out
    assert "chain" in out and "delay" in out and "vibration" in out
    S = sio.loadmat(tmp_path / "c.mat", squeeze_me=True, struct_as_record=False)
    np.testing.assert_array_equal(S["weights"], model.weights)
    assert S["output"] == "interpolated"
    blocks = {b.type: b for b in S["chain"].blocks}
    assert blocks["delay"].delay_s == 2e-4 and blocks["vibration"].modes.frequency_hz == 780.0
    assert "hysteresis" not in blocks


def test_export_errors_are_one_line(tmp_path, capsys):
    (tmp_path / "bad.json").write_text("{")
    assert main(["export-mat", str(tmp_path / "bad.json"), "-o", str(tmp_path / "m.mat")]) == 1
    err = capsys.readouterr().err
    assert "bad.json" in err and "not JSON" in err
    assert main(["export-mat", str(tmp_path / "bad.json"), "-o", str(tmp_path / "no" / "m.mat")]) == 1
    assert capsys.readouterr().err.startswith("preisach: error: -o:")
    assert not (tmp_path / "m.mat").exists()


def test_export_without_scipy_is_one_clear_line_before_any_work(tmp_path):
    code = ("import sys; sys.modules['scipy'] = None; sys.modules['scipy.io'] = None\n"
            "from preisach.cli import main\n"
            f"raise SystemExit(main(['export-mat', {str(tmp_path / 'missing.json')!r}, '-o', "
            f"{str(tmp_path / 'm.mat')!r}]))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert r.stderr.strip() == "preisach: error: MAT files need SciPy: pip install 'preisach[mat]'"
    assert not list(tmp_path.iterdir())


# --- sizes checked before reading (preisach._matsize) ---------------------------------
def _tree(draw, depth):
    """A random MATLAB value: arrays of several classes, structs and cell arrays, nested."""
    from hypothesis import strategies as st

    kind = draw(st.sampled_from(["double", "uint8", "complex", "text", "struct", "cell"] if depth < 3
                                else ["double", "uint8", "text"]))
    if kind in ("double", "uint8", "complex"):
        shape = draw(st.sampled_from([(0,), (1,), (7,), (3, 4), (2, 3, 2), (40, 1)]))
        a = np.arange(int(np.prod(shape)), dtype=np.float64).reshape(shape)
        return a.astype(np.uint8) if kind == "uint8" else (a + 1j * a if kind == "complex" else a)
    if kind == "text":
        return draw(st.sampled_from(["", "x", "Pådrag", "Model Root/Plant/y"]))
    if kind == "struct":
        return {f"f{i}": _tree(draw, depth + 1) for i in range(draw(st.integers(0, 3)))}
    cell = np.empty((1, draw(st.integers(0, 3))), dtype=object)
    for i in range(cell.shape[1]):
        cell[0, i] = _tree(draw, depth + 1)
    return cell


def _values(x) -> int:
    """Numeric and char values in a tree (the walk's count, without its per-array cost)."""
    if isinstance(x, dict):
        return sum(_values(v) for v in x.values())
    if isinstance(x, np.ndarray) and x.dtype == object:
        return sum(_values(v) for v in x.ravel())
    return len(x) if isinstance(x, str) else int(np.asarray(x).size)


def test_the_size_walk_passes_files_scipy_writes_and_counts_their_nested_values(tmp_path):
    """scipy-written files (compressed or not, nested structs and cells) pass the walk and
    load; a budget below their values refuses them, naming the file and the variable."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from preisach._matsize import PER_ARRAY, MatSizeError, check_v5

    @settings(max_examples=40, deadline=None)
    @given(data=st.data(), compress=st.booleans())
    def check(data, compress):
        tree = {"v": _tree(data.draw, 0), "u_dac": U}
        p = tmp_path / "tree.mat"
        sio.savemat(p, tree, do_compression=compress)
        n = _values(tree["v"])
        with open(p, "rb") as f:  # at most 40 arrays in the tree
            check_v5(f, p.stat().st_size, max(n, U.size) + 40 * PER_ARRAY)
        assert any(c.name == "u_dac" for c in list_channels(p))
        with open(p, "rb") as f, pytest.raises(MatSizeError) as err:
            check_v5(f, p.stat().st_size, n - 1)
        assert err.value.variable == "v"

    check()


def test_a_complex_flag_without_its_imaginary_part_is_refused_not_a_crash(tmp_path):
    """Found by the fuzz campaign: SciPy reads the next variable's tag as the missing
    imaginary part and crashes (SIGSEGV); the walk refuses the file first."""
    import struct

    def el(kind: int, data: bytes) -> bytes:
        return struct.pack("<II", kind, len(data)) + data + b"\0" * (-len(data) % 8)

    def double(name: bytes, values: np.ndarray, flags: int) -> bytes:
        body = (el(6, struct.pack("<II", flags | 6, 0)) + el(5, struct.pack("<ii", 1, values.size)) + el(1, name)
                + el(9, values.astype("<f8").tobytes()))
        return struct.pack("<II", 14, len(body)) + body

    head = b"MATLAB 5.0 MAT-file".ljust(116, b" ") + b"\0" * 8 + struct.pack("<HH", 0x0100, 0x4D49)
    p = tmp_path / "complex.mat"
    p.write_bytes(head + double(b"t", T[:30], 0x800) + double(b"u_dac", U[:30], 0))
    with pytest.raises(ValueError, match=r"complex\.mat: variable t: "):
        list_channels(p)
    p.write_bytes(head + double(b"t", T[:30], 0) + double(b"u_dac", U[:30], 0))
    assert [c.name for c in list_channels(p)] == ["t", "u_dac"]  # the same file without the flag reads
