"""Search ranges from the data, and the check that a fitted parameter ended at one.

Every scalar an effect's search moves has a range derived from the records (how slow the
excitation is, how long the record, how fast the fit's sampling), never a fixed number
that a real stage may exceed. A parameter that ends at a bound is reported (``at_bound``)
and its effect is not called detected, unless the bound is physical (a delay of 0, a
creep amplitude of 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Shortest creep time constant searched: faster "creep" is a low-pass's business.
CREEP_TAU_MIN = 5e-3
#: Longest creep time constant searched, in training-record lengths: beyond the record,
#: where an element shows only its first slope and curvature (the held-out records,
#: other input histories, choose the time constant; a drift instead runs on in absolute
#: time across them).
CREEP_TAU_MAX_RECORDS = 10.0
#: Largest creep amplitude searched (realistic stages creep 1-10 %).
CREEP_AMP_MAX = 0.12
#: Longest delay searched, as a share of the slowest excitation's period (and at most an
#: eighth of the training record).
DELAY_SHARE = 0.25


@dataclass(frozen=True)
class Bound:
    """The range of one scalar: ``lo`` to ``hi`` (searched in log units when ``log``);
    ``physical_lo``/``physical_hi``: that end is a physical limit, not a search limit."""

    lo: float
    hi: float
    log: bool
    physical_lo: bool = False
    physical_hi: bool = False

    def clip(self, x: float) -> float:
        return min(max(x, self.lo), self.hi)

    def at(self, x: float) -> str:
        """``"lo"``/``"hi"`` when ``x`` ends at a search (non-physical) bound, else ``""``."""
        if self.log:
            near = lambda b: b > 0 and x > 0 and abs(math.log(x / b)) < 0.01  # noqa: E731
        else:
            near = lambda b: abs(x - b) <= 1e-3 * (self.hi - self.lo)  # noqa: E731
        if near(self.lo) and not self.physical_lo:
            return "lo"
        if near(self.hi) and not self.physical_hi:
            return "hi"
        return ""


Ranges = dict[str, dict[str, Bound]]


def slowest_period(u: NDArray[np.float64], dt: float) -> float:
    """Period of the slowest excitation of ``u``: the strongest line of its spectrum
    (the record's mean and linear trend removed) at or above two cycles per record."""
    n = u.size
    x = u - np.linspace(u[0], u[-1], n)
    spec = np.abs(np.fft.rfft(x - x.mean()))
    f = np.fft.rfftfreq(n, dt)
    ok = f >= 2.0 / (n * dt)
    if not ok.any() or not np.any(spec[ok] > 0):
        return n * dt
    return float(1.0 / f[ok][int(np.argmax(spec[ok]))])


def search_ranges(u: NDArray[np.float64], dt_record: float, duration: float, dt_fit: float) -> Ranges:
    """The ranges of every effect's scalars for a training input ``u`` sampled every
    ``dt_record`` over ``duration`` seconds, fitted at period ``dt_fit``:

    - delay: 0 (physical) to a quarter of the slowest excitation's period, at most an
      eighth of the record, at least 20 fit samples;
    - low-pass cutoff: from the cutoff whose group delay is the longest delay searched
      to 0.4 of the fit's sample rate (a low-pass there is no low-pass);
    - mode: 50 Hz to 0.45 of the fit's Nyquist frequency; damping 1e-3 to 0.5;
    - creep: time constant 5 ms (faster is a low-pass) to 10 record lengths, amplitude 0
      (physical) to 0.12;
    - drift gain: +-1 / record length (more doubles the output over the record);
    - rate time constant: two fit samples to a quarter of the slowest period."""
    period = slowest_period(u, dt_record)
    d_hi = max(20 * dt_fit, min(DELAY_SHARE * period, duration / 8))
    nyq = 0.5 / dt_fit
    g_hi = 1.0 / max(duration, 1e-9)
    return {
        "delay": {"delay_s": Bound(0.0, d_hi, False, physical_lo=True)},
        "lowpass": {"cutoff_hz": Bound(1.0 / (2 * math.pi * d_hi), 0.8 * nyq, True)},
        "vibration": {"frequency_hz": Bound(50.0, 0.45 * nyq, True), "damping": Bound(1e-3, 0.5, True)},
        "creep": {"tau": Bound(CREEP_TAU_MIN, max(0.05, CREEP_TAU_MAX_RECORDS * duration), True),
                  "amp": Bound(0.0, CREEP_AMP_MAX, False, physical_lo=True)},
        "drift": {"gain_per_s": Bound(-g_hi, g_hi, False)},
        "rate": {"tau_s": Bound(2 * dt_fit, max(4 * dt_fit, DELAY_SHARE * period), True)},
    }


def delay_grid(dt: float, hi: float) -> NDArray[np.float64]:
    """Trial delays for a grid search: 0, then steps of at most 1.5x from about a sample
    (``dt``, at least 10 us, at most a tenth of ``hi``) to ``hi`` (a delay is well
    resolved near its minimum)."""
    lo = min(max(dt, 1e-5), hi / 10)
    n = max(11, int(math.ceil(math.log(hi / lo) / math.log(1.5))) + 1)
    return np.concatenate([[0.0], np.geomspace(lo, hi, n)])


def ends_at_bound(name: str, p: dict[str, Any], ranges: Ranges) -> list[str]:
    """The parameters of effect ``name`` (internal form) that ended at a search bound,
    as ``"key=value (lo|hi bound)"`` texts; empty when none did."""
    out = []
    for key, b in ranges.get(name, {}).items():
        if name == "creep":
            vals = p["taus_s"] if key == "tau" else p["amplitudes"]
            if len(vals) != 1:
                continue  # a given chain's creep of several elements is not searched
            v, label = float(vals[0]), ("taus_s" if key == "tau" else "amplitudes")
        elif key in p:
            v, label = float(p[key]), key
        else:
            continue
        side = b.at(v)
        if side:
            out.append(f"{label}={v:.4g} ({'lower' if side == 'lo' else 'upper'} bound "
                       f"{b.lo if side == 'lo' else b.hi:.4g})")
    return out
