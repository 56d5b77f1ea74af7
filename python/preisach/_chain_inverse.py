"""The chain inverse: feed-forward through a whole chain (``docs/method/inversion.md``,
"Inverting a chain").

For a known reference ``r`` (a planned trajectory), the input ``u`` whose chain output
follows ``r``: the linear blocks after the hysteresis (creep, modes, low-passes, the
sensor's gain, filter and delay) are inverted with a stable inverse limited to a stated
bandwidth (``G⁻¹ F``, ``F`` a Butterworth low-pass), their delay and the low-pass's group
delay are taken back by preview, a final drift is undone, then the hysteresis inverse
(any method) gives the hysteresis input, and the inverse of what comes before the
hysteresis (the amplifier's gain, a reconstruction filter) the chain's input. Noise and
quantizers are left out. A chain without an identified hysteresis, with a parametric
one, a rate block, a non-minimum-phase linear block or a bandwidth at or above Nyquist
is refused with a ``ValueError`` naming the block or argument.
"""
from __future__ import annotations

import numbers
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np
from numpy.typing import ArrayLike, NDArray

from preisach import _preisach
from preisach._inverse import METHODS, _as_signal

__all__ = ["ChainInverter", "ChainInversionInfo"]

_STATE_KEYS = ("n", "post", "shift", "pre", "memory", "saturated", "t", "u_prev", "last_cm", "knot_t", "knot_v",
               "r_prev")


@dataclass(frozen=True)
class ChainInversionInfo:
    """What ``Chain.invert(..., return_info=True)`` reports besides the input.

    Attributes:
        method: the hysteresis inverse used.
        latency: the streaming inverter's lag, samples (the look-ahead it needs).
        preview_s: the chain's delay plus the low-pass's group delay, seconds.
        bandwidth_hz: the bandwidth of the linear inverse.
        saturated: references whose hysteresis output is outside the model's reachable range.
        clipped: inputs clipped to the range the chain accepts (see :attr:`ChainInverter.input_limits`).
    """

    method: str
    latency: int
    preview_s: float
    bandwidth_hz: float
    saturated: int
    clipped: int = 0


def _fs(sample_rate_hz: Any) -> float:
    if isinstance(sample_rate_hz, bool) or not isinstance(sample_rate_hz, numbers.Real):
        raise ValueError(f"fs: expected a sample rate in Hz, got {sample_rate_hz!r}")
    fs = float(sample_rate_hz)
    if not np.isfinite(fs) or fs <= 0:
        raise ValueError(f"fs: must be finite and > 0, got {fs}")
    return fs


def input_limits(blocks: list[dict[str, Any]]) -> Optional[tuple[float, float]]:
    """The chain inputs the blocks before the hysteresis accept without clipping: a
    quantizer's ``range`` (the DAC) and an amplifier's ``saturation``, each taken back to
    the chain's input through the static gains in front of it; None if nothing clips."""
    from preisach.chain import Chain

    lo, hi, gain = -np.inf, np.inf, 1.0
    for b in blocks:
        kind = b["type"]
        if kind == "hysteresis":
            break
        if kind == "amplifier":
            gain *= float(b.get("gain", 1.0))
        elif kind in ("noise", "quantizer", "drift"):
            pass
        else:
            gain *= float(np.real(Chain.from_blocks([b]).response(np.array([0.0]))[0]))
        limits = b.get("range") if kind == "quantizer" else b.get("saturation") if kind == "amplifier" else None
        if limits is not None and gain != 0.0 and np.isfinite(gain):
            a, c = sorted((float(limits[0]) / gain, float(limits[1]) / gain))
            lo, hi = max(lo, a), min(hi, c)
    return (lo, hi) if np.isfinite(lo) or np.isfinite(hi) else None


def _opt_int(name: str, x: Any) -> Optional[int]:
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, numbers.Integral) or x < 0:
        raise ValueError(f"{name}: expected an integer >= 0 or None, got {x!r}")
    return int(x)


def _opt_bandwidth(x: Any) -> Optional[float]:
    if x is None:
        return None
    if isinstance(x, bool) or not isinstance(x, numbers.Real):
        raise ValueError(f"bandwidth_hz: expected a frequency in Hz or None, got {x!r}")
    return float(x)


class ChainInverter:
    """Streaming chain inverse: one reference sample in, one input sample out, no
    allocation per sample (the per-sample path is in Rust). Build it with
    :meth:`preisach.Chain.inverter`.

    The output lags the reference by :attr:`latency` samples: ``step(r[n])`` returns
    ``u[n - latency]``, so a reference known ahead (a planned trajectory) is fed
    ``latency`` samples early. The first ``latency`` outputs belong to the rest before
    the record. Once past them the stream equals :meth:`preisach.Chain.invert`.
    """

    def __init__(self, chain: Any, fs: float, method: str = "continuous", lookahead: Optional[int] = None,
                 bandwidth_hz: Optional[float] = None) -> None:
        if not isinstance(method, str) or method not in METHODS:
            raise ValueError(f"method: expected one of {', '.join(map(repr, METHODS))}, got {method!r}")
        self._fs = _fs(fs)
        self._stream = _preisach.ChainInverseStream(chain._core, self._fs, method, _opt_int("lookahead", lookahead),
                                                    _opt_bandwidth(bandwidth_hz))
        limits = input_limits(chain.blocks)
        self._lo, self._hi = limits if limits is not None else (-np.inf, np.inf)
        self._clipped = 0
        self._first_clipped: Optional[int] = None

    def _clip(self, u: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.clip(u, self._lo, self._hi)
        hit = out != u
        if self._first_clipped is None and hit.any():
            self._first_clipped = int(np.argmax(hit))
        self._clipped += int(np.count_nonzero(hit))
        return out

    @property
    def method(self) -> str:
        """The hysteresis inverse."""
        return str(self._stream.method)

    @property
    def sample_rate_hz(self) -> float:
        """The rate the inverse is sampled for, Hz."""
        return self._fs

    @property
    def latency(self) -> int:
        """The output's lag behind the reference, samples (the look-ahead the inverse
        needs: the chain's delay and the low-pass's group delay, rounded up, plus the
        interpolated method's own look-ahead)."""
        return int(self._stream.latency)

    @property
    def latency_s(self) -> float:
        """:attr:`latency` in seconds."""
        return self.latency / self._fs

    @property
    def preview_s(self) -> float:
        """The chain's delay plus the low-pass's group delay at low frequency, seconds."""
        return float(self._stream.preview_s)

    @property
    def bandwidth_hz(self) -> float:
        """The bandwidth of the linear inverse (its Butterworth low-pass), Hz."""
        return float(self._stream.bandwidth_hz)

    @property
    def saturated(self) -> int:
        """References so far whose hysteresis output was outside the model's reachable range."""
        return int(self._stream.saturated)

    @property
    def input_limits(self) -> Optional[tuple[float, float]]:
        """The chain inputs its blocks before the hysteresis pass unclipped (a quantizer's
        ``range``, an amplifier's ``saturation``, through the static gains in front of
        them); outputs are clipped to it. None if the chain states no limit."""
        return None if (self._lo, self._hi) == (-np.inf, np.inf) else (float(self._lo), float(self._hi))

    @property
    def clipped(self) -> int:
        """Inputs so far clipped to :attr:`input_limits`."""
        return self._clipped

    def step(self, r: float) -> float:
        """One reference sample in, the input ``latency`` samples earlier out."""
        u = float(self._stream.step(float(r)))
        if not self._lo <= u <= self._hi:
            self._clipped += 1
            u = min(max(u, self._lo), self._hi)
        return u

    def process(self, block: ArrayLike) -> NDArray[np.float64]:
        """A block of reference samples in, as many input samples out (as :meth:`step`
        on each); a non-finite sample raises, naming its index, before any state changes."""
        return self._clip(self._stream.process(_as_signal("r", block)))

    def reset(self) -> None:
        """Back to the start: filters at rest with the next reference, the hysteresis
        inverse at negative saturation, time 0."""
        self._stream.reset()
        self._clipped, self._first_clipped = 0, None

    @property
    def state(self) -> dict[str, Any]:
        """Snapshot: ``n`` (samples so far), the linear inverses' states ``post`` and
        ``pre`` and the fractional delay line ``shift`` (arrays), and the hysteresis
        inverse's state (``memory``, ``saturated``, ``t``, ``u_prev``, ``last_cm``,
        ``knot_t``, ``knot_v``, ``r_prev``, as :attr:`preisach.Inverter.state`). Assign it
        back to this or an inverter built the same way to resume exactly."""
        return dict(self._stream.get_state(), clipped=self._clipped)

    @state.setter
    def state(self, s: dict[str, Any]) -> None:
        if not isinstance(s, dict):
            raise ValueError(f"state: expected a dict from ChainInverter.state, got {type(s).__name__}")
        missing = set(_STATE_KEYS) - set(s)
        if missing:
            raise ValueError(f"state: missing keys {sorted(missing)}")
        knot_t = np.ascontiguousarray(s["knot_t"], dtype=np.uint64).reshape(-1)
        self._stream.set_state(int(s["n"]), _as_signal("state", s["post"]), _as_signal("state", s["shift"]),
                               _as_signal("state", s["pre"]), _as_signal("state", s["memory"]), int(s["saturated"]),
                               int(s["t"]), float(s["u_prev"]), float(s["last_cm"]), knot_t,
                               _as_signal("state", s["knot_v"]), float(s["r_prev"]))
        self._clipped = int(s.get("clipped", 0))

    def invert(self, r: ArrayLike) -> tuple[NDArray[np.float64], int]:
        """The whole reference offline (the inverter is reset first): ``(u, saturated)``,
        ``u[n]`` the input for ``r[n]``, clipped to :attr:`input_limits` (counted in
        :attr:`clipped`)."""
        u, sat = self._stream.invert(_as_signal("r", r))
        self._clipped, self._first_clipped = 0, None
        return self._clip(u), int(sat)

    def __repr__(self) -> str:
        return (f"ChainInverter(method={self.method!r}, latency={self.latency}, "
                f"bandwidth_hz={self.bandwidth_hz:g}, fs={self._fs:g})")
