"""Reference responses of the linear blocks written with SciPy from their definitions
(``docs/method/blocks.md``), independently of the project's core: transfer functions,
the zero-order hold with the project's convention, the exact response to an input linear
between samples."""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import signal


def tf_mode(f: float, z: float) -> tuple[list[float], list[float]]:
    w = 2 * math.pi * f
    return [w * w], [1.0, 2 * z * w, w * w]


def tf_creep(taus: list[float], amps: list[float], normalized: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """``1 + Σ c/(1 + sτ)`` (or ``1 + Σ c (1/(1 + sτ) − 1)``) over a common denominator."""
    den = np.array([1.0])
    for tau in taus:
        den = np.polymul(den, [tau, 1.0])
    num = den.copy()
    for k, (tau, c) in enumerate(zip(taus, amps)):
        others = np.array([1.0])
        for j, tj in enumerate(taus):
            if j != k:
                others = np.polymul(others, [tj, 1.0])
        term = c * others if not normalized else c * np.polysub(others, np.polymul(others, [tau, 1.0]))
        num = np.polyadd(num, term)
    return num, den


def tf_rate(gain_s: float, tau_s: float) -> tuple[list[float], list[float]]:
    return [gain_s, 0.0], [tau_s, 1.0]


def zoh_reference(num, den, x: np.ndarray, dt: float) -> np.ndarray:
    """The zero-order-hold response with the project's convention: the input ``x[n]`` is
    held over the interval that *ends* at sample n and the output is read after it, so
    ``y[n] = C s[n+1] + D x[n]`` with ``s[k+1] = Ad s[k] + Bd x[k]`` (scipy's
    ``cont2discrete`` state update), starting at rest with ``x[0]``."""
    A, B, C, D = signal.tf2ss(num, den)
    Ad, Bd, _, _, _ = signal.cont2discrete((A, B, C, D), dt, method="zoh")
    s = -np.linalg.solve(A, B[:, 0]) * x[0]  # the continuous steady state: at rest
    y = np.empty_like(x)
    for n, v in enumerate(x):
        s = Ad @ s + Bd[:, 0] * v
        y[n] = C[0] @ s + D[0, 0] * v
    return y


def lsim_reference(num, den, t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The exact response to ``x`` linear between samples, at rest with ``x[0]``."""
    dc = np.polyval(num, 0.0) / np.polyval(den, 0.0)
    _, y, _ = signal.lsim(signal.lti(num, den), x - x[0], t - t[0], interp=True)
    return y + dc * x[0]


def tf_lowpass(cutoff_hz: float, order: int) -> tuple[np.ndarray, np.ndarray]:
    """The analog Butterworth low-pass."""
    return signal.butter(order, 2 * math.pi * cutoff_hz, analog=True)


def apply_effects(effects: dict[str, dict[str, Any]], t: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Creep, vibration, low-pass (exact for ``x`` linear between samples) then delay (linear
    interpolation, at rest before the start), as a model's effects are applied."""
    y = x
    for name in ("creep", "vibration", "lowpass"):
        if name in effects:
            p = effects[name]
            if name == "creep":
                num, den = tf_creep(p["taus_s"], p["amplitudes"], bool(p.get("normalized")))
            elif name == "vibration":
                num, den = tf_mode(p["frequency_hz"], p["damping"])
            else:
                num, den = tf_lowpass(p["cutoff_hz"], p.get("order", 2))
            y = lsim_reference(num, den, t, y)
    if "delay" in effects:
        y = np.interp(t - effects["delay"]["delay_s"], t, y, left=y[0])
    return y
