"""Inversion of the Preisach model for hysteresis compensation (the paper §4.1).

Three methods, all starting from negative saturation (every relay -1, input ``lo``):

``"closest"``
    Closest match (Tan et al. 2001): for each reference sample the input level (one of
    the ``n_h + 1`` levels) whose stepwise model output, from the current memory, is
    nearest the reference; the memory then advances with that level. O(log n_h) per
    sample. Ties and plateaus (levels with equal output, from zero masses) go to the
    level nearest the previous input.
``"interpolated"``
    The *monotone* closest match smoothed as in the paper's Fig. 9. The monotone
    closest match picks, for each sample, the best level among those on the
    reference's side of the current level: when the reference rises
    (``r[t] > r[t-1]``) a level at or above the current one, when it falls one at or
    below, and when it is constant it stays (ties to the level nearest the current
    one). Why not the per-sample closest match: its optimum dithers (after a one-level
    rise switches a column of cells, dropping a few levels and coming back gives
    intermediate outputs), so it keeps reversing against the reference, tracing minor
    loops, and knots at every riser inherit the dither; the paper's Fig. 9 shows a
    monotone staircase, which the monotone closest match is. Its signal ``u_cm`` is
    then interpolated: knots at the riser
    midpoints (a step at sample ``t_s`` from level ``a`` to ``b`` gives the knot
    ``(t_s, (a + b) / 2)``; the first knot is ``(0, u_cm[0])``), linear in between.
    Sample ``t`` moves from ``u[t-1]`` towards the first knot in ``[t, t + L]`` or, if
    there is none, the pseudo-knot ``(t + L, u_cm[t + L])`` (window end clamped to the
    last sample): ``u[t] = u[t-1] + (v - u[t-1]) / (t_knot - t + 1)``. Offline,
    ``lookahead=None`` means ``L`` infinite: piecewise linear through the knots, ending
    at ``u_cm[-1]`` (at the riser midpoint if the last sample is itself a step).
    Streaming needs a finite ``lookahead`` ``L`` and is **delayed by exactly L
    samples**: ``step(r_t)`` returns ``u[t - L]``; the first ``L`` calls return the
    initial input ``lo``. The streamed output equals
    ``[lo] * L + invert(model, r, "interpolated", lookahead=L)[:len(r) - L]`` exactly.
``"continuous"``
    Exact inverse of the interpolated (continuous-output) model: the input nearest the
    previous one with ``y_c(u) = r`` (to ``1e-12`` of the output scale), found by a
    binary search over the levels and regula falsi inside the bracket. Real time, no
    look-ahead. The interpolated output is continuous (diagonal mass lies along the
    diagonal), so every reachable reference is reproduced to rounding.

References outside the reachable output range ``[offset - total, offset + total]``
(the model's output at the ends of ``u_range``, from any memory) saturate: the input
stays at the end of ``u_range`` (``lo``/``hi``, or the nearest level giving the extreme
output if the model is flat there), so the input never leaves ``u_range``. This is not
an error: :func:`invert` emits one :class:`~preisach.PreisachWarning` with the count and
the first index (also in ``invert(..., return_info=True)``), and ``Inverter.saturated``
counts such references as they stream.

``lookahead`` is only used by ``"interpolated"``; it must be ``None`` for
``"closest"`` and ``"continuous"`` (neither needs a preview).
"""
from __future__ import annotations

import numbers
import warnings
from dataclasses import dataclass
from typing import Any, Literal, Optional, Union, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from preisach import _preisach
from preisach._validate import as_number, one_thread

__all__ = ["METHODS", "InversionInfo", "Inverter", "invert"]

METHODS = ("closest", "interpolated", "continuous")


@dataclass(frozen=True)
class InversionInfo:
    """What ``invert(..., return_info=True)`` reports besides the input.

    Attributes:
        method: the inversion method used.
        lookahead: the interpolation look-ahead in samples (``None`` = whole record).
        saturated: number of reference samples outside the reachable output range.
        first_saturated: index of the first of them (``None`` if there is none).
    """

    method: str
    lookahead: Optional[int]
    saturated: int
    first_saturated: Optional[int] = None


def _core_of(model: Any) -> _preisach.Model:
    core = getattr(model, "_core", model)
    if not isinstance(core, _preisach.Model):
        raise TypeError(f"model: expected a preisach.PreisachModel, got {type(model).__name__}")
    return core


def _check_method(method: Any) -> str:
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"method: expected one of {', '.join(map(repr, METHODS))}, got {method!r}")
    return method


def _check_lookahead(method: str, lookahead: Any, streaming: bool) -> Optional[int]:
    if lookahead is None:
        if streaming and method == "interpolated":
            raise ValueError(
                "lookahead: required for streaming method 'interpolated' "
                "(the output is delayed by lookahead samples)"
            )
        return None
    if isinstance(lookahead, bool) or not isinstance(lookahead, numbers.Integral):
        raise ValueError(f"lookahead: expected a non-negative int or None, got {lookahead!r}")
    if lookahead < 0:
        raise ValueError(f"lookahead: must be >= 0, got {lookahead}")
    if int(lookahead) >= 2**63:
        raise ValueError(f"lookahead: {lookahead} is too large (at most 2**63 - 1 samples)")
    if method != "interpolated":
        raise ValueError(f"lookahead: only used by method 'interpolated'; must be None for {method!r}")
    return int(lookahead)


def _as_signal(name: str, x: ArrayLike) -> NDArray[np.float64]:
    try:
        a = np.ascontiguousarray(x, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: cannot be converted to a float64 array ({exc})") from None
    if a.ndim != 1:
        raise ValueError(f"{name}: expected a 1-D array, got shape {a.shape}")
    return a


@overload
def invert(model: Any, r: ArrayLike, method: str = "closest", lookahead: Optional[int] = None, *,
           return_info: Literal[False] = False) -> NDArray[np.float64]: ...


@overload
def invert(model: Any, r: ArrayLike, method: str = "closest", lookahead: Optional[int] = None, *,
           return_info: Literal[True]) -> tuple[NDArray[np.float64], InversionInfo]: ...


def invert(
    model: Any,
    r: ArrayLike,
    method: str = "closest",
    lookahead: Optional[int] = None,
    *,
    return_info: bool = False,
) -> Union[NDArray[np.float64], tuple[NDArray[np.float64], InversionInfo]]:
    """Invert ``model`` over a whole reference ``r`` (the input that makes the model
    output follow ``r``), starting from negative saturation.

    Args:
        model: a ``preisach.PreisachModel``.
        r: reference output, any 1-D array-like of finite numbers.
        method: ``"closest"``, ``"interpolated"`` or ``"continuous"`` (module docs).
        lookahead: ``"interpolated"`` only: preview in samples; ``None`` = the whole
            record (offline piecewise-linear through the knots). Must be ``None`` for
            the other methods.
        return_info: also return an :class:`InversionInfo` (saturation count).

    Returns:
        The input as a float64 array of ``len(r)``, or ``(u, info)``.

    Raises:
        ValueError: bad method or lookahead, ``r`` not 1-D, or not finite (the message
            names the first bad index).
    """
    core = _core_of(model)
    method = _check_method(method)
    lookahead = _check_lookahead(method, lookahead, streaming=False)
    r = _as_signal("r", r)
    u, saturated = _preisach.invert(core, r, method, lookahead)
    first = None
    if saturated:
        first = _warn_saturated(core, r)
    if return_info:
        return u, InversionInfo(method=method, lookahead=lookahead, saturated=int(saturated), first_saturated=first)
    return u


def _warn_saturated(core: _preisach.Model, r: NDArray[np.float64]) -> int:
    """Emit the :class:`~preisach.PreisachWarning` for references beyond the reachable
    output; return the first one's index."""
    from preisach.model import PreisachWarning

    count, first, (lo, hi) = _preisach.saturation(core, r)
    assert first is not None  # only called when the core counted saturated samples
    u_lo, u_hi = core.lo, core.hi
    warnings.warn(
        f"{count} of {r.size} reference samples are outside the model's reachable output range "
        f"[{lo:.6g}, {hi:.6g}] (first at index {first}, r = {r[first]:.6g}): they were clipped, the input "
        f"stays at the end of u_range [{u_lo:.6g}, {u_hi:.6g}]",
        PreisachWarning,
        stacklevel=3,
    )
    return int(first)


class Inverter:
    """Streaming inverse: one reference sample in, one input sample out, no allocation
    per sample (the per-sample path is in Rust).

    Args:
        model: a ``preisach.PreisachModel``.
        method: ``"closest"``, ``"interpolated"`` or ``"continuous"`` (module docs).
        lookahead: required for ``"interpolated"``: preview ``L`` in samples; the
            output is delayed by exactly ``L`` samples (``step(r_t)`` returns
            ``u[t - L]``, the first ``L`` calls return ``lo``). Must be ``None`` for
            the other methods.

    Attributes:
        saturated: references so far outside the reachable output range.
        delay: output delay in samples (``lookahead`` for "interpolated", else 0).
        state: a snapshot (dict) of the whole inverter state; assign it back (to this
            or another inverter of the same model, method and lookahead) to resume
            exactly.
    """

    def __init__(self, model: Any, method: str = "closest", lookahead: Optional[int] = None) -> None:
        core = _core_of(model)
        self._method = _check_method(method)
        self._lookahead = _check_lookahead(self._method, lookahead, streaming=True)
        self._stream = _preisach.InverseStream(core, self._method, self._lookahead)

    @property
    def method(self) -> str:
        """The inversion method."""
        return self._method

    @property
    def lookahead(self) -> Optional[int]:
        """The interpolation look-ahead (``None`` for the other methods)."""
        return self._lookahead

    @property
    def delay(self) -> int:
        """Output delay in samples."""
        return self._lookahead or 0

    @property
    @one_thread
    def saturated(self) -> int:
        """Number of references so far outside the reachable output range."""
        return int(self._stream.saturated)

    @one_thread
    def step(self, r: float) -> float:
        """One reference sample in, one input sample out (delayed by ``delay``)."""
        return self._stream.step(as_number("r", r))

    @one_thread
    def process(self, block: ArrayLike) -> NDArray[np.float64]:
        """A block of reference samples in, as many input samples out. Same as calling
        :meth:`step` on each; a non-finite sample raises before any state changes."""
        return self._stream.process(_as_signal("block", block))

    @one_thread
    def reset(self) -> None:
        """Back to negative saturation; the saturation count is cleared."""
        self._stream.reset()

    @property
    @one_thread
    def state(self) -> dict[str, Any]:
        """Snapshot: ``memory`` is the memory staircase in level coordinates (0 = lo,
        n_h = hi; dominant extrema then the current input), ``saturated`` the count,
        and for "interpolated" the sample counter ``t``, the last output ``u_prev``,
        the last closest-match value ``last_cm``, the knots in the look-ahead window
        (``knot_t``, ``knot_v``) and the previous reference ``r_prev`` (the direction
        of the monotone closest match; ``-inf`` before the first sample)."""
        memory, saturated, t, u_prev, last_cm, knot_t, knot_v, r_prev = self._stream.get_state()
        return {
            "method": self._method,
            "lookahead": self._lookahead,
            "memory": memory,
            "saturated": int(saturated),
            "t": int(t),
            "u_prev": float(u_prev),
            "last_cm": float(last_cm),
            "knot_t": knot_t,
            "knot_v": knot_v,
            "r_prev": float(r_prev),
        }

    @state.setter
    @one_thread
    def state(self, s: dict[str, Any]) -> None:
        if not isinstance(s, dict):
            raise ValueError(f"state: expected a dict from Inverter.state, got {type(s).__name__}")
        keys = {"method", "lookahead", "memory", "saturated", "t", "u_prev", "last_cm", "knot_t", "knot_v", "r_prev"}
        missing = keys - set(s)
        if missing:
            raise ValueError(f"state: missing keys {sorted(missing)}")
        if s["method"] != self._method or s["lookahead"] != self._lookahead:
            raise ValueError(
                f"state: taken from method={s['method']!r}, lookahead={s['lookahead']!r}; "
                f"this inverter has method={self._method!r}, lookahead={self._lookahead!r}"
            )
        try:
            knot_t = np.ascontiguousarray(s["knot_t"], dtype=np.uint64).reshape(-1)
            counts = [int(s[k]) for k in ("saturated", "t")]
            if min(counts) < 0 or max(counts) >= 2**64:
                raise ValueError(f"counts saturated, t = {counts} outside 0 .. 2**64 - 1")
            values = [float(s[k]) for k in ("u_prev", "last_cm", "r_prev")]
        except (TypeError, ValueError, OverflowError) as exc:
            raise ValueError(f"state: not a snapshot from Inverter.state ({exc})") from None
        self._stream.set_state(_as_signal("state", s["memory"]), counts[0], counts[1], values[0], values[1], knot_t,
                               _as_signal("state", s["knot_v"]), values[2])

    def __repr__(self) -> str:
        la = "" if self._lookahead is None else f", lookahead={self._lookahead}"
        return f"Inverter(method={self._method!r}{la}, saturated={self.saturated})"
