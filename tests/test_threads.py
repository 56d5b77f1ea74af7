"""Threads: fits, predictions, inversions and simulations run in parallel Python threads
give exactly the serial results; long calls release the GIL (a second thread makes
progress while one runs); one stream, inverter or stage shared between threads is
refused with a clear error while another thread is inside it, never a panic.

Records come from two independent sources: the project's simulator (``Stage.preset``
with random parameters) and the independent rig of tests/rig.py."""
from __future__ import annotations

import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import rig

import preisach
from preisach.sim import Stage, run_loop

pytestmark = pytest.mark.filterwarnings("ignore::preisach.PreisachWarning")

FS = 10e3


def _records(seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(2):  # the project's simulator, random parameters
        st = Stage.preset("paper", seed=int(rng.integers(1 << 30)), resonance_hz=float(rng.uniform(500, 1500)),
                          noise_std=float(rng.uniform(0.0, 1e-3)))
        u = 3.75 + 3.5 * np.linspace(0.1, 1.0, 6000) * np.sin(2 * np.pi * (30 + 10 * k) * np.arange(6000) / 1e5)
        out.append((u, st.simulate(np.arange(u.size) / 1e5, u)))  # at the stage's own 100 kHz
    for _ in range(2):  # the independent rig
        r = rig.draw_rig(rng, ("creep",), FS)
        u = rig.wf_identification(FS, f=20.0, periods=12)
        out.append((u, r.record(u, FS)["y"]))
    return out


@pytest.fixture(scope="module")
def records() -> list[tuple[np.ndarray, np.ndarray]]:
    return _records(7)


def _fit(rec: tuple[np.ndarray, np.ndarray]) -> preisach.PreisachModel:
    u, y = rec
    return preisach.PreisachModel.fit(u, y, n_h=30, output="interpolated")


def _same_model(a: preisach.PreisachModel, b: preisach.PreisachModel) -> bool:
    return np.array_equal(a.weights, b.weights) and a.offset == b.offset and a.u_range == b.u_range


def test_parallel_fits_predictions_and_inversions_equal_serial(records):
    jobs = records * 2  # more jobs than workers, each record twice
    serial = [_fit(r) for r in jobs]
    with ThreadPoolExecutor(max_workers=4) as ex:
        parallel = list(ex.map(_fit, jobs))
    assert all(_same_model(a, b) for a, b in zip(serial, parallel))

    def use(k: int) -> list[np.ndarray]:
        m, (u, y) = serial[k], jobs[k]
        inv = m.inverter(method="continuous")
        return [m.predict(u), m.predict(u, output="stepwise"), m.invert(y, method="closest"),
                m.invert(y, method="continuous"), m.invert(y, method="interpolated", lookahead=50),
                inv.process(y), m.stream().process(u)]

    want = [use(k) for k in range(len(jobs))]
    with ThreadPoolExecutor(max_workers=4) as ex:
        got = list(ex.map(use, range(len(jobs))))
    for w, g in zip(want, got):
        assert all(np.array_equal(a, b) for a, b in zip(w, g))


def test_parallel_simulations_and_loops_equal_serial(records):
    model = _fit(records[0])
    stage = Stage.preset("paper", seed=3)
    u = records[0][0][:3000]
    t = np.arange(u.size) / 1e5
    ref = model.predict(u)

    def job(k: int) -> list[np.ndarray]:
        if k % 3 == 0:
            return [stage.simulate(t, u), stage.predict(t, u)]  # one shared stage: read-only calls
        own = stage.copy()
        return [own.run(u), run_loop(model, own, ref, method="continuous").y]

    want = [job(k) for k in range(6)]
    with ThreadPoolExecutor(max_workers=3) as ex:
        got = list(ex.map(job, range(6)))
    for w, g in zip(want, got):
        assert all(np.array_equal(a, b) for a, b in zip(w, g))


def _progress_during(call) -> int:
    """Run ``call()`` in this thread while a second thread counts; return how many of the
    counter's checkpoints fall strictly inside the call, away from its ends by more
    than a few switch intervals (with the GIL held throughout, none can)."""
    stamps: list[float] = []
    stop = threading.Event()

    def count() -> None:
        n = 0
        while not stop.is_set():
            n += 1
            if n % 200 == 0:
                stamps.append(time.perf_counter())

    th = threading.Thread(target=count)
    th.start()
    time.sleep(0.05)
    t0 = time.perf_counter()
    call()
    t1 = time.perf_counter()
    stop.set()
    th.join()
    margin = 3 * sys.getswitchinterval()  # a thread waiting for the GIL gets it within one interval
    assert t1 - t0 > 4 * margin, "the call was too short to tell"
    return sum(t0 + margin < s < t1 - margin for s in stamps)


def test_long_calls_release_the_gil():
    n = 8_000_000
    k = np.arange(n)
    u = 5.0 + 4.5 * np.sin(2 * np.pi * k / 5000) * np.sin(2 * np.pi * k / 997_000)
    model = preisach.PreisachModel(np.triu(np.full((200, 200), 1e-3)), (0.0, 10.0))
    y = model.predict(u[:400_000])
    stage = Stage.preset("paper")
    t = np.arange(n // 4) / 1e5
    calls = {
        "predict": lambda: model.predict(u, output="interpolated"),
        "invert": lambda: model.invert(np.concatenate([y] * 10), method="continuous"),
        "fit": lambda: preisach.PreisachModel.fit(u[:400_000], y, n_h=120),
        "simulate": lambda: stage.simulate(t, u[: n // 4]),
    }
    for name, call in calls.items():
        assert _progress_during(call) > 0, f"{name} holds the GIL"


def _clash(first, second) -> list[BaseException]:
    """Start ``first()`` in a thread and call ``second()`` here while it runs; return the
    errors ``second`` raised (retrying until the first is seen running)."""
    errors: list[BaseException] = []
    done = threading.Event()

    def run_first() -> None:
        try:
            first()
        finally:
            done.set()

    th = threading.Thread(target=run_first)
    th.start()
    while not done.is_set():
        try:
            second()
        except BaseException as exc:  # noqa: BLE001 - a PanicException must be seen too
            errors.append(exc)
            break
    th.join()
    return errors


def test_a_shared_stream_inverter_or_stage_is_refused_with_a_clear_error():
    model = preisach.PreisachModel(np.triu(np.full((50, 50), 1e-3)), (0.0, 10.0))
    u = 5.0 + 4.5 * np.sin(np.arange(6_000_000) / 3000.0)
    r = model.predict(u[:2_000_000])
    stream, inverter, stage = model.stream(), model.inverter(method="continuous"), Stage.preset("paper")
    for name, long, short in (
        ("Stream", lambda: stream.process(u), lambda: stream.step(1.0)),
        ("Inverter", lambda: inverter.process(r), lambda: inverter.step(1.0)),
        ("Stage", lambda: stage.run(u[:1_000_000]), lambda: stage.step(1.0)),
    ):
        errors = _clash(long, short)
        assert len(errors) == 1, f"{name}: a second thread was not refused"
        exc = errors[0]
        assert type(exc) is RuntimeError, f"{name}: {type(exc).__name__}: {exc}"
        assert str(exc).startswith(f"{name}: in use by another thread"), str(exc)
    # After the clash each still works and is consistent.
    assert np.isfinite(stream.step(2.0)) and np.isfinite(inverter.step(0.1)) and np.isfinite(stage.step(1.0))


def test_a_shared_model_is_safe():
    """A model is immutable: any number of threads may run it at once."""
    model = preisach.PreisachModel(np.triu(np.full((40, 40), 1e-2)), (0.0, 10.0))
    u = 5.0 + 4.5 * np.sin(np.arange(200_000) / 300.0)
    want = model.predict(u)
    with ThreadPoolExecutor(max_workers=4) as ex:
        got = list(ex.map(lambda _: model.predict(u), range(8)))
    assert all(np.array_equal(want, g) for g in got)
