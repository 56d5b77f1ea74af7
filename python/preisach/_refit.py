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

:func:`refit_creep` fits the chain's creep again behind that hysteresis: a bank of
normalized Kelvin-Voigt elements with time constants log-spaced over what the records
can show (from 10 ms to the longest record), amplitudes >= 0 by non-negative least
squares on the creep's input (the input through the blocks up to the hysteresis) and
output (the record with the blocks after the creep inverted). Creep of time constant T
shows only in records that hold for about T (a step held that long).
:func:`refit_hysteresis` with ``creep_records`` alternates the two fits.
"""
from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import NDArray

from preisach import _preisach
from preisach.chain import Chain, sample_period
from preisach.model import DIAGONAL_FLOOR, PreisachModel

Record = tuple[Any, Any, Any]

#: Levels of the identity hysteresis that carries the linear part's inverse (with
#: diagonal masses only its interpolated output is exactly its input at any level count;
#: a few keep the chain's JSON small).
_IDENTITY_LEVELS = 50
#: Shortest creep time constant of the bank, seconds (faster is a low-pass's business).
CREEP_TAU_MIN_S = 0.01
#: Creep time constants per decade in the bank.
CREEP_PER_DECADE = 3
#: Rounds of (masses, creep) in :func:`refit_hysteresis` with creep records.
_CREEP_ROUNDS = 2


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


def _signals(t: Any, u: Any, y: Any, where: str = "") -> Record:
    from preisach._validate import as_signal

    tt, uu, yy = (as_signal(f"{where}{n}", x) for n, x in (("t", t), ("u", u), ("y", y)))
    if not tt.size == uu.size == yy.size:
        raise ValueError(f"{where}u, {where}y: expected the length of {where}t ({tt.size}), "
                         f"got {uu.size} and {yy.size}")
    return tt, uu, yy


def _masses(chain: Chain, tt: NDArray[np.float64], uu: NDArray[np.float64], yy: NDArray[np.float64], n_h: int,
            diagonal_floor: float, bandwidth_hz: Optional[float]) -> Chain:
    fs = 1.0 / sample_period(tt)
    pre, post = _split(chain)
    x = Chain.from_blocks(pre).predict(tt, uu) if pre else uu
    h = hysteresis_output(post, yy, fs, bandwidth_hz)
    model = PreisachModel.fit(x, h, n_h, output="interpolated", diagonal_floor=diagonal_floor)
    return Chain.from_blocks(pre + Chain(model).blocks + post, chain.sample_rate_hz, chain.initial_input)


def refit_hysteresis(chain: Chain, t: Any, u: Any, y: Any, n_h: int = 100,
                     diagonal_floor: float = DIAGONAL_FLOOR, bandwidth_hz: Optional[float] = None,
                     creep_records: Optional[Sequence[Record]] = None) -> Chain:
    """``chain`` with its hysteresis identified again on the record ``(t, u, y)`` behind
    the chain's other blocks (see the module doc): an interpolated model of ``n_h``
    levels. The record should start at rest (the linear inverse starts its filters at
    rest at the first sample). Returns a new chain (same rate and initial input).

    ``creep_records``: further records ``(t, u, y)``, each from rest, that show creep
    (steps held for as long as the creep to be compensated). With them the chain's
    creep is replaced by a bank fitted on them and ``(t, u, y)`` (:func:`refit_creep`),
    alternating with the masses; the bank is kept only if it predicts all the records
    better than the refitted chain without creep."""
    tt, uu, yy = _signals(t, u, y)
    if creep_records is None:
        return _masses(chain, tt, uu, yy, n_h, diagonal_floor, bandwidth_hz)
    recs = [(tt, uu, yy)] + [_signals(*r, where=f"creep_records[{i}].") for i, r in enumerate(creep_records)]
    plain = _masses(_without_creep(chain), tt, uu, yy, n_h, diagonal_floor, bandwidth_hz)
    cur = plain
    for _ in range(_CREEP_ROUNDS):
        cur = _masses(refit_creep(cur, recs), tt, uu, yy, n_h, diagonal_floor, bandwidth_hz)
    return cur if _rms(cur, recs) < _rms(plain, recs) else plain


def _rms(chain: Chain, recs: Sequence[Record]) -> float:
    return float(np.sqrt(np.mean(np.concatenate([(chain.predict(t, u) - y) ** 2 for t, u, y in recs]))))


def _without_creep(chain: Chain) -> Chain:
    return Chain.from_blocks([b for b in chain.blocks if b["type"] != "creep"], chain.sample_rate_hz,
                             chain.initial_input)


def creep_bank(longest_s: float, tau_min_s: float = CREEP_TAU_MIN_S,
               per_decade: int = CREEP_PER_DECADE) -> NDArray[np.float64]:
    """Log-spaced creep time constants from ``tau_min_s`` to ``longest_s`` (at least two)."""
    decades = max(np.log10(max(longest_s, tau_min_s) / tau_min_s), 0.0)
    return np.asarray(np.logspace(np.log10(tau_min_s), np.log10(tau_min_s) + decades,
                                  max(2, int(np.ceil(decades * per_decade)) + 1)), dtype=np.float64)


def refit_creep(chain: Chain, records: Sequence[Record], taus_s: Optional[Sequence[float]] = None) -> Chain:
    """``chain`` with its creep replaced by a bank of normalized elements (``y = x +
    sum c_k (LP_k[x] - x)``) right after its hysteresis (and rate), fitted on
    ``records`` (each ``(t, u, y)`` from rest) with ``c_k >= 0``: see the module doc.
    ``taus_s``: the bank's time constants (default :func:`creep_bank` up to the longest
    record). Elements fitted to zero are dropped; none left drops the creep."""
    recs = [_signals(*r, where=f"records[{i}].") for i, r in enumerate(records)]
    if not recs:
        raise ValueError("records: expected at least one (t, u, y) record")
    pre, post = _split(_without_creep(chain))
    k = next((i for i, b in enumerate(post) if b["type"] != "rate"), len(post))
    upto = pre + [b for b in chain.blocks if b["type"] == "hysteresis"] + post[:k]
    taus = creep_bank(max(float(t[-1] - t[0]) for t, _, _ in recs)) if taus_s is None else np.asarray(taus_s, float)
    if taus.ndim != 1 or taus.size == 0 or not np.all(np.isfinite(taus) & (taus > 0)):
        raise ValueError(f"taus_s: expected positive finite time constants, got {taus_s!r}")
    cols, rhs = [], []
    for t, u, y in recs:
        x = Chain.from_blocks(upto).predict(t, u)
        z = hysteresis_output(post[k:], y, 1.0 / sample_period(t))
        # Each record's mean is left out and a gain (either sign) is fitted with the
        # elements: offset and gain are the masses' business. Records weigh alike.
        col = np.column_stack([x] + [_element(tau).predict(t, x) - x for tau in taus])
        w = 1.0 / np.sqrt(t.size)
        cols.append(w * (col - col.mean(axis=0)))
        rhs.append(w * (z - x - np.mean(z - x)))
    a, b = np.concatenate(cols), np.concatenate(rhs)
    # The gain is free: projected out, the elements' amplitudes by NNLS, then the gain.
    g = a[:, 0] / max(float(np.linalg.norm(a[:, 0])), 1e-300)
    amps = _preisach.nnls(np.ascontiguousarray(a[:, 1:] - np.outer(g, g @ a[:, 1:])), b - g * (g @ b))
    gain = float(a[:, 0] @ (b - a[:, 1:] @ amps)) / max(float(a[:, 0] @ a[:, 0]), 1e-300)
    c = amps / (1.0 + gain)
    keep = c > 1e-9 * max(float(np.max(c)), 0.0)
    creep = [{"type": "creep", "taus_s": [float(v) for v in taus[keep]],
              "amplitudes": [float(v) for v in c[keep]], "normalized": True}] if keep.any() else []
    return Chain.from_blocks(pre + upto[len(pre):] + creep + post[k:], chain.sample_rate_hz, chain.initial_input)


def _element(tau: float) -> Chain:
    return Chain.from_blocks([{"type": "creep", "taus_s": [float(tau)], "amplitudes": [1.0], "normalized": True}])
