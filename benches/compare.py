"""Side-by-side ratios against the plain NumPy / SciPy way, measured in one run.

    python benches/compare.py            # prints a Markdown table

The machine is small and noisy: every figure is the median of repeated runs, and the
claims are ratios measured back to back in the same process.
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
import warnings

import numpy as np

from preisach import PreisachModel, _preisach

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from machine import describe  # noqa: E402

warnings.simplefilter("ignore")


def median_time(f, repeat: int = 5) -> float:
    ts = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def smooth_weights(n: int) -> np.ndarray:
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    c = (j - i) / n
    m = (i + j) / (2 * n) - 0.5
    return np.triu(np.exp(-((c - 0.15) ** 2) / 0.02 - m**2 / 0.1) + 2.0 * (i == j)) / n


def record_40() -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """The n_h = 40 identification record: input, output and model range."""
    u = sweep(200_000, n_rev=100, noise=0.02, seed=2)
    y = PreisachModel(smooth_weights(40), (0, 100)).predict(u) + np.random.default_rng(3).normal(0, 0.01, u.size)
    return u, y, (float(u.min()) + 0.005 * np.ptp(u), float(u.max()) - 0.005 * np.ptp(u))


def sweep(n: int, n_rev: int = 100, noise: float = 0.0, seed: int = 0) -> np.ndarray:
    t = np.linspace(0, 1, n)
    u = 50 + 53 * np.linspace(0.02, 1, n) * np.sin(np.pi * n_rev * t)
    return u + noise * np.random.default_rng(seed).normal(size=n)


def numpy_relay_grid(w: np.ndarray, lo: float, hi: float, u: np.ndarray) -> np.ndarray:
    """The plain way: every relay explicit, one vectorized update per sample."""
    n = w.shape[0]
    thr = lo + (np.arange(n) + 0.5) * (hi - lo) / n
    iu = np.triu_indices(n)
    beta, alpha, ww = thr[iu[0]], thr[iu[1]], w[iu]
    R = -np.ones(ww.size)
    out = np.empty(u.size)
    for k, x in enumerate(u):
        R = np.where(x >= alpha, 1.0, np.where(x < beta, -1.0, R))
        out[k] = ww @ R
    return out


def numpy_closest_match(w: np.ndarray, lo: float, hi: float, r: np.ndarray) -> np.ndarray:
    """Brute force: every candidate level's relay state evaluated, vectorized over levels."""
    n = w.shape[0]
    thr = lo + (np.arange(n) + 0.5) * (hi - lo) / n
    lv = lo + (hi - lo) * np.arange(n + 1) / n
    iu = np.triu_indices(n)
    beta, alpha, ww = thr[iu[0]], thr[iu[1]], w[iu]
    up = lv[:, None] >= alpha[None, :]
    down = lv[:, None] < beta[None, :]
    R = -np.ones(ww.size)
    out = np.empty(r.size)
    for k, x in enumerate(r):
        cand = np.where(up, 1.0, np.where(down, -1.0, R[None, :]))
        y = cand @ ww
        best = int(np.argmin(np.abs(y - x)))
        R = cand[best]
        out[k] = lv[best]
    return out


def main() -> None:
    rows: list[tuple[str, str, str, str]] = []

    # --- forward at n_h = 100 and 1000 -------------------------------------------------
    u = sweep(1_000_000, noise=0.05)
    fw = {}
    for n in (100, 1000):
        m = PreisachModel(smooth_weights(n), (0.0, 100.0))
        fw[n] = median_time(lambda: m.predict(u)) / u.size
    m100 = PreisachModel(smooth_weights(100), (0.0, 100.0))
    small = u[::500][:2000]
    t_np = median_time(lambda: numpy_relay_grid(m100.weights, 0.0, 100.0, small), repeat=3) / small.size
    np.testing.assert_allclose(numpy_relay_grid(m100.weights, 0.0, 100.0, small[:300]),
                               m100.predict(small[:300]) - m100.offset, atol=1e-9)
    rows.append(("forward, n_h = 100 (batch `predict`)", f"{fw[100] * 1e9:.1f} ns/sample",
                 f"NumPy relay grid {t_np * 1e9:,.0f} ns/sample", f"{t_np / fw[100]:,.0f}x faster"))
    rows.append(("forward, n_h = 1000 vs n_h = 100", f"{fw[1000] * 1e9:.1f} ns/sample", "",
                 f"{fw[1000] / fw[100]:.2f}x the n_h = 100 cost"))

    # --- identification at n_h = 100 from 10^6 samples (own process: peak memory) ----
    code = (
        "import resource, time, json, warnings, numpy as np, sys\n"
        "sys.path.insert(0, %r)\n"
        "from compare import smooth_weights, sweep\n"
        "from preisach import PreisachModel\n"
        "warnings.simplefilter('ignore')\n"
        "u = sweep(1_000_000, noise=0.02)\n"
        "y = PreisachModel(smooth_weights(100), (0, 100)).predict(u) + np.random.default_rng(1).normal(0, 1e-3, u.size)\n"
        "base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss\n"
        "ts = []\n"
        "for _ in range(3):\n"
        "    t0 = time.perf_counter(); m = PreisachModel.fit(u, y, 100); ts.append(time.perf_counter() - t0)\n"
        "print(json.dumps({'t': sorted(ts)[1], 'peak_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,"
        " 'rows': m.report.n_rows, 'rmse': m.report.rmse}))\n"
    ) % (sys.path[0] or ".")
    res = json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout)
    rows.append(("identify n_h = 100 from 10^6 samples", f"{res['t']:.2f} s, peak {res['peak_mb']:.0f} MB (whole process)",
                 f"dense A would be {1e6 * 5050 * 8 / 1e9:.0f} GB", f"{res['rows']} merged rows"))

    # --- n_h = 40 against scipy.optimize.nnls on the same rows -------------------------
    from scipy.optimize import nnls

    n = 40
    u40, y40, rng = record_40()
    A, counts, target, within = _preisach.regression_rows(u40, y40, n, rng)
    sw = np.sqrt(counts)[:, None]
    A2 = np.hstack([A, -A[:, -1:]]) * sw
    b2 = target * sw[:, 0]

    def scipy_fit():
        x, _ = nnls(A2, b2, maxiter=100 * A2.shape[1])
        return np.concatenate([x[:-2], [x[-2] - x[-1]]])

    t_sp = median_time(scipy_fit, repeat=3)
    x_sp = scipy_fit()
    t_us = median_time(lambda: PreisachModel.fit(u40, y40, n, u_range=rng), repeat=21)
    reps = [PreisachModel.fit(u40, y40, n, u_range=rng).report for _ in range(21)]
    t_solve = float(np.median([r.time_solve_s for r in reps]))
    t_rows = float(np.median([r.time_rows_s for r in reps]))
    m40 = PreisachModel.fit(u40, y40, n, u_range=rng)
    iu = np.triu_indices(n)
    x_us = np.concatenate([m40.weights[iu], [m40.offset]])
    obj = lambda x: (float(counts @ (A @ x - target) ** 2) + within) / counts.sum()
    rows.append((f"identify n_h = 40 ({u40.size} samples, {A.shape[0]} rows), solver {m40.report.solver!r}",
                 f"solve {t_solve * 1e3:.1f} ms (+ rows {t_rows * 1e3:.1f} ms; whole fit {t_us * 1e3:.1f} ms), "
                 f"MSE {obj(x_us):.6e}",
                 f"scipy.optimize.nnls on the merged rows {t_sp * 1e3:.0f} ms, MSE {obj(x_sp):.6e}",
                 f"solve {t_sp / t_solve:.0f}x, whole fit "
                 f"{t_sp / t_us:.0f}x faster; objective ratio {obj(x_us) / obj(x_sp):.9f}"))

    # The plain way (the paper's lsqnonneg): one row per sample, relay states from the
    # NumPy relay grid, on a record short enough for SciPy to finish.
    u_s = sweep(6_000, n_rev=100, noise=0.02, seed=4)
    y_s = PreisachModel(smooth_weights(n), (0, 100)).predict(u_s) + np.random.default_rng(5).normal(0, 0.01, u_s.size)
    rng_s = (float(u_s.min()) + 0.005 * np.ptp(u_s), float(u_s.max()) - 0.005 * np.ptp(u_s))
    thr = rng_s[0] + (np.arange(n) + 0.5) * (rng_s[1] - rng_s[0]) / n
    beta, alpha = thr[iu[0]], thr[iu[1]]

    def scipy_plain():
        R = -np.ones(beta.size)
        A_full = np.empty((u_s.size, beta.size + 2))
        for k, x in enumerate(u_s):
            R = np.where(x >= alpha, 1.0, np.where(x < beta, -1.0, R))
            A_full[k, :-2] = R
        A_full[:, -2], A_full[:, -1] = 1.0, -1.0
        x, _ = nnls(A_full, y_s, maxiter=100 * A_full.shape[1])
        return A_full, x

    t0 = time.perf_counter()
    A_full, x_plain = scipy_plain()
    t_plain = time.perf_counter() - t0
    t_us_s = median_time(lambda: PreisachModel.fit(u_s, y_s, n, u_range=rng_s), repeat=5)
    ms = PreisachModel.fit(u_s, y_s, n, u_range=rng_s)
    mse_plain = float(np.mean((A_full @ x_plain - y_s) ** 2))
    mse_us = ms.report.rmse**2
    rows.append((f"identify n_h = 40, plain way ({u_s.size} samples, one row each)",
                 f"{t_us_s * 1e3:.1f} ms, MSE {mse_us:.6e}",
                 f"relay-grid matrix + scipy.optimize.nnls {t_plain:.1f} s, MSE {mse_plain:.6e}",
                 f"{t_plain / t_us_s:,.0f}x faster, objective ratio {mse_us / mse_plain:.9f}"))

    # --- closest-match inversion against NumPy brute force ------------------------------
    r = m100.predict(sweep(1_000_000, n_rev=10))
    try:
        t_inv = median_time(lambda: m100.invert(r, method="closest")) / r.size
        rs = r[::997][:800]
        t_bf = median_time(lambda: numpy_closest_match(m100.weights, 0.0, 100.0, rs - m100.offset), repeat=3) / rs.size
        rows.append(("closest-match inverse, n_h = 100", f"{t_inv * 1e9:.0f} ns/sample",
                     f"NumPy brute force {t_bf * 1e9:,.0f} ns/sample", f"{t_bf / t_inv:,.0f}x faster"))
    except (AttributeError, ImportError) as exc:  # inversion not built
        rows.append(("closest-match inverse", "n/a", str(exc), ""))

    print(describe() + "\n")
    print("| what | preisach | plain NumPy / SciPy | ratio |")
    print("|---|---|---|---|")
    for r_ in rows:
        print("| " + " | ".join(r_) + " |")


if __name__ == "__main__":
    main()
