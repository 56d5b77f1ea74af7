"""An independent simulated stage: the ground truth of the diagnosis tests and of
``benches/blind_validation.py``.

Simulated without the project's blocks: a fine-grid (n_h = 120) interpolated Preisach
model with a smooth random density, then SciPy filters (zero-order-hold modes, bilinear
Butterworth low-pass, exact first-order creep elements), an integer + linear-
interpolation delay, drift in absolute time and white sensor noise. SciPy is a
test/bench dependency only.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import signal

from preisach import PreisachModel

EFFECTS = ("delay", "lowpass", "vibration", "creep", "drift")
U_LO, U_HI = 0.0, 100.0


def true_hysteresis(rng: np.random.Generator, n_h: int = 120) -> PreisachModel:
    """A smooth random Preisach density (a bump along the diagonal plus a broad part),
    scaled so the output spans about 15 µm."""
    lv = np.linspace(U_LO, U_HI, n_h + 1)
    c = (lv[:-1] + lv[1:]) / 2
    B, A = np.meshgrid(c, c, indexing="ij")
    width = rng.uniform(8, 25)
    centre = rng.uniform(35, 65)
    spread = rng.uniform(25, 60)
    w = np.exp(-((A - B) / width) ** 2) * np.exp(-(((A + B) / 2 - centre) / spread) ** 2)
    w += 0.2 * np.exp(-((A - B) / (2 * width)) ** 2)
    w = np.where(A >= B, w, 0.0)
    w *= 15.0 / (2 * w.sum())
    return PreisachModel(w, (U_LO, U_HI), rng.uniform(-1, 1), "interpolated")


def draw_effects(rng: np.random.Generator, names: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    """Random parameters in the issue's realistic ranges."""
    out: dict[str, dict[str, Any]] = {}
    for n in names:
        if n == "delay":
            out[n] = {"delay_s": rng.uniform(1e-4, 1e-3)}
        elif n == "lowpass":
            out[n] = {"cutoff_hz": rng.uniform(300, 1500), "order": int(rng.integers(1, 3))}
        elif n == "vibration":
            out[n] = {"frequency_hz": rng.uniform(500, 2000), "damping": math.exp(rng.uniform(math.log(0.005), math.log(0.05)))}
        elif n == "creep":
            tau = math.exp(rng.uniform(math.log(0.01), math.log(10)))
            out[n] = {"taus_s": [tau], "amplitudes": [rng.uniform(0.01, 0.10)]}
        elif n == "drift":
            out[n] = {"gain_per_s": rng.choice([-1, 1]) * rng.uniform(0.005, 0.02),
                      "offset": rng.uniform(-0.3, 0.3), "offset_per_s": rng.uniform(-0.05, 0.05)}
    return out


def simulate(h_model: PreisachModel, eff: dict[str, dict[str, Any]], t: np.ndarray, u: np.ndarray,
             noise: float, rng: np.random.Generator) -> np.ndarray:
    """The true stage: hysteresis -> creep -> mode -> low-pass -> delay -> drift -> noise."""
    fs = 1.0 / float(np.median(np.diff(t)))
    x = h_model.predict(u)

    def filt(b: np.ndarray, a: np.ndarray, x: np.ndarray) -> np.ndarray:
        zi = signal.lfilter_zi(b, a) * x[0]
        return signal.lfilter(b, a, x, zi=zi)[0]

    if "creep" in eff:
        p = eff["creep"]
        y = x.copy()
        for tau, c in zip(p["taus_s"], p["amplitudes"]):
            a = math.exp(-1 / (fs * tau))
            y += c * filt(np.array([1 - a]), np.array([1.0, -a]), x)
        x = y
    if "vibration" in eff:
        p = eff["vibration"]
        w = 2 * math.pi * p["frequency_hz"]
        b, a, _ = signal.cont2discrete(([w * w], [1, 2 * p["damping"] * w, w * w]), 1 / fs, method="zoh")
        x = filt(np.ravel(b), np.ravel(a), x)
    if "lowpass" in eff:
        p = eff["lowpass"]
        b, a = signal.butter(p["order"], p["cutoff_hz"], fs=fs)
        x = filt(b, a, x)
    if "delay" in eff:
        D = eff["delay"]["delay_s"] * fs
        k = int(math.floor(D))
        f = D - k
        xp = np.concatenate([np.full(k + 1, x[0]), x])
        x = (1 - f) * xp[1:x.size + 1] + f * xp[0:x.size]
    if "drift" in eff:
        p = eff["drift"]
        x = x * (1 + p["gain_per_s"] * t) + p["offset"] + p["offset_per_s"] * t
    return x + noise * rng.standard_normal(x.size)


def delay_seen(params: dict[str, dict[str, Any]], fs: float) -> float:
    """The delay a chain of the stage's effects as continuous blocks needs (the truth a
    found delay is compared with): the stage's delay, plus half a sample when it has a
    mode (the zero-order-hold discretization is the continuous mode driven by a held
    input, which lags by half a sample at every frequency)."""
    return float(params["delay"]["delay_s"]) + (0.5 / fs if "vibration" in params else 0.0)


def waveform(kind: str, fs: float, dur: float, rng: np.random.Generator) -> np.ndarray:
    """Input signals: a reversal-rich training sweep, sines, triangles, steps with dwell."""
    t = np.arange(int(round(dur * fs))) / fs
    mid, amp = 50.0, 45.0
    if kind == "train":
        # Decaying multi-tone: many nested reversals, several rates, plus a few steps.
        # Two decaying bursts: large loops early and late, so a slow drift in time is not
        # confounded with the input level.
        # The first 7 Hz cycle of each burst keeps the full amplitude, and 63 Hz = 9 x 7 Hz
        # puts the top of the sweep at the top of the range: the training record covers
        # the holdouts' input range (otherwise the gap is extrapolation, not an effect).
        env = 0.15 + 0.85 * np.exp(-np.maximum(0.0, (t % (dur / 2)) - 1 / 7) / (dur / 6))
        # Starts at rest at the bottom; the first cycles span the whole range.
        s = 0.8 * np.cos(2 * np.pi * 7 * t) + 0.2 * np.cos(2 * np.pi * 63 * t)
        u = mid - amp * env * s
        steps = np.zeros_like(t)
        for k, tk in enumerate(np.arange(0.6, dur, dur / 5)):
            steps += (t >= tk) * (6.0 if k % 2 == 0 else -6.0)
        u = u + steps * (t > 0.5)
    elif kind == "sine":
        f = rng.uniform(20, 60)
        u = mid + amp * 0.9 * np.sin(2 * np.pi * f * t - np.pi / 2) * np.minimum(1, t / 0.05)
    elif kind == "triangle":
        f = rng.uniform(10, 40)
        ph = (t * f) % 1.0
        u = mid - amp * 0.9 + 2 * amp * 0.9 * np.where(ph < 0.5, 2 * ph, 2 - 2 * ph)
    elif kind == "steps":
        levels = rng.uniform(mid - 0.9 * amp, mid + 0.9 * amp, size=8)
        edges = np.linspace(0, dur, 9)[:-1]
        u = np.full_like(t, mid - 0.9 * amp)
        for e, lv in zip(edges[1:], levels):
            u[t >= e] = lv
    elif kind == "reversals":
        pts = mid + 0.9 * amp * np.array([-1, 1, -0.6, 0.7, -0.3, 0.4, 0.0, 0.9, -0.9, 0.2, -0.5, 0.6])
        u = np.interp(t, np.linspace(0, dur, pts.size), pts)
    else:
        raise ValueError(kind)
    return np.clip(u, U_LO, U_HI)


def make_stage(seed: int, names: tuple[str, ...], fs: float = 50e3, dur: float = 1.5,
               noise: float = 0.003) -> dict[str, Any]:
    """One stage: truth + records (train, two holdouts, one further blind record).
    Absolute time runs on across records."""
    rng = np.random.default_rng(seed)
    hm = true_hysteresis(rng)
    eff = draw_effects(rng, names)
    recs = []
    t0 = 0.0
    for kind in ("train", "triangle", "steps", rng.choice(["sine", "reversals", "steps"])):
        u = waveform(str(kind), fs, dur, rng)
        t = t0 + np.arange(u.size) / fs
        y = simulate(hm, eff, t, u, noise, rng)
        recs.append({"t": t, "u": u, "y": y, "kind": str(kind)})
        t0 = t[-1] + 1.0 / fs
    return {"seed": seed, "truth": names, "params": eff, "train": recs[0], "holdouts": recs[1:3], "blind": recs[3]}
