"""The continuous inverse of fitted models at the reference's turns, with and without the
diagonal floor of identification.

For each stage: record an identification sweep with noise, fit n_h = 100 twice (the
default ``diagonal_floor`` and ``diagonal_floor=0``), then

- count the excited diagonal masses that are zero;
- invert a smooth sine (two periods, 20,000 samples each, over 80 % of the reachable
  range) with the continuous inverse and report the largest input step over the
  reference's largest step times the average inverse slope (u_range span / output
  span), at the turns and elsewhere (turn = within 2 % of a period of a turn);
- score each fit on holdout records it never saw (RMSE, output units).

Stages: the ``paper`` preset with random delay, mode and noise seed (the demo's quick
identification sweep; holdouts: a 20 Hz sine and steps with dwell), and the
independent rig of ``tests/rig.py`` (class ``paper_mode_delay``, random parameters;
its own holdouts).

Usage: python benches/inverse_turns.py [--seeds N]
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

from preisach import PreisachModel, PreisachWarning
from preisach.demo import identification_input
from preisach.sim import Stage

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from machine import describe  # noqa: E402
from rig import make_case  # noqa: E402

SPP = 20_000  # samples per period of the test sine


def paper_stage(seed: int) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    rng = np.random.default_rng(seed)
    stage = Stage.preset("paper", delay=float(rng.uniform(2e-4, 6e-4)), seed=seed,
                         resonance_hz=float(rng.uniform(600, 1000)), damping=float(rng.uniform(0.01, 0.04)))

    def record(u: np.ndarray) -> np.ndarray:
        stage.reset()
        stage.run(np.zeros(10_000))
        return stage.run(u)  # type: ignore[no-any-return]

    u, n_sine = identification_input(quick=True)
    y = record(u)
    fs = 100e3
    t = np.arange(int(0.15 * fs)) / fs
    sine = 3.75 - 3.0 * np.cos(2 * np.pi * 20 * t)
    steps = np.repeat(rng.uniform(0.5, 7.0, 8), int(0.05 * fs))
    return u[:n_sine], y[:n_sine], [(sine, record(sine)), (steps, record(steps))]


def rig_stage(seed: int) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    case = make_case("paper_mode_delay", seed)
    return case["train"]["u"], case["train"]["y"], [(h["u"], h["y"]) for h in case["holdouts"]]


def turn_steps(m: PreisachModel) -> tuple[float, float]:
    """(turns, elsewhere): largest input step / (largest reference step x inverse slope)."""
    lo, hi = m.u_range
    y_lo, y_hi = float(m.predict([lo])[0]), float(m.predict([hi])[0])
    t = np.arange(2 * SPP) / SPP
    r = 0.5 * (y_lo + y_hi) - 0.4 * (y_hi - y_lo) * np.cos(2 * np.pi * t)
    du = np.abs(np.diff(m.invert(r, method="continuous")))
    scale = np.max(np.abs(np.diff(r))) * (hi - lo) / (y_hi - y_lo)
    near = np.zeros(du.size, dtype=bool)
    for k in (SPP // 2, SPP, 3 * SPP // 2):  # the sine's turns
        near[max(0, k - SPP // 50):k + SPP // 50] = True
    near[: SPP // 50] = True  # the start is a turn too
    return float(du[near].max() / scale), float(du[~near].max() / scale)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    a = ap.parse_args()
    print(describe())
    print()
    print("| stage | seed | fit | zero diagonal masses | input step at turns | elsewhere | holdout RMSE |")
    print("|---|---|---|---|---|---|---|")
    for name, make in (("paper + delay", paper_stage), ("rig (mode, delay)", rig_stage)):
        for seed in range(a.seeds):
            u, y, holdouts = make(seed)
            for label, floor in (("plain", 0.0), ("default floor", None)):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", PreisachWarning)
                    m = (PreisachModel.fit(u, y, 100) if floor is None
                         else PreisachModel.fit(u, y, 100, diagonal_floor=floor))
                zeros = int(np.sum(np.diag(m.weights) == 0))
                at, off = turn_steps(m)
                rmse = " / ".join(f"{np.sqrt(np.mean((hy - m.predict(hu)) ** 2)):.6g}" for hu, hy in holdouts)
                print(f"| {name} | {seed} | {label} | {zeros} | {at:.2f} | {off:.2f} | {rmse} |", flush=True)


if __name__ == "__main__":
    main()
