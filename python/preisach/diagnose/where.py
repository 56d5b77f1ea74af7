"""Where the gap lies (localization of a residual) and the signature statistics that
point at an effect. All numpy, all on the residual ``r = y - model``."""
from __future__ import annotations

import math
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import NDArray


def noise_floor(r: NDArray[np.float64]) -> float:
    """Sensor-noise estimate from the data itself: the MAD of second differences of a
    residual, scaled for white noise (var of the 2nd difference = 6 sigma^2). Smooth model
    error and rare jumps barely move a median."""
    if r.size < 5:
        return float("nan")
    d2 = np.diff(r, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def repeatability_floor(records: Sequence[tuple[NDArray[np.float64], NDArray[np.float64]]]) -> Optional[float]:
    """The repeatability floor from repeated records, ``(u, y)`` pairs: records whose
    inputs agree (same length, within 1e-3 of the input's span RMS) are repeats of one
    experiment, and the RMS of their outputs' difference is what a chain fitted on one
    repeat scores on another at best (noise, wander, the stage's own unrepeatability of
    both). The median over every pair of repeats; None when there are none."""
    out = []
    for i, (ui, yi) in enumerate(records):
        for uj, yj in records[:i]:
            if ui.size != uj.size:
                continue
            span = max(float(np.ptp(ui)), 1e-300)
            if math.sqrt(float(np.mean((ui - uj) ** 2))) <= 1e-3 * span:
                out.append(math.sqrt(float(np.mean((yi - yj) ** 2))))
    return float(np.median(out)) if out else None


def segments(u: NDArray[np.float64], dt: float, rest: Optional[float] = None) -> dict[str, NDArray[np.bool_]]:
    """Boolean masks: ``after_step`` (10 ms after a jump of the input; from the rest input
    ``rest`` to the first sample too), ``reversal`` (within 2 ms of a turning point),
    ``dwell`` (input constant, not just after a step) and ``moving`` (the rest)."""
    n = u.size
    span = float(np.ptp(u)) or 1.0
    du = np.diff(u, prepend=u[0] if rest is None else rest)
    step = np.abs(du) > 0.02 * span
    moving_thr = 1e-6 * span
    still = np.abs(du) <= moving_thr

    def widen(mask: NDArray[np.bool_], k: int) -> NDArray[np.bool_]:
        idx = np.flatnonzero(mask)
        out = np.zeros(n, dtype=bool)
        if idx.size:
            c = np.zeros(n + 1, dtype=np.int64)
            np.add.at(c, idx, 1)
            np.add.at(c, np.minimum(idx + k, n), -1)
            out = np.cumsum(c[:n]) > 0
        return out

    after = widen(step, max(1, int(0.01 / dt)))
    nz = np.flatnonzero(np.abs(du) > moving_thr)
    turn = np.zeros(n, dtype=bool)
    if nz.size > 2:
        s = np.sign(du[nz])
        tp = nz[1:][s[1:] != s[:-1]]
        tp = tp[~step[tp]]
        turn[tp] = True
    k = max(1, int(0.002 / dt))
    rev = widen(np.roll(turn, -k) if k < n else turn, 2 * k) & ~after
    dwell = still & ~after & ~rev
    moving = ~(after | rev | dwell)
    return {"after_step": after, "reversal": rev, "dwell": dwell, "moving": moving}


def spectrum(r: NDArray[np.float64], dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Welch amplitude spectral density (Hann, 50 % overlap); returns (f, asd)."""
    n = r.size
    nseg = min(n, 1 << int(min(15, max(6, math.floor(math.log2(max(n // 8, 64)))))))
    win = np.hanning(nseg)
    acc = np.zeros(nseg // 2 + 1)
    cnt = 0
    for s in range(0, n - nseg + 1, max(1, nseg // 2)):
        seg = r[s:s + nseg]
        acc += np.abs(np.fft.rfft((seg - seg.mean()) * win)) ** 2
        cnt += 1
    psd = acc / max(cnt, 1) * 2 * dt / np.sum(win ** 2)
    return np.fft.rfftfreq(nseg, dt).astype(np.float64), np.sqrt(psd).astype(np.float64)


def peaks(f: NDArray[np.float64], asd: NDArray[np.float64], k: int = 3) -> list[dict[str, float]]:
    """The ``k`` strongest narrow peaks (above 50 Hz) relative to a smoothed trend."""
    ok = f > 50
    if ok.sum() < 8:
        return []
    ff, a = f[ok], np.log(asd[ok] + 1e-300)
    w = max(3, ok.sum() // 40)
    trend = np.convolve(a, np.ones(w) / w, mode="same")
    ex = a - trend
    out: list[dict[str, float]] = []
    for i in np.argsort(ex)[::-1]:
        if len(out) >= k:
            break
        if any(abs(ff[i] - p["frequency_hz"]) < 3 * (ff[1] - ff[0]) for p in out):
            continue
        out.append({"frequency_hz": float(ff[i]), "prominence_db": float(20 / math.log(10) * ex[i])})
    return out


def localize(name: str, t: NDArray[np.float64], u: NDArray[np.float64], r: NDArray[np.float64],
             dt: float, levels: NDArray[np.float64], rest: Optional[float] = None) -> dict[str, Any]:
    """Where the residual of one record lies: time windows, segment kinds, input level
    (Preisach cell row), frequency bands and input rate. ``rest``: the input the record
    stepped from at its first sample (the start is then after a step)."""
    tot = float(np.sqrt(np.mean(r ** 2)))
    seg = segments(u, dt, rest)
    by_seg = {k: {"fraction_of_samples": float(m.mean()),
                  "rmse": float(np.sqrt(np.mean(r[m] ** 2))) if m.any() else None,
                  "share_of_error": float(np.sum(r[m] ** 2) / max(np.sum(r ** 2), 1e-300))}
              for k, m in seg.items()}
    # Time: ten windows; the worst ones are the localized segments (plots mark them).
    nw = 10
    edges = np.linspace(0, r.size, nw + 1).astype(int)
    win = [{"t0": float(t[a]), "t1": float(t[b - 1]), "rmse": float(np.sqrt(np.mean(r[a:b] ** 2)))}
           for a, b in zip(edges[:-1], edges[1:]) if b > a]
    worst = sorted(win, key=lambda w: -w["rmse"])[:3]
    # Input level: bins of the model's level grid (at most 10 bins).
    nb = min(10, max(1, levels.size - 1))
    lv = np.linspace(levels[0], levels[-1], nb + 1)
    k = np.clip(np.searchsorted(lv, u, side="right") - 1, 0, nb - 1)
    by_level = []
    for i in range(nb):
        m = k == i
        if m.any():
            by_level.append({"u_lo": float(lv[i]), "u_hi": float(lv[i + 1]), "rmse": float(np.sqrt(np.mean(r[m] ** 2))),
                             "samples": int(m.sum())})
    # Frequency: residual power per band.
    f, asd = spectrum(r, dt)
    psd = asd ** 2
    bands = []
    edges_f = [0, 1, 10, 100, 1000, 10000, float("inf")]
    tot_p = float(np.sum(psd)) or 1e-300
    for a, b in zip(edges_f[:-1], edges_f[1:]):
        m = (f >= a) & (f < b)
        if m.any():
            bands.append({"f_lo": a, "f_hi": b if math.isfinite(b) else None,
                          "share_of_power": float(psd[m].sum() / tot_p)})
    # Input rate: quartiles of |du/dt|.
    rate = np.abs(np.gradient(u, dt))
    qs = np.quantile(rate, [0, 0.25, 0.5, 0.75, 1.0])
    by_rate = []
    for a, b in zip(qs[:-1], qs[1:]):
        m = (rate >= a) & (rate <= b)
        if m.any():
            by_rate.append({"rate_lo": float(a), "rate_hi": float(b), "rmse": float(np.sqrt(np.mean(r[m] ** 2)))})
    return {"record": name, "rmse": tot, "segments": by_seg, "worst_windows": worst, "by_level": by_level,
            "by_band": bands, "peaks": peaks(f, asd), "by_rate": by_rate}


def signatures(t: NDArray[np.float64], u: NDArray[np.float64], h: NDArray[np.float64],
               r: NDArray[np.float64], dt: float) -> dict[str, Any]:
    """Signature statistics of a residual ``r`` against the model output ``h``:
    cross-correlation lag with the model's rate (delay / low-pass), the slope of the
    residual phase vs frequency, the spectral peak (mode), residual vs log time in
    dwells (creep), and correlation with absolute time and with time x output (drift)."""
    out: dict[str, Any] = {}
    hd = np.gradient(h, dt)
    # First-order delay model r ~ -d * dh/dt.
    den = float(hd @ hd)
    out["lag_ls_s"] = float(-(r @ hd) / den) if den > 0 else 0.0
    # Phase of the residual relative to the model output: transfer r/h per band.
    n = min(r.size, 1 << 16)
    H = np.fft.rfft(h[:n] - h[:n].mean())
    R = np.fft.rfft(r[:n])
    f = np.fft.rfftfreq(n, dt)
    strong = np.abs(H) > 0.05 * np.abs(H).max()
    strong[0] = False
    if strong.sum() >= 2:
        G = 1 + R[strong] / H[strong]  # measured/model transfer at the excited lines
        ph = np.unwrap(np.angle(G))
        out["phase_slope_s"] = float(-np.polyfit(2 * np.pi * f[strong], ph, 1)[0]) if strong.sum() > 2 else None
        out["gain_drop_at_high_f"] = float(np.abs(G[-1]) - np.abs(G[0]))
    fs, asd = spectrum(r, dt)
    out["peaks"] = peaks(fs, asd, 2)
    seg = segments(u, dt)
    out["dwell_fraction"] = float(seg["dwell"].mean() + seg["after_step"].mean())
    tt = t - t[0]
    out["corr_time"] = float(abs(np.corrcoef(tt, r)[0, 1])) if r.std() > 0 else 0.0
    th = tt * (h - h.mean())
    out["corr_time_output"] = float(abs(np.corrcoef(th, r)[0, 1])) if r.std() > 0 and th.std() > 0 else 0.0
    return out
