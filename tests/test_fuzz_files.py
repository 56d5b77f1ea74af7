"""Fuzz the file readers and every CLI command: model, chain and stage JSON with each
field removed, wrong types, deep nesting, huge arrays, duplicate keys, truncation and
garbage; CSV, .npz and MAT files truncated, corrupt or binary. Each ends in a value or a
clear error naming the file or the argument (tests/fuzzing.py: the contract); the CLI
exits 0, 1 or 2 with one line on stderr, never a traceback."""
from __future__ import annotations

import io
import json
import re
import uuid
import warnings
from contextlib import redirect_stderr, redirect_stdout
from pathlib import Path

import numpy as np
import pytest
from fuzzing import TALLY, corrupt_bytes, current_test, mutated_json, outcome, sweep, watchdog
from hypothesis import given
from hypothesis import strategies as st

import preisach
from preisach.cli import build_parser, main
from preisach.sim import Stage

pytestmark = pytest.mark.filterwarnings("ignore::preisach.PreisachWarning")

DATA = Path(__file__).parent / "data" / "v1"
GOLDEN = sorted(p.name for p in DATA.glob("*.json"))


def _docs() -> dict[str, object]:
    u = sweep(2000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", preisach.PreisachWarning)
        model = preisach.PreisachModel.fit(u, 0.3 * u + np.tanh(u - 5.0), n_h=6, u_range=(0.0, 10.0))
    docs: dict[str, object] = {name: json.loads((DATA / name).read_text()) for name in GOLDEN}
    docs["model_v2"] = model.to_dict()
    docs["chain_v2"] = preisach.Chain(model, {"delay": {"delay_s": 1e-3}, "lowpass": {"cutoff_hz": 300.0,
                                                                                       "order": 2}}).to_dict()
    docs["stage_v2"] = Stage.preset("paper").to_dict()
    return docs


DOCS = _docs()


#: What an error about a chain, model or stage file may name.
JSON_NAMES = ["chain", "corrupt", "text", "blocks", "model", "weights", "sample_rate_hz", "initial_input"]


def scratch(tmp: Path, suffix: str, data: bytes) -> Path:
    """A fresh file under ``tmp`` (hypothesis reuses the function-scoped tmp_path)."""
    p = tmp / f"{uuid.uuid4().hex}{suffix}"
    p.write_bytes(data)
    return p


@given(name=st.sampled_from(sorted(DOCS)), data=st.data())
def test_chain_json_mutations(tmp_path, name, data):
    text = data.draw(mutated_json(DOCS[name]))
    for load in (preisach.Chain.from_json, Stage.from_json):
        got = outcome(lambda: load(text), JSON_NAMES)
        if isinstance(got, preisach.Chain):
            json.loads(got.to_json())  # what loads is written back as valid JSON
    p = scratch(tmp_path, ".json", text.encode("utf-8", "surrogatepass"))
    outcome(lambda: preisach.load(p), [str(p)])
    outcome(lambda: preisach.PreisachModel.load(p), [str(p)])


@given(name=st.sampled_from(sorted(DOCS)), data=st.data())
def test_chain_dict_mutations(name, data):
    d = data.draw(st.builds(json.loads, mutated_json(DOCS[name]).filter(_parses)))
    outcome(lambda: preisach.Chain.from_dict(d), JSON_NAMES)
    outcome(lambda: preisach.PreisachModel.from_dict(d), JSON_NAMES)


def _parses(text: str) -> bool:
    try:
        json.loads(text)
    except (ValueError, RecursionError):
        return False
    return True


@given(data=st.data(), name=st.sampled_from(sorted(DOCS)))
def test_blocks_and_effects_mutations(data, name):
    """Chain.from_blocks, Stage(...) and Chain(model, effects) on mutated block lists."""
    doc = DOCS[name]
    blocks = doc.get("blocks", []) if isinstance(doc, dict) else []
    mutated = data.draw(st.builds(json.loads, mutated_json(blocks).filter(_parses)))
    names = ["blocks", "chain", "corrupt", "sample_rate_hz", "effects"]
    outcome(lambda: preisach.Chain.from_blocks(mutated), names)
    outcome(lambda: Stage(mutated), names)
    outcome(lambda: preisach.Chain(None, mutated), names)


def _csv(cols: dict[str, np.ndarray]) -> bytes:
    out = io.StringIO()
    names = list(cols)
    out.write(",".join(names) + "\n")
    for row in zip(*cols.values()):
        out.write(",".join(repr(float(x)) for x in row) + "\n")
    return out.getvalue().encode()


GOOD_CSV = _csv({"t": np.arange(40) / 1e3, "u": sweep(40), "y": np.cos(np.arange(40))})
#: A repeat of the same experiment (another output): the diagnosis refuses a holdout that is the training record.
GOOD_REPEAT_CSV = _csv({"t": np.arange(40) / 1e3, "u": sweep(40), "y": np.cos(np.arange(40)) + 0.01})


@given(data=st.data())
def test_read_record_corrupt_csv(tmp_path, data):
    p = scratch(tmp_path, ".csv", data.draw(corrupt_bytes(GOOD_CSV)))
    got = outcome(lambda: preisach.read_record(p), [str(p)])
    if isinstance(got, dict):
        assert {"t", "u", "y"} <= set(got) and all(v.dtype == np.float64 for v in got.values())


@given(data=st.data())
def test_read_record_corrupt_npz(tmp_path, data):
    buf = io.BytesIO()
    np.savez(buf, t=np.arange(30) / 1e3, u=sweep(30), y=np.zeros(30))
    p = scratch(tmp_path, ".npz", data.draw(corrupt_bytes(buf.getvalue())))
    outcome(lambda: preisach.read_record(p), [str(p)])


def _mat_bytes(compressed: bool) -> bytes:
    import scipy.io

    buf = io.BytesIO()
    scipy.io.savemat(buf, {"t": np.arange(30) / 1e3, "u_dac": sweep(30), "y_sensor": np.zeros(30)},
                     do_compression=compressed)
    return buf.getvalue()


@given(data=st.data(), compressed=st.booleans())
def test_mat_corrupt(tmp_path, data, compressed):
    pytest.importorskip("scipy")
    from preisach.matlab import list_channels, read_mat

    p = scratch(tmp_path, ".mat", data.draw(corrupt_bytes(_mat_bytes(compressed))))
    outcome(lambda: list_channels(p), [str(p)])
    outcome(lambda: read_mat(p, u="u_dac", y="y_sensor", t="t"), [str(p), "u", "y", "t", "--u", "--y", "--t"])


# --- the command line ------------------------------------------------------------------
def commands() -> list[str]:
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    return sorted(sub.choices)  # type: ignore[union-attr]


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with watchdog(), redirect_stdout(out), redirect_stderr(err):
        code = main(argv)
    TALLY[current_test(), "returned" if code == 0 else "refused"] += 1
    return code, out.getvalue(), err.getvalue()


ARG = st.one_of(st.sampled_from(["--n-h", "-o", "--range", "--method", "--lookahead", "--holdout", "--json", "--u",
                                 "--y", "--t", "--fs", "--list", "--preset", "--reg", "--solver", "--quick", "-1e3",
                                 "nan", "inf", "0", "-1", "99999999999999999999", "1e308", "", "paper", "x=y"]),
                st.text(max_size=12))


@given(cmd=st.sampled_from(commands()), args=st.lists(ARG, max_size=6))
def test_cli_random_arguments(tmp_path, monkeypatch, cmd, args):
    """Random flags and values: exit 1 or 2 with one line on stderr (or 0), never a
    traceback. A demo or diagnose that would really run is not started (slow)."""
    if cmd in ("demo", "diagnose") and "--help" not in args:
        args = args + ["--holdout"] if cmd == "diagnose" else args + ["--out", "/dev/null/x"]
    monkeypatch.chdir(tmp_path)
    code, _, err = run_cli([cmd, *args])
    assert code in (0, 1, 2), (code, err)
    if code:
        assert err.count("\n") == 1 and "Traceback" not in err and err.startswith(("error:", "preisach: error:")), err


@given(data=st.data(), name=st.sampled_from(sorted(DOCS)),
       cmd=st.sampled_from(["predict", "compare", "invert", "simulate", "export-mat", "diagnose-baseline"]))
def test_cli_on_mutated_model_files(tmp_path, data, name, cmd):
    p = scratch(tmp_path, ".json", data.draw(mutated_json(DOCS[name])).encode("utf-8", "surrogatepass"))
    rec = scratch(tmp_path, ".csv", GOOD_CSV)
    hold = scratch(tmp_path, ".csv", GOOD_REPEAT_CSV)
    ref = scratch(tmp_path, ".csv", _csv({"t": np.arange(20) / 1e3, "r": np.linspace(0.0, 2.0, 20)}))
    out = str(tmp_path / "out.x")
    argv = {"predict": ["predict", str(p), str(rec), "-o", out], "compare": ["compare", str(p), str(rec)],
            "invert": ["invert", str(p), str(ref), "-o", out], "simulate": ["simulate", str(p), str(rec), "-o", out],
            "export-mat": ["export-mat", str(p), "-o", out],
            "diagnose-baseline": ["diagnose", str(rec), "--holdout", str(hold), "--baseline", str(p), "--json", out,
                                  "--n-h", "4"]}[cmd]
    code, _, err = run_cli(argv)
    assert code in (0, 1), (code, err)
    if code:
        last = err.strip().splitlines()[-1]
        # A chain the file describes well but that has no inverse is refused naming its block.
        named = str(p) in last or (cmd == "simulate" and "the run's rate" in last) or \
            (cmd == "invert" and re.search(r"^preisach: error: blocks\[\d+\] \(\w+\): cannot be inverted", last))
        assert "Traceback" not in err and last.startswith("preisach: error: ") and named, err


@given(data=st.data(), cmd=st.sampled_from(["identify", "predict", "compare", "invert", "simulate", "diagnose"]))
def test_cli_on_corrupt_records(tmp_path, data, cmd):
    rec = scratch(tmp_path, ".csv", data.draw(corrupt_bytes(GOOD_CSV)))
    good = scratch(tmp_path, ".csv", GOOD_CSV)
    model = scratch(tmp_path, ".json", json.dumps(DOCS["model_v2"]).encode())
    out = str(tmp_path / "out.x")
    argv = {"identify": ["identify", str(rec), "--n-h", "5", "-o", out],
            "predict": ["predict", str(model), str(rec), "-o", out], "compare": ["compare", str(model), str(rec)],
            "invert": ["invert", str(model), str(rec), "-o", out],
            "simulate": ["simulate", "--preset", "paper", str(rec), "-o", out],
            "diagnose": ["diagnose", str(good), "--holdout", str(rec), "--json", out, "--n-h", "4"]}[cmd]
    if cmd == "diagnose":
        argv[1], argv[3] = argv[3], argv[1]  # the corrupt one as the training record
    code, _, err = run_cli(argv)
    assert code in (0, 1), (code, err)
    if code:
        last = err.strip().splitlines()[-1]
        named = str(rec) in last
        assert "Traceback" not in err and last.startswith("preisach: error: ") and named, err


@given(data=st.data(), compressed=st.booleans(),
       args=st.sampled_from([["--list"], ["--u", "u_dac", "--y", "y_sensor", "--t", "t"], ["--u", "0", "--fs", "1e3"],
                             ["--u", "u_dac", "--fs", "nan"], ["--u", "9", "--fs", "-5"]]))
def test_cli_import_mat_corrupt(tmp_path, data, compressed, args):
    pytest.importorskip("scipy")
    p = scratch(tmp_path, ".mat", data.draw(corrupt_bytes(_mat_bytes(compressed))))
    out = [] if "--list" in args else ["-o", str(tmp_path / "o.csv")]
    code, _, err = run_cli(["import-mat", str(p), *args, *out])
    assert code in (0, 1, 2), (code, err)
    if code:
        assert err.count("\n") == 1 and "Traceback" not in err, err
