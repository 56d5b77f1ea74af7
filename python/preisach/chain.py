"""A model chain: the identified Preisach model followed by plant effects
(``docs/method/blocks.md``), as written by ``preisach diagnose --save-model`` and run by ``preisach
predict``.

JSON form::

    {"format": "preisach-chain", "version": 1,
     "model": <PreisachModel.to_dict()>,
     "effects": [{"name": "delay", "params": {"delay_s": 3e-4}}, ...]}

Effect parameters are in physical units (seconds, hertz), so a chain runs at any
sample rate. The effects are applied in the fixed DESIGN order whatever their order
in the list: hysteresis -> rate branch -> creep -> vibration -> low-pass -> delay ->
drift. Linear blocks are simulated exactly for an input that is linear between
samples (first-order hold), so the result does not depend on the sample rate beyond
that interpolation; numpy only.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from preisach.io import PathLike, write_text
from preisach.model import PreisachModel

FORMAT = "preisach-chain"
VERSION = 1

#: Effect names in the order they are applied, with their pinned parameter names.
EFFECT_PARAMS: dict[str, tuple[str, ...]] = {
    "rate": ("gain_s", "tau_s"),
    "creep": ("taus_s", "amplitudes"),
    "vibration": ("frequency_hz", "damping"),
    "lowpass": ("cutoff_hz", "order"),
    "delay": ("delay_s",),
    "drift": ("gain_per_s", "offset", "offset_per_s"),
}
ORDER = tuple(EFFECT_PARAMS)


# --------------------------------------------------------------------------------------
# Exact simulation of linear blocks given as partial fractions.
# --------------------------------------------------------------------------------------
def lti(x: ArrayLike, dt: float, poles: Sequence[complex], residues: Sequence[complex],
        direct: float = 0.0) -> NDArray[np.float64]:
    """Output of ``H(s) = direct + sum r_k / (s - p_k)`` for input ``x`` sampled every
    ``dt`` seconds, starting at rest. Poles must be stable; a complex pole stands for
    itself and its conjugate (pass one of each pair)."""
    from preisach import _preisach

    xx = np.ascontiguousarray(x, dtype=np.float64)
    ps = [(complex(p).real, complex(p).imag) for p in poles]
    rs = [(complex(r).real, complex(r).imag) for r in residues]
    return _preisach.lti(xx, float(dt), ps, rs, float(direct))


def butterworth_pf(cutoff_hz: float, order: int) -> tuple[list[complex], list[complex]]:
    """Partial fractions of the analog Butterworth low-pass (DC gain 1): one pole of
    each conjugate pair, with its residue."""
    wc = 2 * math.pi * cutoff_hz
    ps = [wc * np.exp(1j * math.pi * (2 * k + order + 1) / (2 * order)) for k in range(order)]
    num = np.prod([-p for p in ps]).real
    poles, res = [], []
    for k, p in enumerate(ps):
        if p.imag < -1e-9 * wc:
            continue  # the conjugate of a pole already taken
        den = np.prod([p - q for j, q in enumerate(ps) if j != k]) if order > 1 else 1.0
        poles.append(complex(p) if abs(p.imag) > 1e-9 * wc else complex(p.real, 0.0))
        res.append(complex(num / den))
    return poles, res


def mode_pf(frequency_hz: float, damping: float) -> tuple[list[complex], list[complex]]:
    """Partial fractions of ``w^2 / (s^2 + 2 zeta w s + w^2)`` (DC gain 1)."""
    w = 2 * math.pi * frequency_hz
    z = min(float(damping), 0.999)
    wd = w * math.sqrt(1 - z * z)
    p = complex(-z * w, wd)
    return [p], [w * w / (2j * wd)]


def delay_signal(x: NDArray[np.float64], delay_s: float, dt: float) -> NDArray[np.float64]:
    """``x(t - delay)`` with linear interpolation between samples; the record was at rest
    (``x[0]``) before its start."""
    if delay_s <= 0:
        return x
    idx = np.arange(x.size, dtype=np.float64) - delay_s / dt
    return np.interp(idx, np.arange(x.size, dtype=np.float64), x, left=x[0])


def sample_period(t: NDArray[np.float64], what: str = "t") -> float:
    """The sample period of a time vector (median step); errors name ``what``."""
    if t.size < 2:
        raise ValueError(f"{what}: need at least 2 samples")
    d = np.diff(t)
    if not np.all(d > 0):
        i = int(np.argmax(~(d > 0)))
        raise ValueError(f"{what}: time must increase strictly (row {i + 1})")
    return float(np.median(d))


# --------------------------------------------------------------------------------------
# Effects applied to a hysteresis output.
# --------------------------------------------------------------------------------------
def _check_params(name: str, params: Any, source: str) -> dict[str, Any]:
    if name not in EFFECT_PARAMS:
        raise ValueError(f"{source}: unknown effect {name!r} (known: {', '.join(EFFECT_PARAMS)})")
    if not isinstance(params, dict):
        raise ValueError(f"{source}: params of effect {name!r} must be an object")
    out: dict[str, Any] = {}
    for k in EFFECT_PARAMS[name]:
        if k not in params:
            if name == "drift":
                out[k] = 0.0
                continue
            if name == "lowpass" and k == "order":
                out[k] = 2
                continue
            raise ValueError(f"{source}: effect {name!r} lacks parameter {k!r}")
        v = params[k]
        vals = v if isinstance(v, list) else [v]
        if not all(isinstance(q, (int, float)) and not isinstance(q, bool) and math.isfinite(q) for q in vals):
            raise ValueError(f"{source}: effect {name!r} parameter {k!r} must be finite number(s), got {v!r}")
        out[k] = [float(q) for q in v] if isinstance(v, list) else float(v)
    if name == "delay" and out["delay_s"] < 0:
        raise ValueError(f"{source}: delay_s must be >= 0")
    if name == "lowpass":
        if out["cutoff_hz"] <= 0 or int(out["order"]) not in (1, 2, 3, 4):
            raise ValueError(f"{source}: lowpass needs cutoff_hz > 0 and order 1-4")
        out["order"] = int(out["order"])
    if name == "vibration" and (out["frequency_hz"] <= 0 or out["damping"] <= 0):
        raise ValueError(f"{source}: vibration needs frequency_hz > 0 and damping > 0")
    if name == "creep":
        if not isinstance(out["taus_s"], list) or not isinstance(out["amplitudes"], list) \
                or len(out["taus_s"]) != len(out["amplitudes"]) or any(x <= 0 for x in out["taus_s"]):
            raise ValueError(f"{source}: creep needs equal-length lists taus_s (> 0) and amplitudes")
    if name == "rate" and out["tau_s"] <= 0:
        raise ValueError(f"{source}: rate needs tau_s > 0")
    return out


def apply_linear(name: str, p: dict[str, Any], x: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """One linear block (creep, vibration, lowpass, delay) applied to ``x``."""
    if name == "creep":
        # "_norm" (internal, used while fitting): y = x + sum c (LP[x] - x), DC gain 1, so
        # the masses need not rescale as the gains change.
        norm = bool(p.get("_norm"))
        y = x.copy()
        for tau, c in zip(p["taus_s"], p["amplitudes"]):
            if c != 0:
                lp = lti(x, dt, [complex(-1 / tau)], [complex(1 / tau)])
                y += c * (lp - x) if norm else c * lp
        return y
    if name == "vibration":
        poles, res = mode_pf(p["frequency_hz"], p["damping"])
        return lti(x, dt, poles, res)
    if name == "lowpass":
        poles, res = butterworth_pf(p["cutoff_hz"], int(p["order"]))
        return lti(x, dt, poles, res)
    if name == "delay":
        return delay_signal(x, p["delay_s"], dt)
    raise ValueError(f"not a linear effect: {name}")


def partial_fractions(name: str, p: dict[str, Any]) -> tuple[list[complex], list[complex], float]:
    """The creep, vibration or low-pass block as (poles, residues, direct term), the form
    :func:`lti` runs (a complex pole stands for its conjugate pair)."""
    if name == "creep":
        taus, cs = p["taus_s"], p["amplitudes"]
        poles = [complex(-1 / tau) for tau, c in zip(taus, cs) if c != 0]
        res = [complex(c / tau) for tau, c in zip(taus, cs) if c != 0]
        # "_norm": y = x + sum c (LP[x] - x); otherwise y = x + sum c LP[x].
        direct = 1.0 - float(sum(cs)) if p.get("_norm") else 1.0
        return poles, res, direct
    if name == "vibration":
        poles, res = mode_pf(p["frequency_hz"], p["damping"])
        return poles, res, 0.0
    if name == "lowpass":
        poles, res = butterworth_pf(p["cutoff_hz"], int(p["order"]))
        return poles, res, 0.0
    raise ValueError(f"not a linear block with poles: {name}")


def rate_term(p: dict[str, Any], u: NDArray[np.float64], dt: float) -> NDArray[np.float64]:
    """The rate branch ``gain_s * s / (1 + s tau) u``: the input velocity, low-passed."""
    tau = p["tau_s"]
    d = lti(u, dt, [complex(-1 / tau)], [complex(-1 / tau ** 2)], direct=1 / tau)
    return p["gain_s"] * d


def apply_effects(effects: dict[str, dict[str, Any]], t: NDArray[np.float64], u: NDArray[np.float64],
                  h: NDArray[np.float64], dt: float, stop_before: Optional[str] = None) -> NDArray[np.float64]:
    """Run the effects (a dict name -> params) over the hysteresis output ``h`` in the
    DESIGN order. ``stop_before`` returns the signal entering that block."""
    x = h
    for name in ORDER:
        if name == stop_before:
            return x
        if name not in effects:
            continue
        p = effects[name]
        if name == "rate":
            x = x + rate_term(p, u, dt)
        elif name == "drift":
            x = x * (1 + p["gain_per_s"] * t) + p["offset"] + p["offset_per_s"] * t
        else:
            x = apply_linear(name, p, x, dt)
    return x


class Chain:
    """A Preisach model followed by effects; see the module doc.

    ``effects`` is a list of ``{"name": ..., "params": {...}}`` dicts (or a dict
    name -> params)."""

    def __init__(self, model: PreisachModel, effects: Any = ()) -> None:
        self.model = model
        items = effects.items() if isinstance(effects, dict) else [(e.get("name"), e.get("params")) for e in effects]
        self.effects: dict[str, dict[str, Any]] = {}
        for name, params in items:
            if name in self.effects:
                raise ValueError(f"chain: effect {name!r} given twice")
            self.effects[str(name)] = _check_params(str(name), params, "chain")

    def predict(self, t: ArrayLike, u: ArrayLike) -> NDArray[np.float64]:
        """Chain output for input ``u`` sampled at times ``t`` (seconds; any sample rate;
        ``t`` is absolute time, which the drift block uses)."""
        tt = np.asarray(t, dtype=np.float64).ravel()
        uu = np.asarray(u, dtype=np.float64).ravel()
        if tt.shape != uu.shape:
            raise ValueError(f"t: length {tt.size} does not match u (length {uu.size})")
        if not (np.all(np.isfinite(tt)) and np.all(np.isfinite(uu))):
            raise ValueError("t, u: must be finite (NaN or inf found)")
        dt = sample_period(tt) if tt.size > 1 else 1.0
        h = self.model.predict(uu)
        return apply_effects(self.effects, tt, uu, h, dt)

    def to_dict(self) -> dict[str, Any]:
        """The versioned JSON-ready dict."""
        return {
            "format": FORMAT,
            "version": VERSION,
            "model": self.model.to_dict(),
            "effects": [{"name": n, "params": self.effects[n]} for n in ORDER if n in self.effects],
        }

    @classmethod
    def from_dict(cls, d: Any, source: str = "chain") -> "Chain":
        """Rebuild a chain from :meth:`to_dict` output; ValueError names ``source``."""
        if not isinstance(d, dict) or d.get("format") != FORMAT:
            raise ValueError(f"corrupt {source}: 'format' must be {FORMAT!r}")
        if d.get("version") != VERSION:
            raise ValueError(f"corrupt {source}: unsupported 'version' {d.get('version')!r} (this build reads {VERSION})")
        model = PreisachModel.from_dict(d.get("model"), source=f"{source} (model)")
        eff = d.get("effects", [])
        if not isinstance(eff, list) or not all(isinstance(e, dict) for e in eff):
            raise ValueError(f"corrupt {source}: 'effects' must be a list of objects")
        try:
            return cls(model, eff)
        except ValueError as exc:
            raise ValueError(f"corrupt {source}: {exc}") from None

    def save(self, path: PathLike) -> None:
        """Write the chain as JSON (atomically)."""
        write_text(path, json.dumps(self.to_dict(), allow_nan=False) + "\n")

    @classmethod
    def load(cls, path: PathLike) -> "Chain":
        """Read a chain written by :meth:`save`."""
        p = Path(path)
        try:
            d = json.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ValueError(f"{p}: cannot read chain ({exc})") from None
        return cls.from_dict(d, source=f"chain file {p}")

    def __repr__(self) -> str:
        return f"Chain({self.model!r}, effects={list(self.effects)})"
