"""Faults: a process killed (SIGKILL) while writing a model, a chain, a CSV or JSON leaves
the old file or the new one, never a torn one; the write helper flushes the data to disk
before the rename; Ctrl-C during ``preisach diagnose`` or ``preisach demo`` exits with
one line, code 130, no traceback and no output files, and starts no queued fit; inputs are never modified (a
property over every function that takes arrays, with read-only inputs)."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from fuzzing import sweep
from hypothesis import given
from hypothesis import strategies as st

import preisach
from preisach import io as pio
from preisach.sim import Stage, run_loop

pytestmark = pytest.mark.filterwarnings("ignore::preisach.PreisachWarning")

# --- SIGKILL while writing ---------------------------------------------------------------
WRITER = textwrap.dedent("""
    import sys, numpy as np, preisach
    from preisach.io import write_csv, write_text
    kind, path = sys.argv[1], sys.argv[2]
    n = 40 if kind == "model" else 200_000
    versions = []
    for v in (1.0, 2.0):
        w = np.triu(np.full((n, n), v * 1e-3)) if kind == "model" else None
        versions.append(w)
    print("ready", flush=True)
    k = 0
    while True:
        v = 1.0 + k % 2
        if kind == "model":
            preisach.PreisachModel(versions[k % 2], (0.0, 10.0), offset=v).save(path)
        elif kind == "chain":
            preisach.Chain.from_blocks([{"type": "delay", "delay_s": v * 1e-3}] * 5000).save(path)
        elif kind == "csv":
            write_csv(path, {"t": np.arange(n) * v, "u": np.full(n, v)})
        else:
            write_text(path, '{"v": %r, "pad": "%s"}' % (v, "x" * 3_000_000))
        k += 1
""")


def _check_whole(kind: str, path: Path) -> float:
    """The file's version (1 or 2), reading it whole: a torn file fails here."""
    if kind == "model":
        return preisach.PreisachModel.load(path).offset
    if kind == "chain":
        c = preisach.Chain.load(path)
        assert len(c.blocks) == 5000
        return c.blocks[0]["delay_s"] * 1e3
    if kind == "csv":
        rec = preisach.read_record(path, ["t", "u"])
        assert rec["u"].size == 200_000 and np.all(rec["u"] == rec["u"][0])
        return float(rec["u"][0])
    d = json.loads(path.read_text())
    assert len(d["pad"]) == 3_000_000
    return float(d["v"])


@pytest.mark.parametrize("kind", ["model", "chain", "csv", "json"])
def test_a_process_killed_while_writing_leaves_the_old_or_the_new_file(tmp_path, kind):
    path = tmp_path / f"out.{kind}"
    rng = np.random.default_rng(1)
    seen = set()
    for _ in range(int(os.environ.get("FUZZ_KILLS", "8"))):
        with subprocess.Popen([sys.executable, "-c", WRITER, kind, str(path)], stdout=subprocess.PIPE, text=True) as p:
            assert p.stdout is not None and p.stdout.readline().strip() == "ready"
            deadline = time.monotonic() + 60
            while not path.exists() and time.monotonic() < deadline:
                time.sleep(0.01)
            time.sleep(float(rng.uniform(0.0, 0.4)))  # somewhere inside a write, most of the time
            p.send_signal(signal.SIGKILL)
            p.wait()
        seen.add(_check_whole(kind, path))
    assert seen <= {1.0, 2.0}
    # A kill can leave a stray temporary file beside the output, never at its name.
    assert all(q.name.startswith(".out.") and q.name.endswith(".tmp") for q in tmp_path.iterdir() if q != path)


def test_the_write_helper_syncs_before_it_renames(tmp_path, monkeypatch):
    events: list[tuple[str, str]] = []
    real_fsync, real_replace = os.fsync, os.replace

    def fsync(fd: int) -> None:
        events.append(("fsync", os.readlink(f"/proc/self/fd/{fd}")))
        real_fsync(fd)

    def replace(a: str, b: str) -> None:
        events.append(("replace", str(a)))
        real_replace(a, b)

    monkeypatch.setattr(pio.os, "fsync", fsync)
    monkeypatch.setattr(pio.os, "replace", replace)
    pio.write_text(tmp_path / "a.txt", "hello")
    kinds = [e[0] for e in events]
    assert kinds == ["fsync", "replace", "fsync"]
    assert events[0][1] == events[1][1]  # the temporary file itself, before its rename
    assert events[2][1] == str(tmp_path)  # then the directory entry
    assert (tmp_path / "a.txt").read_text() == "hello"


# --- Ctrl-C ------------------------------------------------------------------------------
def _interrupt(argv: list[str], cwd: Path, after: str) -> subprocess.CompletedProcess[str]:
    """Run ``python -m preisach ARGV``, send SIGINT once ``after`` shows on stderr."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", MPLBACKEND="Agg")
    with subprocess.Popen([sys.executable, "-m", "preisach", *argv], cwd=cwd, stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True, env=env) as p:
        assert p.stderr is not None
        err = []
        for line in p.stderr:
            err.append(line)
            if after in line:
                break
        time.sleep(0.3)
        p.send_signal(signal.SIGINT)
        out, rest = p.communicate(timeout=120)
    return subprocess.CompletedProcess(argv, p.returncode, out, "".join(err) + rest)


def _records(tmp: Path) -> tuple[Path, Path]:
    st = Stage.preset("paper", seed=2)
    u = 3.75 + 3.5 * np.linspace(0.1, 1.0, 20_000) * np.sin(2 * np.pi * 10 * np.arange(20_000) / 1e4)
    t = np.arange(u.size) / 1e4
    pio.write_csv(tmp / "train.csv", {"t": t, "u": u, "y": st.predict(t, u)})
    v = 3.75 + 3.0 * np.sin(2 * np.pi * 20 * t[:5000])
    pio.write_csv(tmp / "hold.csv", {"t": t[:5000], "u": v, "y": st.predict(t[:5000], v)})
    return tmp / "train.csv", tmp / "hold.csv"


@pytest.mark.parametrize("command", ["diagnose", "demo"])
def test_ctrl_c_exits_with_one_line_and_no_output_files(tmp_path, command):
    if command == "demo":
        argv, after = ["demo", "--quick", "--no-plots", "--out", "out"], "identifying"
    else:
        train, hold = _records(tmp_path)
        argv = ["diagnose", str(train), "--holdout", str(hold), "--json", "out/report.json", "--save-model",
                "out/aug.json", "--n-h", "20"]
        (tmp_path / "out").mkdir()
        after = "baseline"
    before = sorted(p.name for p in tmp_path.rglob("*"))
    res = _interrupt(argv, tmp_path, after)
    assert res.returncode == 130, res.stderr
    assert "Traceback" not in res.stderr
    assert res.stderr.strip().splitlines()[-1] == "preisach: interrupted"
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # nothing new, no stray temporaries


def test_ctrl_c_while_writing_removes_the_files_written(tmp_path, monkeypatch, capsys):
    """An interrupt that lands between two output files: the first is removed too."""
    from preisach import cli

    train, hold = _records(tmp_path)
    calls = []
    real = pio.write_text

    def write_then_interrupt(path, text):
        calls.append(path)
        if len(calls) == 2:
            raise KeyboardInterrupt
        real(path, text)

    monkeypatch.setattr(pio, "write_text", write_then_interrupt)
    monkeypatch.setattr(preisach.chain, "write_text", write_then_interrupt)
    out = tmp_path / "new"
    argv = ["diagnose", str(train), "--holdout", str(hold), "--json", str(out / "r.json"), "--save-model",
            str(tmp_path / "aug.json"), "--n-h", "10"]
    out.mkdir()
    assert cli.main(argv) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == "preisach: interrupted"
    assert not (out / "r.json").exists() and not (tmp_path / "aug.json").exists() and len(calls) == 2


def test_ctrl_c_in_the_candidate_fits_starts_nothing_new(tmp_path, monkeypatch):
    """Ctrl-C while candidate fits and their trials run in threads: the queued fits are
    dropped and no solve starts once the interrupt is handled; only those already in the
    core finish. Counted, not timed: the rest of an uninterrupted candidate round is
    hundreds of solves. (Counted from the handling, ``Trials.cancel``: until Python runs
    the main thread's handler, which on a busy machine can take several of these small
    solves, the threads go on as they would without a Ctrl-C.)"""
    from preisach import _preisach
    from preisach.diagnose import diagnose
    from preisach.diagnose.search import Trials

    module = sys.modules["preisach.diagnose"]  # (preisach.diagnose is also the function)
    train, hold = _records(tmp_path)
    real, main, lock = _preisach.Behind, threading.main_thread().ident, threading.Lock()
    count = {"solves": 0, "at_interrupt": -1, "at_cancel": -1, "candidates": False}
    real_cancel = Trials.cancel

    def cancel(self: Trials) -> None:
        with lock:
            if count["at_cancel"] < 0:
                count["at_cancel"] = count["solves"]
        real_cancel(self)

    class Counting:
        """A fit session that counts its solves, and sends SIGINT to the main thread at
        the 40th solve of the candidate round (a Ctrl-C)."""

        def __init__(self, *args: object, session: object = None, **kw: object) -> None:
            self.session = session if session is not None else real(*args, **kw)

        def share(self, other: "Counting") -> None:
            self.session.share(other.session)

        def fork(self) -> "Counting":
            return Counting(session=self.session.fork())

        def solve(self, *args: object, **kw: object) -> object:
            with lock:
                count["solves"] += 1
                if count["candidates"] and count["at_interrupt"] < 0 and count["solves"] >= count["start"] + 40:
                    count["at_interrupt"] = count["solves"]
                    signal.pthread_kill(main, signal.SIGINT)
            return self.session.solve(*args, **kw)

    real_say = module._say

    def say(show: bool, msg: str) -> None:  # the candidate round follows the "where: ..." line
        if "where:" in msg:
            with lock:
                if not count["candidates"]:
                    count["candidates"], count["start"] = True, count["solves"]
        real_say(show, msg)

    monkeypatch.setattr(_preisach, "Behind", Counting)
    monkeypatch.setattr(module, "_say", say)
    monkeypatch.setattr(Trials, "cancel", cancel)
    with pytest.raises(KeyboardInterrupt):
        diagnose(str(train), [str(hold)], n_h=10, workers=2, progress=False)
    for t in threading.enumerate():  # the pools' threads end once their solve in the core ends
        if t is not threading.current_thread() and t.name.startswith(("preisach-trial", "ThreadPoolExecutor")):
            t.join(300)
            assert not t.is_alive()
    assert count["at_interrupt"] > 0, "the diagnosis ended before the interrupt"
    assert count["at_cancel"] >= count["at_interrupt"], "the interrupt did not cancel the trials"
    # Started after the interrupt was handled: at most the solves the other threads had
    # begun (two candidates, two trials, and the finer hysteresis alone, fitted beside the
    # round).
    assert count["solves"] - count["at_cancel"] <= 5, count


# --- inputs are never modified -------------------------------------------------------------
def _frozen(x: np.ndarray) -> np.ndarray:
    a = np.array(x, dtype=np.float64)
    a.flags.writeable = False
    return a


@given(n=st.integers(2, 300), seed=st.integers(0, 2**32 - 1), n_h=st.integers(1, 15))
def test_inputs_are_never_modified(n, seed, n_h):
    """Every function that takes arrays gets read-only ones (a write would raise) and
    copies to compare with afterwards."""
    rng = np.random.default_rng(seed)
    u = _frozen(sweep(n) + 0.1 * rng.standard_normal(n))
    y = _frozen(0.3 * u + np.tanh(u - 5.0) + 0.01 * rng.standard_normal(n))
    t = _frozen(np.arange(n) / 1e5)
    w = _frozen(np.triu(rng.random((n_h, n_h))))
    keep = {k: v.copy() for k, v in dict(u=u, y=y, t=t, w=w).items()}
    model = preisach.PreisachModel(w, (0.0, 10.0))
    fitted = preisach.PreisachModel.fit(u, y, n_h)
    r = _frozen(fitted.predict(u))
    keep["r"] = r.copy()
    stage = Stage.preset("paper", noise_std=0.0)
    model.predict(u, return_state=True)
    state = _frozen(model.predict(u, return_state=True)[1])
    keep["state"] = state.copy()
    model.predict(u, state)
    model.stream(state).process(u)
    for method, la in (("closest", None), ("interpolated", 5), ("continuous", None)):
        fitted.invert(r, method=method, lookahead=la)
        fitted.inverter(method=method, lookahead=la).process(r)
    stage.predict(t, u)
    stage.simulate(t, u)
    stage.copy().run(u)
    run_loop(fitted, stage.copy(), r, method="continuous")
    preisach.compare(fitted, {"t": t, "u": u, "y": y})
    preisach.fit_percent(y, r)
    preisach.chain.sample_period(t)
    with tempfile.TemporaryDirectory() as d:
        pio.write_csv(Path(d) / "r.csv", {"t": t, "u": u})
    for k, v in dict(u=u, y=y, t=t, w=w, r=r, state=state).items():
        assert np.array_equal(v, keep[k]), k
