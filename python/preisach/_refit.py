"""The hysteresis of a chain identified again behind the chain's linear part
(``docs/method/inversion.md``, "Compensating with a diagnosed chain").

A diagnosis fits its masses on a coarse grid (n_h = 40 by default) and at a reduced
rate; compensation wants the finest model the record supports, fitted as the model the
inverse inverts. :func:`refit_hysteresis` takes the chain's linear part as found and
fits the masses again: the measured output is run through the chain inverse of that
part (an identity hysteresis followed by the chain's blocks after its hysteresis), which
gives the hysteresis output the record implies; the input through the blocks before the
hysteresis gives its input; then :meth:`PreisachModel.fit` with ``output="interpolated"``
(the model the continuous inverse inverts exactly) and its diagonal floor.
"""
from __future__ import annotations

from typing import Any, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.chain import Chain, sample_period
from preisach.model import DIAGONAL_FLOOR, PreisachModel

#: Levels of the identity hysteresis that carries the linear part's inverse.
_IDENTITY_LEVELS = 1000


def _split(chain: Chain) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    blocks = chain.blocks
    kinds = [b["type"] for b in blocks]
    if kinds.count("hysteresis") != 1:
        raise ValueError(f"chain: expected exactly one hysteresis block, got {kinds.count('hysteresis')}")
    k = kinds.index("hysteresis")
    return blocks[:k], blocks[k + 1:]


def _identity(lo: float, hi: float) -> PreisachModel:
    """A model whose interpolated output is its input on [lo, hi]: diagonal masses only."""
    n = _IDENTITY_LEVELS
    return PreisachModel(np.diag(np.full(n, (hi - lo) / (2 * n))), (lo, hi), 0.5 * (lo + hi), "interpolated")


def _static_gain(blocks: list[dict[str, Any]]) -> float:
    lin = [b for b in blocks if b["type"] not in ("noise", "quantizer", "drift")]
    if not lin:
        return 1.0
    g = float(np.real(Chain.from_blocks(lin).response(np.array([0.0]))[0]))
    if not np.isfinite(g) or g == 0.0:
        raise ValueError("chain: the linear part after the hysteresis has no static gain to invert")
    return g


def hysteresis_output(post: list[dict[str, Any]], y: NDArray[np.float64], fs: float,
                      bandwidth_hz: Optional[float] = None) -> NDArray[np.float64]:
    """What the hysteresis put out, given the measured ``y`` and the blocks ``post``
    after it: ``y`` through the chain inverse of ``post`` (at rest at ``y[0]``)."""
    if not post:
        return y.copy()
    g = _static_gain(post)
    a, b = float(y.min()) / g, float(y.max()) / g
    lo, hi = min(a, b), max(a, b)
    span = max(hi - lo, 1e-9 * max(1.0, abs(lo), abs(hi)))
    linear = Chain.from_blocks(Chain(_identity(lo - span, hi + span)).blocks + post)
    return linear.invert(y, fs, bandwidth_hz=bandwidth_hz)  # type: ignore[no-any-return]


def refit_hysteresis(chain: Chain, t: Any, u: Any, y: Any, n_h: int = 100,
                     diagonal_floor: float = DIAGONAL_FLOOR, bandwidth_hz: Optional[float] = None) -> Chain:
    """``chain`` with its hysteresis identified again on the record ``(t, u, y)`` behind
    the chain's other blocks (see the module doc): an interpolated model of ``n_h``
    levels. The record should start at rest (the linear inverse starts its filters at
    rest at the first sample). Returns a new chain (same rate and initial input)."""
    from preisach._validate import as_signal

    tt, uu, yy = as_signal("t", t), as_signal("u", u), as_signal("y", y)
    if not tt.size == uu.size == yy.size:
        raise ValueError(f"u, y: expected the length of t ({tt.size}), got {uu.size} and {yy.size}")
    fs = 1.0 / sample_period(tt)
    pre, post = _split(chain)
    x = Chain.from_blocks(pre).predict(tt, uu) if pre else uu
    h = hysteresis_output(post, yy, fs, bandwidth_hz)
    model = PreisachModel.fit(x, h, n_h, output="interpolated", diagonal_floor=diagonal_floor)
    return Chain.from_blocks(pre + Chain(model).blocks + post, chain.sample_rate_hz, chain.initial_input)
