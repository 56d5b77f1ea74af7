"""The plant simulator and the 100 kHz hardware-in-the-loop style sample loop.

A :class:`Stage` is a :class:`~preisach.Chain` of blocks (amplifier, hysteresis, rate,
creep, vibration, sensor, lowpass, delay, noise, quantizer, drift; see
``docs/method/blocks.md``) at its own sample rate, run one sample at a time in Rust;
:meth:`~preisach.Chain.simulate` runs it on a record at the record's own rate. The
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

A record starts at rest: blocks start in equilibrium with the stage's initial input (by
default the first sample). After construction, :meth:`Stage.reset` and
:meth:`Stage.reset_state`, every stateful linear block (low-pass filters, vibration
modes, creep elements, delay line, the amplifier's slew limiter) sets its state to the
steady state for that input, so a constant input gives a constant output from the first
sample (no ringing of the 780 Hz mode at the start of a run). The hysteresis memory
starts with all relays down, then the initial input; drift and noise are unaffected.

:func:`run_loop` drives a stage (or any chain with a sample rate, e.g. a diagnosed
chain) with a compensator built from a
:class:`~preisach.PreisachModel` (the streaming inverse) and times every sample
against the sample period (10 µs at 100 kHz).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from preisach import _preisach
from preisach._validate import as_signal
from preisach.chain import VERSION, Chain, _blocks_json, _dumps

__all__ = ["Stage", "LoopResult", "Timing", "run_loop", "hysteresis_block", "CHAIN_VERSION", "METHODS"]

#: Version of the chain JSON format written by this build.
CHAIN_VERSION = VERSION
#: Compensators :func:`run_loop` can build.
METHODS = ("continuous", "interpolated", "closest", "identity")
#: Default look-ahead of the ``interpolated`` method in :func:`run_loop`, samples.
DEFAULT_LOOKAHEAD = 2000


class Stage(Chain):
    """A simulated stage: a :class:`~preisach.Chain` of plant blocks at its own sample
    rate, with its state.

    Parameters
    ----------
    blocks : sequence of dict
        Blocks in signal order, each a dict with a ``"type"`` key and the block's
        parameters, e.g. ``{"type": "vibration", "modes": [{"frequency_hz": 780,
        "damping": 0.02}]}`` (the chain JSON format, ``docs/method/blocks.md``; the
        fields of version-1 stage files, e.g. ``freq_hz``, are read too).
    sample_rate_hz : float
        The stage's own rate (default 100 kHz): what :meth:`run`, :meth:`step` and
        :func:`run_loop` use. :meth:`~preisach.Chain.simulate` runs at any record's rate.

    Notes
    -----
    Bad parameters raise ``ValueError`` naming the parameter and the block.
    Use :meth:`preset` for a ready-made stage and :meth:`from_json` to load one.
    """

    def __init__(self, blocks: Sequence[Mapping[str, Any]], sample_rate_hz: float = 100_000.0) -> None:
        if isinstance(sample_rate_hz, bool) or not isinstance(sample_rate_hz, (int, float, np.integer, np.floating)):
            raise ValueError(f"sample_rate_hz: expected a number, got {sample_rate_hz!r}")
        fs = float(sample_rate_hz)
        if not math.isfinite(fs) or fs <= 0:
            raise ValueError(f"sample_rate_hz: must be finite and > 0, got {fs}")
        self._core = _preisach.Chain.from_blocks(_blocks_json(blocks), fs, None)
        self._core.check_stage()

    @classmethod
    def preset(cls, name: str = "paper", **overrides: Any) -> "Stage":
        """A named stage. ``"paper"`` (see the module doc) takes the overrides
        ``delay`` (bool: 4.58e-4 s on/off, or seconds), ``seed``, ``noise_std`` (V),
        ``n_h``, ``resonance_hz``, ``damping``, ``creep`` (bool), ``creep_per_decade``,
        ``lowpass_hz``, ``lowpass_order``, ``dac_bits``, ``adc_bits`` (0 = ideal),
        ``drift_gain_per_s``, ``drift_offset_per_s``, ``sample_rate_hz``."""
        if not isinstance(name, str):
            raise ValueError(f"name: expected a preset name, got {name!r}")
        text = _dumps(overrides, f"preset {name!r}")
        return cls._wrap(_preisach.Chain.preset(name, text))

    @classmethod
    def from_json(cls, text: Any) -> "Stage":
        """Load a stage from the JSON text of any chain, model or stage file (version 1
        or 2). Malformed JSON raises ``ValueError('corrupt chain: ...')``."""
        st = cls._wrap(Chain.from_json(text)._core)
        if st.sample_rate_hz is not None:
            st._core.check_stage()
        return st


def hysteresis_block(model: Any, interpolated: bool = True) -> dict[str, Any]:
    """A ``hysteresis`` block dict holding an identified :class:`~preisach.PreisachModel`
    (so a stage can be "identified model + effects"). ``interpolated`` selects the
    continuous output (default) or the stepwise staircase."""
    block = Chain(model).blocks[0]
    block["output"] = "interpolated" if interpolated else "stepwise"
    return block


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


def run_loop(model: Any, stage: Chain, reference: ArrayLike, method: str = "continuous",
             lookahead: Optional[int] = None, bandwidth_hz: Optional[float] = None) -> LoopResult:
    """Run the hardware-in-the-loop style sample loop: reference → compensator → DAC →
    plant chain → sensor, one sample at a time in Rust, timed per sample.

    Parameters
    ----------
    model : PreisachModel, Chain or None
        What the compensator inverts. A :class:`~preisach.PreisachModel` (the
        hysteresis inverse alone; it maps the stage's input, DAC volts, to its output);
        a :class:`~preisach.Chain` holding an identified model (e.g. a diagnosed chain):
        the chain inverse (:meth:`~preisach.Chain.inverter` at the stage's rate, the
        reference fed ahead by its latency); ``None`` only for ``method="identity"``.
    stage : Stage or Chain
        The plant, run at its own sample rate (a chain without one, e.g. a diagnosed
        chain saved without it, is refused); it is reset first (rest, time 0) and left in
        its final state.
    reference : 1-D array
        Desired output, in the stage's output units (sensor volts for ``paper``).
    method : {"continuous", "interpolated", "closest", "identity"}
        ``continuous``: exact inverse of the interpolated model (no look-ahead);
        ``interpolated``: closest match smoothed by linear interpolation (the paper's Fig. 9),
        streaming with ``lookahead`` samples of preview (default 2000); the reference
        is fed ahead by that much so ``u`` lines up with it (feed-forward);
        ``closest``: closest match (steps); ``identity``: ``u = reference``. With a
        chain, the hysteresis inverse inside the chain inverse.
    lookahead : int, optional
        Only for ``interpolated``; with a chain, the chain inverter's latency.
    bandwidth_hz : float, optional
        Only with a chain: the linear inverse's bandwidth (default: see
        :meth:`~preisach.Chain.inverter`).

    Returns
    -------
    LoopResult
        The input, output, error and timing of the run.
    """
    if not isinstance(stage, Chain):
        raise ValueError(f"stage: expected a preisach.sim.Stage or a preisach.Chain, got {type(stage).__name__}")
    if method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(repr(m) for m in METHODS)}, got {method!r}")
    r = as_signal("reference", reference)
    if isinstance(model, Chain):
        if method == "identity":
            raise ValueError("method: 'identity' takes no model; pass model=None")
        fs = stage.sample_rate_hz
        if fs is None:
            raise ValueError("stage: the chain has no sample_rate_hz to run at")
        inv = model.inverter(fs, lookahead=lookahead, method=method, bandwidth_hz=bandwidth_hz)
        d = _preisach.run_loop_chain(inv._stream, stage._core, r)
        return _loop_result(d)
    if bandwidth_hz is not None:
        raise ValueError("bandwidth_hz: only meaningful when model is a Chain")
    if method == "interpolated" and lookahead is None:
        lookahead = DEFAULT_LOOKAHEAD
    if lookahead is not None:
        if method != "interpolated":
            raise ValueError(f"lookahead: only meaningful for method 'interpolated', not {method!r}")
        if isinstance(lookahead, bool) or not isinstance(lookahead, (int, np.integer)) or not 0 <= lookahead < 2**63:
            raise ValueError(f"lookahead: expected an integer in 0 .. 2**63 - 1, got {lookahead!r}")
        lookahead = int(lookahead)
    core = None
    if method != "identity":
        core = getattr(model, "_core", None)
        if not isinstance(core, _preisach.Model):
            raise ValueError("model: expected a preisach.PreisachModel or a preisach.Chain, "
                             f"got {type(model).__name__}")
    d = _preisach.run_loop(core, stage._core, r, method, lookahead)
    return _loop_result(d)


def _loop_result(d: Any) -> LoopResult:
    timing = Timing(float(d["mean_ns"]), float(d["p99_ns"]), float(d["max_ns"]), int(d["misses"]),
                    float(d["budget_ns"]), int(d["samples"]))
    return LoopResult(u=d["u"], y=d["y"], error=d["error"], timing=timing)
