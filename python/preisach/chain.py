"""Chains of blocks (``docs/method/blocks.md``): the simulated stage, an identified model, a
model plus effects (what ``preisach diagnose --save-model`` writes) are one object,
:class:`Chain`, run by the Rust core (``preisach._preisach.Chain``); see
``docs/method/blocks.md`` for the block vocabulary and the JSON format.

JSON form (version 2)::

    {"format": "preisach-chain", "version": 2,
     "sample_rate_hz": 100000.0,          (optional: the stage's own rate)
     "initial_input": 0.0,                (optional: the input at rest before a record)
     "blocks": [{"type": "hysteresis", "source": "identified", ...},
                {"type": "delay", "delay_s": 3e-4}, ...],
     "report": {...}}                     (optional: a fit report, passed through)

Blocks run in list order; parameters are in physical units, so a chain runs at any
sample rate: :meth:`Chain.predict` (deterministic, the linear blocks by the first-order
hold) and :meth:`Chain.simulate` (per sample, with noise and quantization) take the rate
from the record's time column. Files of version 1 (a ``preisach-model``, a
``preisach-chain`` of a model and effects, a stage) load too; files are written as
version 2.
"""
from __future__ import annotations

import json
import math
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional, TypeVar, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from preisach import _preisach
from preisach._validate import as_number, as_signal, one_thread
from preisach.io import PathLike, write_text
from preisach.model import PreisachModel

if TYPE_CHECKING:
    from preisach._chain_inverse import ChainInverter

FORMAT = "preisach-chain"
VERSION = 2
_C = TypeVar("_C", bound="Chain")

#: Effects of :class:`Chain` (model, effects), in the order they are applied, with their
#: pinned parameter names.
EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    "rate": ("gain_s", "tau_s"),
    "creep": ("taus_s", "amplitudes"),
    "vibration": ("frequency_hz", "damping"),
    "lowpass": ("cutoff_hz", "order"),
    "delay": ("delay_s",),
    "drift": ("gain_per_s", "offset", "offset_per_s"),
}
ORDER = tuple(EFFECT_PARAMS)


def sample_period(t: ArrayLike, what: str = "t") -> float:
    """The sample period of a time column (seconds): ``t`` must increase strictly and
    be regular (within a quarter period of the line through its ends; the rounding of a
    stored time axis passes, a missing sample does not). Errors name ``what`` and the
    row."""
    try:
        tt = np.ascontiguousarray(t, dtype=np.float64).ravel()
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{what}: cannot be converted to a float64 array ({exc})") from None
    try:
        return float(_preisach.sample_period(tt))
    except ValueError as exc:
        msg = str(exc)
        raise ValueError(f"{what}{msg[1:]}" if msg.startswith("t:") else msg) from None


def _finite_numbers(x: Any) -> bool:
    """Every entry of the sequence ``x`` a finite number (checked at once: a model's
    masses are thousands of them)."""
    if isinstance(x, np.ndarray):
        return x.dtype.kind in "biuf" and bool(np.isfinite(x).all())
    try:
        return all(map(math.isfinite, x))
    except (TypeError, OverflowError):
        return False  # nested, not numbers, or too large for a float: entry by entry


def _non_finite(x: Any, path: str) -> Optional[str]:
    """Path of the first non-finite number inside nested dicts/lists, or None."""
    if isinstance(x, Mapping):
        for k, v in x.items():
            p = _non_finite(v, f"{path}.{k}" if path else str(k))
            if p is not None:
                return p
    elif isinstance(x, (list, tuple, np.ndarray)):
        if _finite_numbers(x):
            return None
        for i, v in enumerate(x):
            p = _non_finite(v, f"{path}[{i}]")
            if p is not None:
                return p
    elif isinstance(x, (float, np.floating)) and not math.isfinite(float(x)):
        return f"{path} = {float(x)}"
    return None


def _json_default(o: Any) -> Any:
    # numpy scalars and arrays in user-built dicts.
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    raise TypeError(f"{type(o).__name__} is not JSON serializable")


def _dumps(x: Any, what: str) -> str:
    """JSON text of ``x``; a non-finite number or an object JSON cannot hold is a
    ValueError naming ``what`` and where it is."""
    try:
        bad = _non_finite(x, "")
    except RecursionError:
        raise ValueError(f"{what}: nested too deeply") from None
    if bad is not None:
        name, _, value = bad.partition(" = ")
        raise ValueError(f"{what}: {name}: must be finite, got {value}")
    try:
        return json.dumps(x, allow_nan=False, default=_json_default)
    except (TypeError, ValueError, RecursionError) as exc:
        raise ValueError(f"{what}: cannot be written as JSON ({exc})") from None


def _blocks_json(blocks: Any) -> str:
    """JSON text of a list of block dicts; errors name the block."""
    if isinstance(blocks, (str, bytes)) or not isinstance(blocks, (list, tuple)):
        raise ValueError(f"blocks: expected a list of dicts, got {type(blocks).__name__}")
    texts = []
    for k, b in enumerate(blocks):
        if not isinstance(b, Mapping):
            raise ValueError(f"blocks[{k}]: expected a dict with a 'type' key, got {type(b).__name__}")
        texts.append(_dumps(dict(b), f"blocks[{k}] ({b.get('type', '?')})"))
    return "[" + ", ".join(texts) + "]"


def _check_finite(d: Any) -> None:
    """A parsed file holds no NaN or inf (Python's JSON reads them; the errors name the
    block and field)."""
    if isinstance(d, Mapping) and isinstance(d.get("blocks"), list):
        _blocks_json(d["blocks"])
    _dumps(d, "chain")


def _opt_float(name: str, x: Optional[float]) -> Optional[float]:
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name}: expected a number or None, got {x!r}")
    return float(x)


class Chain:
    """A chain of blocks; see the module doc.

    ``Chain(model, effects)``: an identified :class:`~preisach.PreisachModel` (or None)
    followed by effects, a list of ``{"name": ..., "params": {...}}`` dicts or a dict
    name -> params (``rate``, ``creep``, ``vibration``, ``lowpass``, ``delay``,
    ``drift``), applied in that fixed order; the model's fit report goes with it. :meth:`from_blocks` builds any chain;
    :class:`preisach.sim.Stage` is a chain built from blocks at a sample rate.

    A chain with a ``sample_rate_hz`` also runs sample by sample at that rate, keeping
    its state (``run``, ``step``, ``reset``, ``reset_state``, ``time_s``)."""

    _core: Any

    def __init__(self, model: Optional[PreisachModel] = None, effects: Any = ()) -> None:
        if model is not None and not isinstance(model, PreisachModel):
            raise ValueError(f"model: expected a preisach.PreisachModel or None, got {type(model).__name__}")
        if isinstance(effects, Mapping):
            eff: Any = dict(effects)
        elif isinstance(effects, (list, tuple)):
            eff = list(effects)
        else:
            raise ValueError(f"effects: expected a list of {{name, params}} dicts or a dict, got {effects!r}")
        text = _dumps(eff, "effects")
        if model is None:
            self._core = _preisach.Chain.from_effects(None, "stepwise", text)
            return
        report = None if model.report is None else _dumps(model.report.to_dict(), "report")
        self._core = _preisach.Chain.from_effects(model._core, model.output, text, report)

    @classmethod
    def _wrap(cls: type[_C], core: Any) -> _C:
        c = cls.__new__(cls)
        c._core = core
        return c

    @classmethod
    def from_blocks(cls: type[_C], blocks: Any, sample_rate_hz: Optional[float] = None,
                    initial_input: Optional[float] = None) -> _C:
        """A chain of ``blocks`` (dicts with a ``"type"`` key, see the module doc; a
        version-1 stage's block fields are read too)."""
        text = _blocks_json(blocks)
        fs = _opt_float("sample_rate_hz", sample_rate_hz)
        x0 = _opt_float("initial_input", initial_input)
        return cls._wrap(_preisach.Chain.from_blocks(text, fs, x0))

    # --- what it is ----------------------------------------------------------------
    def to_json(self) -> str:
        """The version-2 JSON text."""
        return str(self._core.to_json())

    def to_dict(self) -> dict[str, Any]:
        """The version-2 JSON-ready dict (``format``, ``version``, ``blocks``, ...)."""
        return dict(json.loads(self.to_json()))

    @property
    def blocks(self) -> list[dict[str, Any]]:
        """The blocks' parameters in signal order (copies; edit them and build a new chain)."""
        return list(self.to_dict()["blocks"])

    @property
    def sample_rate_hz(self) -> Optional[float]:
        """The chain's own sample rate, Hz (None: it runs only on records)."""
        fs = self._core.sample_rate_hz
        return None if fs is None else float(fs)

    @sample_rate_hz.setter
    def sample_rate_hz(self, fs: Optional[float]) -> None:
        self._core.sample_rate_hz = _opt_float("sample_rate_hz", fs)

    @property
    def initial_input(self) -> Optional[float]:
        """The input at which the stage rested before a record (None: its first input).
        Blocks start in equilibrium with it; if it differs from the first input, the
        first sample is a step."""
        x = self._core.initial_input
        return None if x is None else float(x)

    @initial_input.setter
    def initial_input(self, x: Optional[float]) -> None:
        self._core.initial_input = _opt_float("initial_input", x)

    @property
    def model(self) -> Optional[PreisachModel]:
        """The identified model of the first hysteresis block (None if the chain has no
        identified hysteresis block first among its hysteresis blocks)."""
        kinds = self._core.kinds()
        if "hysteresis" not in kinds:
            return None
        got = self._core.identified_model(kinds.index("hysteresis"))
        return None if got is None else PreisachModel._wrap(*got)

    @property
    def effects(self) -> dict[str, dict[str, Any]]:
        """The blocks after an identified model, name -> params (the pinned names; a
        vibration of one mode as ``frequency_hz``, ``damping``). ValueError if the chain
        is not a model followed by distinct effects (use :attr:`blocks`)."""
        blocks = self.blocks
        if blocks and blocks[0].get("type") == "hysteresis":
            if self.model is None:
                raise ValueError("effects: the chain's hysteresis is not an identified model; use .blocks")
            blocks = blocks[1:]
        out: dict[str, dict[str, Any]] = {}
        for b in blocks:
            name = b.pop("type")
            if name in out or name == "hysteresis":
                raise ValueError(f"effects: the chain has more than one {name} block; use .blocks")
            if name == "vibration" and len(b["modes"]) == 1:
                b = dict(b["modes"][0])
            out[name] = b
        return out

    def kinds(self) -> list[str]:
        """Block type names in signal order."""
        return list(self._core.kinds())

    # --- records -------------------------------------------------------------------
    @one_thread
    def predict(self, t: ArrayLike, u: ArrayLike, initial_input: Optional[float] = None) -> NDArray[np.float64]:
        """Deterministic output for input ``u`` sampled at times ``t`` (seconds, strictly
        increasing and regular; the rate is taken from ``t``, and ``t`` is the absolute
        time drift uses). Noise and quantizers are off; linear blocks are exact for an
        input linear between samples. ``initial_input`` overrides the chain's own."""
        return self._record(self._core.predict, t, u, initial_input)

    @one_thread
    def simulate(self, t: ArrayLike, u: ArrayLike, initial_input: Optional[float] = None) -> NDArray[np.float64]:
        """The simulated measurement of input ``u`` at times ``t``: sample by sample at
        the rate of ``t`` (input held over each sample interval), with noise (from its
        seeds) and quantization. A fresh run from rest every call."""
        return self._record(self._core.simulate, t, u, initial_input)

    @staticmethod
    def _record(run: Any, t: ArrayLike, u: ArrayLike, initial_input: Optional[float]) -> NDArray[np.float64]:
        tt, uu = as_signal("t", t), as_signal("u", u)
        if tt.shape != uu.shape:
            raise ValueError(f"u: length {uu.size} does not match t (length {tt.size})")
        return run(tt, uu, _opt_float("initial_input", initial_input))  # type: ignore[no-any-return]

    def response(self, f_hz: ArrayLike) -> NDArray[np.complex128]:
        """Frequency response of the chain's linear blocks (creep, vibration, lowpass,
        delay, sensor; any other block is an error) at ``f_hz``."""
        return self._core.response(as_signal("f_hz", f_hz, allow_empty=True))  # type: ignore[no-any-return]

    # --- the chain inverse -----------------------------------------------------------
    def inverter(self, fs: Optional[float] = None, lookahead: Optional[int] = None, method: str = "continuous",
                 bandwidth_hz: Optional[float] = None) -> "ChainInverter":
        """A streaming inverse of the chain at ``fs`` Hz (default: the chain's own rate):
        reference samples in, inputs out, :attr:`~preisach.ChainInverter.latency`
        samples late (see ``docs/method/inversion.md``, "Inverting a chain").

        ``lookahead``: the latency in samples (at least the chain's delay plus the
        low-pass's group delay, rounded up; for ``method="interpolated"`` what exceeds
        that is the interpolation's look-ahead); None = the least (``interpolated``: plus
        2000 samples). ``method``: the hysteresis inverse (``continuous``,
        ``interpolated``, ``closest``). ``bandwidth_hz``: the linear inverse's bandwidth
        (below Nyquist); None = twice the fastest lag of the chain's linear blocks, at
        most a tenth of ``fs``."""
        from preisach._chain_inverse import ChainInverter

        if fs is None:
            fs = self.sample_rate_hz
            if fs is None:
                raise ValueError("fs: the chain has no sample_rate_hz; give the rate of the reference")
        return ChainInverter(self, fs, method, lookahead, bandwidth_hz)

    def invert(self, r: ArrayLike, fs: Optional[float] = None, method: str = "continuous",
               bandwidth_hz: Optional[float] = None, lookahead: Optional[int] = None,
               return_info: bool = False) -> Any:
        """The input ``u`` whose chain output follows the reference ``r`` (1-D, finite,
        sampled at ``fs`` Hz, default the chain's own rate): feed-forward through the
        whole chain, ``u[n]`` belongs to ``r[n]`` (the preview is taken from ``r``
        itself; past its end the last sample is held). Equal to the streaming
        :meth:`inverter` once past its latency. Arguments as :meth:`inverter`;
        ``return_info`` also returns a :class:`~preisach.ChainInversionInfo`.

        A NaN or inf in ``r`` raises ``ValueError`` naming its index; so does a chain
        that cannot be inverted (naming the block). References that ask the hysteresis
        for an output beyond its reachable range are clipped, counted and reported in one
        :class:`~preisach.PreisachWarning`; so are inputs beyond what the chain's
        amplifier (``saturation``) or DAC (a quantizer's ``range``) accepts."""
        from preisach._chain_inverse import ChainInversionInfo

        rr = as_signal("r", r)
        inv = self.inverter(fs, lookahead, method, bandwidth_hz)
        u, sat = inv.invert(rr)
        if sat:
            from preisach.model import PreisachWarning

            warnings.warn(f"{sat} of {rr.size} reference samples ask the hysteresis for an output beyond its "
                          "reachable range: they were clipped (the input stays at the end of u_range there)",
                          PreisachWarning, stacklevel=2)
        if inv.clipped:
            from preisach.model import PreisachWarning

            lo, hi = inv.input_limits or (-np.inf, np.inf)
            first = inv._first_clipped
            warnings.warn(f"{inv.clipped} of {rr.size} inputs were clipped to the range the chain's amplifier/DAC "
                          f"accepts, [{lo:g}, {hi:g}] (first at index {first})", PreisachWarning, stacklevel=2)
        if return_info:
            return u, ChainInversionInfo(method=inv.method, latency=inv.latency, preview_s=inv.preview_s,
                                         bandwidth_hz=inv.bandwidth_hz, saturated=sat, clipped=inv.clipped)
        return u

    # --- per sample at the chain's own rate ------------------------------------------
    @property
    @one_thread
    def time_s(self) -> float:
        """Absolute time of the next sample, seconds (drift depends on it)."""
        return float(self._core.time_s)

    @time_s.setter
    @one_thread
    def time_s(self, t: float) -> None:
        self._core.time_s = as_number("time_s", t)

    @one_thread
    def run(self, u: ArrayLike) -> NDArray[np.float64]:
        """Run the input ``u`` (1-D, finite) from the current state at the chain's own
        rate; returns ``y`` (float64, same length). State and time carry over."""
        return self._core.run(as_signal("u", u, allow_empty=True))  # type: ignore[no-any-return]

    @one_thread
    def step(self, u: float) -> float:
        """One sample."""
        if isinstance(u, bool) or not isinstance(u, (int, float, np.integer, np.floating)):
            raise ValueError(f"u: expected a number, got {u!r}")
        return float(self._core.step(float(u)))

    @one_thread
    def reset(self) -> None:
        """Back to rest, time 0, noise streams from their seeds: a replay is identical.
        The next sample finds every block in equilibrium with the initial input."""
        self._core.reset()

    @one_thread
    def reset_state(self) -> None:
        """Back to rest for a new record; absolute time and noise streams run on."""
        self._core.reset_state()

    def copy(self: _C) -> _C:
        """An independent copy (same parameters and state)."""
        return type(self)._wrap(self._core.copy())

    # --- files ---------------------------------------------------------------------
    @classmethod
    def from_json(cls: type[_C], text: Union[str, bytes]) -> _C:
        """A chain from JSON text of any chain, model or stage file (version 1 or 2)."""
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        if not isinstance(text, str):
            raise ValueError(f"text: expected a JSON string, got {type(text).__name__}")
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ValueError(f"corrupt chain: not JSON ({exc})") from None
        except RecursionError:
            raise ValueError("corrupt chain: not JSON (nested too deeply)") from None
        _check_finite(d)
        return cls._wrap(_preisach.Chain.from_json(text))

    @classmethod
    def from_dict(cls: type[_C], d: Any, source: str = "chain") -> _C:
        """A chain from a dict of any chain, model or stage file; errors name ``source``."""
        if not isinstance(d, Mapping):
            raise ValueError(f"corrupt {source}: expected a JSON object")
        try:
            _check_finite(d)
            return cls._wrap(_preisach.Chain.from_json(_dumps(d, "chain")))
        except ValueError as exc:
            raise ValueError(str(exc) if source in ("chain", "model") else f"{source}: {exc}") from None

    def save(self, path: PathLike) -> None:
        """Write the chain as version-2 JSON (atomically)."""
        write_text(path, self.to_json() + "\n")

    @classmethod
    def load(cls: type[_C], path: PathLike) -> _C:
        """Read any chain, model or stage file."""
        p = Path(path)
        try:
            text = p.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ValueError(f"{p}: cannot read ({exc})") from None
        try:
            return cls.from_json(text)
        except ValueError as exc:
            raise ValueError(f"{p}: {exc}") from None

    def __repr__(self) -> str:
        fs = self.sample_rate_hz
        rate = "" if fs is None else f", sample_rate_hz={fs:g}"
        return f"{type(self).__name__}({' -> '.join(self.kinds())}{rate})"


def load(path: PathLike) -> Union[PreisachModel, Chain]:
    """Read a model, chain or stage file (version 1 or 2): a
    :class:`~preisach.PreisachModel` when the file is one identified hysteresis block,
    else a :class:`Chain`."""
    chain = Chain.load(path)
    model = PreisachModel._of_chain(chain)
    return chain if model is None else model
