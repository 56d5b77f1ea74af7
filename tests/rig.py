"""A second, independent simulated rig: what real captures of a piezo stage carry.

Test and benchmark code only (SciPy). Nothing here uses the project's code or its
conventions, so a method that only works on the project's own simulator fails here:

- **Hysteresis**: a generalized Prandtl–Ishlinskii operator (play operators with random,
  continuous thresholds between a monotone input map and a mild output nonlinearity).
  It is rate independent with wiping-out, but it is no discrete Preisach model on any
  grid, and its output nonlinearity breaks the congruency of minor loops a little, as a
  real actuator does.
- **The analog world**: every linear part (the amplifier's bandwidth, creep, the
  mechanical modes, the sensor's filter, the anti-aliasing filter) is a continuous-time
  system discretized by SciPy on a grid ``OVERSAMPLE`` times finer than the capture.
  The DAC holds each command for one sample period; the ADC samples at the tick, before
  that tick's command acts (a step shows one sample late; the held staircase lags a
  smooth command by half a sample: ``Rig.timing_s``), adds white noise and a slow
  record-to-record wander (the repeatability floor), and quantizes to 16 bits.
- **History before the record**: the stage rested at a level (by default the first
  command; a capture that starts with a step from rest has another), after a history of
  excursions that the record does not show (the hysteresis memory is not "all relays
  down"). A session carries its own sensor offset; a channel its own delay.

``make_case(name, seed)`` draws a stage and its records for one validation class (see
``CLASSES``) with the truth the diagnosis should find.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional, Sequence

import numpy as np
from scipy import signal

#: The analog grid is this many times finer than the capture.
OVERSAMPLE = 16
#: DAC command range (volts) and the amplifier's gain (piezo volts per DAC volt).
DAC_LO, DAC_HI = 0.0, 10.0
AMP_GAIN = 15.0
#: ADC: 16 bits over +-10 V.
ADC_BITS, ADC_RANGE = 16, 10.0


# ------------------------------------------------------------------------ hysteresis
@dataclass
class PlayHysteresis:
    """``y = z + eps * z^2 / stroke`` with ``z = a v + sum_i w_i P_{r_i}[v]`` and
    ``v = x + kappa (x - x_lo)^2 / (x_hi - x_lo)``, ``P_r`` the play operator of half
    width ``r`` (input in piezo volts, output in micrometres)."""

    r: np.ndarray
    w: np.ndarray
    a: float
    kappa: float
    eps: float
    x_lo: float
    x_hi: float
    stroke: float

    def vmap(self, x: np.ndarray) -> np.ndarray:
        return x + self.kappa * (x - self.x_lo) ** 2 / (self.x_hi - self.x_lo)

    def rest_state(self, history: Sequence[float]) -> np.ndarray:
        """Play outputs after a descent from far above to ``x_lo`` (negative saturation),
        then the levels of ``history`` in turn (piezo volts)."""
        v0 = float(self.vmap(np.array([self.x_lo]))[0])
        p = v0 + self.r
        for x in history:
            v = float(self.vmap(np.array([x]))[0])
            p = np.clip(p, v - self.r, v + self.r)
        return p

    def run(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Output for input ``x`` from play state ``p``; returns (y, final state).

        Within a monotone run of the input a play operator is a clamp from one side only
        (rising: ``max(p0, v - r)``; falling: ``min(p0, v + r)``), so each run is one
        vectorized step."""
        v = self.vmap(np.asarray(x, dtype=np.float64))
        z = np.empty_like(v)
        d = np.sign(np.diff(v))
        # Run boundaries: where the direction changes (flat steps continue a run).
        nz = np.flatnonzero(d)
        cuts = [0]
        if nz.size:
            s = d[nz]
            turn = nz[1:][s[1:] != s[:-1]]
            cuts += list(turn + 1)
        cuts.append(v.size)
        p = p.copy()
        for a, b in zip(cuts[:-1], cuts[1:]):
            for c in range(a, b, 65536):
                seg = v[c:min(b, c + 65536)]
                rising = seg[-1] >= seg[0] if seg.size > 1 else True
                if rising:
                    blk = np.maximum(p[None, :], seg[:, None] - self.r[None, :])
                else:
                    blk = np.minimum(p[None, :], seg[:, None] + self.r[None, :])
                z[c:c + seg.size] = self.a * seg + blk @ self.w
                p = blk[-1].copy()
        y = z + self.eps * z * z / self.stroke
        return y, p


def draw_hysteresis(rng: np.random.Generator) -> PlayHysteresis:
    """A random actuator: 0-150 V gives 25-35 um with a loop about 10 % of the stroke wide."""
    x_lo, x_hi = 0.0, AMP_GAIN * DAC_HI
    m = 24
    span = x_hi - x_lo
    r = np.sort(rng.uniform(0.0, 0.35, m)) * span
    w = np.exp(-r / (rng.uniform(0.08, 0.2) * span)) * rng.uniform(0.5, 1.5, m)
    a = rng.uniform(0.4, 1.0) * float(w.sum())
    h = PlayHysteresis(r=r, w=w, a=a, kappa=rng.uniform(-0.25, 0.25), eps=0.0, x_lo=x_lo, x_hi=x_hi, stroke=1.0)
    # Scale to the stroke over the whole range, then bend the output a little.
    z, _ = h.run(np.linspace(x_lo, x_hi, 2000), h.rest_state([]))
    stroke = rng.uniform(25.0, 35.0)
    k = stroke / float(z[-1] - z[0])
    h.w, h.a, h.stroke = h.w * k, h.a * k, stroke
    h.eps = rng.uniform(-0.04, 0.04)
    return h


# ------------------------------------------------------------------------ the stage
@dataclass
class Rig:
    """One simulated stage. Linear parts are analog (continuous-time ``(b, a)``
    polynomials); ``modes`` as (frequency_hz, damping); ``creep`` as (taus_s,
    amplitudes) in the Kelvin-Voigt form ``x + sum c_k x / (1 + s tau_k)``;
    ``lowpass`` (cutoff_hz, order) an extra Butterworth in the sensor channel;
    ``delays`` the sensor delay of each channel (seconds)."""

    hyst: PlayHysteresis
    amp_hz: float = 30e3
    creep: Optional[tuple[list[float], list[float]]] = None
    modes: list[tuple[float, float]] = field(default_factory=list)
    sensor_gain: float = 0.2
    lowpass: Optional[tuple[float, int]] = None
    aa_hz: float = 3e3
    delays: dict[str, float] = field(default_factory=lambda: {"clean": 0.0})
    noise_std: float = 2e-4
    wander_std: float = 0.0
    drift_gain_per_s: float = 0.0
    drift_offset_per_s: float = 0.0

    def timing_s(self, fs: float, modes: bool = True) -> float:
        """The capture's own low-frequency lag, seconds (what a delay fitted on a "none"
        stage approaches): half a sample of the DAC's hold (the ADC reads at the tick,
        before that tick's command acts, so a step shows one sample late; the held
        staircase lags a smooth command by half a sample), the group delays of the
        amplifier, the modes (``2 zeta / omega_0`` each; ``modes=False`` leaves them out:
        a chain that carries the stage's mode carries its lag) and the anti-aliasing
        filter."""
        lag = 0.5 / fs + 1.0 / (2 * math.pi * self.amp_hz) + math.sqrt(2.0) / (2 * math.pi * self.aa_hz)
        if modes:
            lag += sum(2 * z / (2 * math.pi * f) for f, z in self.modes)
        return lag

    def _analog(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """The linear parts behind the hysteresis, as analog (b, a), in signal order."""
        parts: list[tuple[np.ndarray, np.ndarray]] = []
        for f, z in self.modes:
            w = 2 * math.pi * f
            parts.append((np.array([w * w]), np.array([1.0, 2 * z * w, w * w])))
        if self.lowpass is not None:
            fc, order = self.lowpass
            parts.append(signal.butter(order, 2 * math.pi * fc, analog=True))
        parts.append(signal.butter(2, 2 * math.pi * self.aa_hz, analog=True))
        return parts

    def record(self, u: np.ndarray, fs: float, t0: float = 0.0, *, rest: Optional[float] = None,
               history: Sequence[float] = (), channel: str = "clean", session_offset: float = 0.0,
               session_gain: float = 1.0, rng: Optional[np.random.Generator] = None) -> dict[str, Any]:
        """Capture the response to DAC commands ``u`` (volts) sampled at ``fs``, the first
        at absolute time ``t0``. Before it the DAC rested at ``rest`` (default ``u[0]``)
        long enough for everything to settle, after visiting the DAC levels ``history``
        (default: none, i.e. the stage came up from 0 V)."""
        rng = rng if rng is not None else np.random.default_rng(0)
        u = np.asarray(u, dtype=np.float64)
        rest = float(u[0]) if rest is None else float(rest)
        dt_f = 1.0 / (fs * OVERSAMPLE)
        dac = np.repeat(np.clip(u, DAC_LO, DAC_HI), OVERSAMPLE)

        def lfilter_rest(b: np.ndarray, a: np.ndarray, x: np.ndarray, x_rest: float,
                         method: str = "foh") -> tuple[np.ndarray, float]:
            # The DAC's staircase is truly held ("zoh"); every later signal is smooth, and
            # a cascade of held-input discretizations would lag by half a step per stage.
            bd, ad, _ = signal.cont2discrete((b, a), dt_f, method=method)
            bd = np.ravel(bd)
            zi = signal.lfilter_zi(bd, ad) * x_rest
            y = signal.lfilter(bd, ad, x, zi=zi)[0]
            return y, x_rest * float(np.sum(bd) / np.sum(ad))

        # Amplifier (gain and bandwidth), then the hysteresis from its rest memory.
        wa = 2 * math.pi * self.amp_hz
        x, x_rest = lfilter_rest(np.array([AMP_GAIN * wa]), np.array([1.0, wa]), dac, rest, "zoh")
        p = self.hyst.rest_state([AMP_GAIN * h for h in history] + [x_rest])
        h_rest, _ = self.hyst.run(np.array([x_rest]), p)
        y, _ = self.hyst.run(x, p)
        y_rest = float(h_rest[0])
        if self.creep is not None:
            out = y.copy()
            for tau, c in zip(*self.creep):
                lp, _ = lfilter_rest(np.array([1.0 / tau]), np.array([1.0, 1.0 / tau]), y, y_rest)
                out += c * lp
            y_rest *= 1 + sum(self.creep[1])
            y = out
        y, y_rest = self.sensor_gain * y, self.sensor_gain * y_rest
        for b, a in self._analog():
            y, y_rest = lfilter_rest(b, a, y, y_rest)
        d = self.delays[channel] / dt_f
        if d > 0:
            k = int(math.floor(d))
            f = d - k
            pre = np.concatenate([np.full(k + 1, y_rest), y])
            y = (1 - f) * pre[1:y.size + 1] + f * pre[:y.size]
        # The ADC reads at the tick, before that tick's command acts.
        ys = y[::OVERSAMPLE]
        n = u.size
        t = t0 + np.arange(n) / fs
        ys = session_gain * ys * (1 + self.drift_gain_per_s * t) + self.drift_offset_per_s * t + session_offset
        ys = ys + self.noise_std * rng.standard_normal(n) + self.wander_std * _wander(rng, t - t0)
        q = 2 * ADC_RANGE / (2 ** ADC_BITS - 1)
        ys = np.round((ys + ADC_RANGE) / q) * q - ADC_RANGE
        return {"t": t, "u": u.copy(), "y": ys,
                "truth": {"rest": rest, "history": list(history), "channel": channel,
                          "delay_s": self.delays[channel], "session_offset": session_offset,
                          "session_gain": session_gain}}


def _wander(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """A slow record-to-record wander of unit RMS: a few sines of 0.2-5 Hz."""
    k = 5
    f = np.exp(rng.uniform(math.log(0.2), math.log(5.0), k))
    ph = rng.uniform(0, 2 * math.pi, k)
    a = rng.standard_normal(k)
    x = np.sum(a[:, None] * np.sin(2 * math.pi * f[:, None] * t[None, :] + ph[:, None]), axis=0)
    return x / max(float(np.sqrt(np.mean(x * x))), 1e-12)


# ------------------------------------------------------------------------ inputs
MID, AMP = 5.0, 4.6


def wf_identification(fs: float, f: float = 10.0, periods: int = 50) -> np.ndarray:
    """The paper's identification input (the paper, Fig. 6a): a sine of increasing amplitude,
    ``2 periods`` reversals, starting at its lowest point, slightly past the range used."""
    n = int(round(periods / f * fs))
    t = np.arange(n) / fs
    env = np.linspace(0.02, 1.0, n)
    return MID - AMP * env * np.cos(2 * math.pi * f * t)


def wf_steps(fs: float, rng: np.random.Generator, n_steps: int = 8, dwell: float = 0.08) -> np.ndarray:
    """Steps between random levels, each held ``dwell`` seconds (modes ring, creep shows)."""
    lv = rng.uniform(MID - 0.85 * AMP, MID + 0.85 * AMP, n_steps)
    return np.repeat(lv, int(round(dwell * fs)))


def wf_sine(fs: float, f: float, dur: float, amp: float = 0.8 * AMP, phase: float = -math.pi / 2) -> np.ndarray:
    """A sine; by default starting at its lowest point (no step at the start)."""
    t = np.arange(int(round(dur * fs))) / fs
    return MID + amp * np.sin(2 * math.pi * f * t + phase)


def wf_triangle(fs: float, f: float, dur: float) -> np.ndarray:
    t = np.arange(int(round(dur * fs))) / fs
    ph = (t * f) % 1.0
    return MID - 0.85 * AMP + 1.7 * AMP * np.where(ph < 0.5, 2 * ph, 2 - 2 * ph)


# ------------------------------------------------------------------------ classes
#: Validation classes: what each stage carries, and what the diagnosis should name.
#: ``effects``: the effect names present (the truth); ``protocol``: how records are
#: taken; ``start``: how each record starts; ``sessions``: records in different
#: sessions (a sensor offset each); ``repeats``: the holdouts repeat the training input.
CLASSES: dict[str, dict[str, Any]] = {
    "none": {"effects": (), "protocol": "mixed"},
    "repeats": {"effects": (), "protocol": "repeats"},
    "paper_mode": {"effects": ("vibration",), "protocol": "paper"},
    "paper_mode_delay": {"effects": ("vibration", "delay"), "protocol": "paper"},
    "holdout_delay": {"effects": ("delay",), "protocol": "mixed", "holdout_only": "delay"},
    "step_from_rest": {"effects": ("vibration",), "protocol": "mixed", "start": "rest"},
    "history": {"effects": ("initial_state",), "protocol": "mixed", "start": "history"},
    "sessions": {"effects": ("drift",), "protocol": "mixed", "sessions": True},
    "creep": {"effects": ("creep",), "protocol": "mixed"},
    "lowpass": {"effects": ("lowpass",), "protocol": "mixed"},
}


def draw_rig(rng: np.random.Generator, effects: Sequence[str], fs: float) -> Rig:
    """A stage with random parameters; only ``effects`` are visible above the noise. A
    stage always has a mode, well damped and far above the inputs' band unless
    ``vibration`` is an effect; the anti-aliasing filter sits at 0.35 fs."""
    rig = Rig(hyst=draw_hysteresis(rng), aa_hz=0.35 * fs, amp_hz=rng.uniform(20e3, 40e3))
    if "vibration" in effects:
        f = rng.uniform(600.0, min(1400.0, 0.2 * fs))
        rig.modes = [(f, math.exp(rng.uniform(math.log(0.01), math.log(0.04))))]
    else:
        rig.modes = [(min(0.3 * fs, rng.uniform(3e3, 6e3)), 0.5)]
    if "delay" in effects:
        rig.delays = {"clean": rng.uniform(2.5e-4, 1e-3)}
    if "creep" in effects:
        taus = sorted(float(x) for x in np.exp(rng.uniform(math.log(0.02), math.log(5.0), 2)))
        rig.creep = (taus, [rng.uniform(0.01, 0.04), rng.uniform(0.01, 0.04)])
    if "lowpass" in effects:
        rig.lowpass = (rng.uniform(300.0, 1500.0), int(rng.integers(1, 3)))
    rig.noise_std = rng.uniform(1e-4, 5e-4)
    return rig


def make_case(name: str, seed: int, fs: float = 10e3) -> dict[str, Any]:
    """One stage of class ``name``: a training record, two holdouts and a blind record
    (never given to the diagnosis), with the truth. Absolute time runs on across records
    (a second apart)."""
    spec = CLASSES[name]
    rng = np.random.default_rng(seed)
    effects = tuple(spec["effects"])
    only = spec.get("holdout_only")
    rig = draw_rig(rng, tuple(e for e in effects if e != only), fs)
    if only == "delay":
        rig.delays = {"clean": 0.0, "delayed": rng.uniform(2.5e-4, 1e-3)}
    if spec["protocol"] == "repeats":
        rig.wander_std = rng.uniform(5.0, 15.0) * rig.noise_std

    proto = spec["protocol"]
    if proto == "paper":
        kinds = ["ident", "steps", "sine50", "steps"]
    elif proto == "repeats":
        kinds = ["ident", "ident", "ident", "ident"]
    else:
        kinds = ["ident", "steps", "triangle", "sine"]
    wave_rng = np.random.default_rng(seed + 7919)
    waves = {"ident": wf_identification(fs, f=float(rng.uniform(5.0, 15.0)), periods=50)}
    recs = []
    t0 = 0.0
    sessions = rng.uniform(-1.0, 1.0, 4) if spec.get("sessions") else np.zeros(4)
    for i, kind in enumerate(kinds):
        if kind == "ident":
            u = waves["ident"]
        elif kind == "steps":
            u = wf_steps(fs, wave_rng, dwell=0.4 if "creep" in effects else 0.08)
        elif kind == "sine50":
            u = wf_sine(fs, 50.0, 0.6)
        elif kind == "triangle":
            u = wf_triangle(fs, float(rng.uniform(5.0, 20.0)), 1.0)
        else:
            u = wf_sine(fs, float(rng.uniform(10.0, 40.0)), 1.0)
        rest, history = None, ()
        if spec.get("start") == "rest":
            rest = float(rng.uniform(DAC_LO, DAC_LO + 0.5))
        elif spec.get("start") == "history":
            # Unrecorded excursions before the record: the memory is not "rose from 0 V".
            history = tuple(float(x) for x in rng.uniform(DAC_LO + 0.5, DAC_HI - 0.5, int(rng.integers(2, 5))))
        channel = "delayed" if (only == "delay" and i > 0) else "clean"
        rec = rig.record(u, fs, t0, rest=rest, history=history, channel=channel,
                         session_offset=float(sessions[i]), rng=rng)
        rec["kind"] = kind
        recs.append(rec)
        t0 = float(rec["t"][-1]) + 1.0
    truth = {"effects": effects, "dominant": effects[0] if effects else "none", "class": name,
             "modes": rig.modes if "vibration" in effects else [],
             "delay_s": (rig.delays.get("delayed") if only == "delay" else rig.delays["clean"]),
             # (A chain that carries the mode carries its lag: the delay found is the rest.)
             "timing_s": rig.timing_s(fs, modes="vibration" not in effects),
             "creep": rig.creep, "lowpass": rig.lowpass, "noise_std": rig.noise_std, "wander_std": rig.wander_std, "records": [r["truth"] for r in recs]}
    return {"name": name, "seed": seed, "fs": fs, "rig": rig, "truth": truth,
            "train": recs[0], "holdouts": recs[1:3], "blind": recs[3]}


def records(case: dict[str, Any]) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The training record and the holdouts as ``{"t", "u", "y"}`` dicts (what a user
    would hand to the diagnosis: no truth)."""
    strip = lambda r: {k: r[k] for k in ("t", "u", "y")}  # noqa: E731
    return strip(case["train"]), [strip(h) for h in case["holdouts"]]
