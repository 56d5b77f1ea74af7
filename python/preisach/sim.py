"""The plant simulator and the 100 kHz hardware-in-the-loop style sample loop.

A :class:`Stage` is a chain of blocks (amplifier, hysteresis, creep, vibration, sensor,
lowpass, delay, noise, quantizer, drift) run one sample at a time in Rust. The
``paper`` preset mirrors the stage of Stakvik et al. (2015, §3.1):

| block | what (units) |
|---|---|
| quantizer | 16-bit DAC, ±10 V (input ``u``: DAC volts; usable 0–7.5 V) |
| lowpass | reconstruction filter, 2nd-order Butterworth at 20 kHz |
| amplifier | 20 V/V, saturation [−30, 180] V (piezo volts) |
| hysteresis | parametric Preisach on a 500-level grid, piezo V → µm (0–~40 µm) |
| creep | Kelvin–Voigt, 1 % per decade from 0.1 s to 100 s |
| vibration | one mode at 780 Hz, damping 0.02 (unit DC gain) |
| sensor | 1/5 V/µm, 4th-order anti-aliasing at 20 kHz, 1 nm noise, 16-bit ADC; 4.58e-4 s delay if ``delay=True`` |

The output ``y`` is the sensor voltage (0.2 V per µm).

A record starts at rest: blocks start in equilibrium with the first sample. After
construction, :meth:`Stage.reset` and :meth:`Stage.reset_state`, every stateful linear
block (low-pass filters, vibration modes, creep elements, delay line, the amplifier's
slew limiter) sets its state to the steady state for the first input, so a constant
input gives a constant output from the first sample (no ringing of the 780 Hz mode at
the start of a run). The hysteresis memory starts with all relays down, then the first
input; drift and noise are unaffected.

:func:`run_loop` drives a stage with a compensator built from a
:class:`~preisach.PreisachModel` (the streaming inverse) and times every sample
against the sample period (10 µs at 100 kHz).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from preisach import _preisach
from preisach._validate import as_signal

__all__ = ["Stage", "LoopResult", "Timing", "run_loop", "hysteresis_block", "CHAIN_VERSION", "METHODS"]

#: Version of the chain JSON format written by this build.
CHAIN_VERSION = 1
#: Compensators :func:`run_loop` can build.
METHODS = ("continuous", "interpolated", "closest", "identity")
#: Default look-ahead of the ``interpolated`` method in :func:`run_loop`, samples.
DEFAULT_LOOKAHEAD = 2000


class Stage:
    """A simulated stage: a chain of plant blocks with its state.

    Parameters
    ----------
    blocks : sequence of dict
        Blocks in signal order, each a dict with a ``"type"`` key and the block's
        parameters, e.g. ``{"type": "vibration", "modes": [{"freq_hz": 780,
        "damping": 0.02}]}`` (the chain JSON format; see the README / ``to_json()``).
    sample_rate_hz : float
        Sample rate every block is discretized for (default 100 kHz).

    Notes
    -----
    Bad parameters raise ``ValueError`` naming the parameter and the block.
    Use :meth:`preset` for a ready-made stage and :meth:`from_json` to load one.
    """

    def __init__(self, blocks: Sequence[Mapping[str, Any]], sample_rate_hz: float = 100_000.0) -> None:
        if isinstance(blocks, (str, bytes)) or not isinstance(blocks, Sequence):
            raise ValueError(f"blocks: expected a list of dicts, got {type(blocks).__name__}")
        for k, b in enumerate(blocks):
            if not isinstance(b, Mapping):
                raise ValueError(f"blocks[{k}]: expected a dict with a 'type' key, got {type(b).__name__}")
        if isinstance(sample_rate_hz, bool) or not isinstance(sample_rate_hz, (int, float, np.integer, np.floating)):
            raise ValueError(f"sample_rate_hz: expected a number, got {sample_rate_hz!r}")
        fs = float(sample_rate_hz)
        if not math.isfinite(fs) or fs <= 0:
            raise ValueError(f"sample_rate_hz: must be finite and > 0, got {fs}")
        for k, b in enumerate(blocks):
            bad = _non_finite(b, "")
            if bad is not None:
                name, _, value = bad.partition(" = ")
                raise ValueError(f"{name}: must be finite, got {value} (blocks[{k}], {b.get('type', '?')})")
        try:
            text = json.dumps({"version": CHAIN_VERSION, "sample_rate_hz": fs, "blocks": [dict(b) for b in blocks]},
                              allow_nan=False, default=_json_default)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"blocks: cannot be written as JSON ({exc})") from None
        self._core = _preisach.Chain.from_json(text)

    @classmethod
    def _wrap(cls, core: Any) -> "Stage":
        s = cls.__new__(cls)
        s._core = core
        return s

    @classmethod
    def preset(cls, name: str = "paper", **overrides: Any) -> "Stage":
        """A named stage. ``"paper"`` (see the module doc) takes the overrides
        ``delay`` (bool: 4.58e-4 s on/off, or seconds), ``seed``, ``noise_std`` (V),
        ``n_h``, ``resonance_hz``, ``damping``, ``creep`` (bool), ``creep_per_decade``,
        ``lowpass_hz``, ``lowpass_order``, ``dac_bits``, ``adc_bits`` (0 = ideal),
        ``drift_gain_per_s``, ``drift_offset_per_s``, ``sample_rate_hz``."""
        if not isinstance(name, str):
            raise ValueError(f"name: expected a preset name, got {name!r}")
        bad = _non_finite(overrides, "")
        if bad is not None:
            name_, _, value = bad.partition(" = ")
            raise ValueError(f"{name_}: must be finite, got {value} (preset {name!r})")
        try:
            text = json.dumps(overrides, allow_nan=False, default=_json_default)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"overrides: cannot be written as JSON ({exc})") from None
        return cls._wrap(_preisach.Chain.preset(name, text))

    @classmethod
    def from_json(cls, text: str) -> "Stage":
        """Load a stage from chain JSON text (as written by :meth:`to_json`).
        Malformed JSON raises ``ValueError('corrupt chain: ...')``."""
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        if not isinstance(text, str):
            raise ValueError(f"text: expected a JSON string, got {type(text).__name__}")
        return cls._wrap(_preisach.Chain.from_json(text))

    def to_json(self) -> str:
        """The versioned chain JSON (parameters only, no state)."""
        return str(self._core.to_json())

    def to_dict(self) -> dict[str, Any]:
        """The chain JSON as a dict (``version``, ``sample_rate_hz``, ``blocks``)."""
        return dict(json.loads(self.to_json()))

    @property
    def blocks(self) -> list[dict[str, Any]]:
        """The blocks' parameters in signal order (copies; edit and build a new Stage)."""
        return list(self.to_dict()["blocks"])

    @property
    def sample_rate_hz(self) -> float:
        """Sample rate, Hz."""
        return float(self._core.sample_rate_hz)

    @property
    def time_s(self) -> float:
        """Absolute time of the next sample, seconds (drift depends on it)."""
        return float(self._core.time_s)

    @time_s.setter
    def time_s(self, t: float) -> None:
        self._core.time_s = float(t)

    def run(self, u: ArrayLike) -> NDArray[np.float64]:
        """Run the input ``u`` (1-D, finite) from the current state; returns ``y``
        (float64, same length). State and time carry over to the next call."""
        return self._core.run(as_signal("u", u, allow_empty=True))  # type: ignore[no-any-return]

    def step(self, u: float) -> float:
        """One sample."""
        if isinstance(u, bool) or not isinstance(u, (int, float, np.integer, np.floating)):
            raise ValueError(f"u: expected a number, got {u!r}")
        return float(self._core.step(float(u)))

    def reset(self) -> None:
        """Back to rest, time 0, noise streams from their seeds: a replay is identical.
        The next sample finds every block in equilibrium with it."""
        self._core.reset()

    def reset_state(self) -> None:
        """Back to rest for a new record (every block in equilibrium with the next
        sample); absolute time and noise streams run on."""
        self._core.reset_state()

    def copy(self) -> "Stage":
        """An independent copy (same parameters and state)."""
        return Stage._wrap(self._core.copy())

    def __repr__(self) -> str:
        return f"Stage({' -> '.join(self._core.kinds())}, sample_rate_hz={self.sample_rate_hz:g})"


def hysteresis_block(model: Any, interpolated: bool = True) -> dict[str, Any]:
    """A ``hysteresis`` block dict holding an identified :class:`~preisach.PreisachModel`
    (so a stage can be "identified model + effects"). ``interpolated`` selects the
    continuous output (default) or the stepwise staircase."""
    w = np.asarray(model.weights, dtype=np.float64)
    n = w.shape[0]
    lo, hi = model.u_range
    return {
        "type": "hysteresis",
        "source": "identified",
        "lo": float(lo),
        "hi": float(hi),
        "n_h": int(n),
        # Packed upper triangle, row by row (i <= j): the core's cell order.
        "weights": w[np.triu_indices(n)].tolist(),
        "offset": float(model.offset),
        "interpolated": bool(interpolated),
    }


@dataclass(frozen=True)
class Timing:
    """Per-sample wall-clock time of a loop run (compensator + simulated plant),
    in nanoseconds; ``misses`` counts samples over ``budget_ns`` (one sample period)."""

    mean_ns: float
    p99_ns: float
    max_ns: float
    misses: int
    budget_ns: float
    samples: int


@dataclass(frozen=True)
class LoopResult:
    """What :func:`run_loop` returns.

    ``u``: compensator output (DAC command); ``y``: measured output (sensor volts);
    ``error``: ``reference - y``; ``timing``: a :class:`Timing`."""

    u: NDArray[np.float64]
    y: NDArray[np.float64]
    error: NDArray[np.float64]
    timing: Timing


def run_loop(model: Any, stage: Stage, reference: ArrayLike, method: str = "continuous",
             lookahead: Optional[int] = None) -> LoopResult:
    """Run the hardware-in-the-loop style sample loop: reference → compensator → DAC →
    plant chain → sensor, one sample at a time in Rust, timed per sample.

    Parameters
    ----------
    model : PreisachModel or None
        The identified model the compensator inverts (``None`` only for
        ``method="identity"``). It maps the stage's input (DAC volts) to its output.
    stage : Stage
        The plant; it is reset first (rest, time 0) and left in its final state.
    reference : 1-D array
        Desired output, in the stage's output units (sensor volts for ``paper``).
    method : {"continuous", "interpolated", "closest", "identity"}
        ``continuous``: exact inverse of the interpolated model (no look-ahead);
        ``interpolated``: closest match smoothed by linear interpolation (the paper's Fig. 9),
        streaming with ``lookahead`` samples of preview (default 2000); the reference
        is fed ahead by that much so ``u`` lines up with it (feed-forward);
        ``closest``: closest match (steps); ``identity``: ``u = reference``.
    lookahead : int, optional
        Only for ``interpolated``.

    Returns
    -------
    LoopResult
        The input, output, error and timing of the run.
    """
    if not isinstance(stage, Stage):
        raise ValueError(f"stage: expected a preisach.sim.Stage, got {type(stage).__name__}")
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(repr(m) for m in METHODS)}, got {method!r}")
    if method == "interpolated" and lookahead is None:
        lookahead = DEFAULT_LOOKAHEAD
    if lookahead is not None:
        if method != "interpolated":
            raise ValueError(f"lookahead: only meaningful for method 'interpolated', not {method!r}")
        if isinstance(lookahead, bool) or not isinstance(lookahead, (int, np.integer)) or lookahead < 0:
            raise ValueError(f"lookahead: expected an integer >= 0, got {lookahead!r}")
        lookahead = int(lookahead)
    core = None
    if method != "identity":
        core = getattr(model, "_core", None)
        if not isinstance(core, _preisach.Model):
            raise ValueError(f"model: expected a preisach.PreisachModel, got {type(model).__name__}")
    r = as_signal("reference", reference)
    d = _preisach.run_loop(core, stage._core, r, method, lookahead)
    timing = Timing(float(d["mean_ns"]), float(d["p99_ns"]), float(d["max_ns"]), int(d["misses"]),
                    float(d["budget_ns"]), int(d["samples"]))
    return LoopResult(u=d["u"], y=d["y"], error=d["error"], timing=timing)


def _non_finite(x: Any, path: str) -> Optional[str]:
    """Path of the first non-finite number inside nested dicts/lists, or None."""
    if isinstance(x, Mapping):
        for k, v in x.items():
            p = _non_finite(v, f"{path}.{k}" if path else str(k))
            if p is not None:
                return p
    elif isinstance(x, (list, tuple, np.ndarray)):
        for i, v in enumerate(x):
            p = _non_finite(v, f"{path}[{i}]")
            if p is not None:
                return p
    elif isinstance(x, (float, np.floating)) and not math.isfinite(float(x)):
        return f"{path} = {float(x)}"
    return None


def _json_default(o: Any) -> Any:
    # numpy scalars and arrays in user-built block dicts.
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON serializable")
