"""The diagnosis report: attributes, JSON, a human summary and the evidence sentences."""
from __future__ import annotations

import json
import math
from typing import Any

import numpy as np


def _num(x: float, unit: str = "") -> str:
    return f"{x:.3g}{unit}"


def evidence_text(name: str, sig: dict[str, dict[str, Any]], train: str, holds: list[str], floor: float,
                  d: dict[str, Any]) -> str:
    """One or two sentences of signature statistics for effect ``name``."""
    s = sig.get(holds[0], {}) if holds else {}
    st = sig.get(train, {})
    base = (f"holdout RMSE {d['rmse_current']:.4g} -> {d['rmse_after']:.4g} "
            f"({100 * d['score']:.1f} % smaller, noise floor {floor:.3g})")
    if name == "delay":
        return (f"{base}; residual ~ -d*dh/dt gives d = {_num(1e3 * st.get('lag_ls_s', 0.0))} ms on the training "
                f"record, "
                f"phase slope {_num(1e3 * (s.get('phase_slope_s') or 0.0))} ms (a delay: linear phase, flat gain)")
    if name == "lowpass":
        return (f"{base}; gain change at high frequency {s.get('gain_drop_at_high_f', float('nan')):.3g} "
                f"(a low-pass loses gain as well as phase; a delay keeps the gain)")
    if name == "vibration":
        pk = s.get("peaks") or [{}]
        return (f"{base}; residual spectrum peak at {_num(pk[0].get('frequency_hz', float('nan')), ' Hz')} "
                f"({pk[0].get('prominence_db', float('nan')):.1f} dB above trend); ringing after steps")
    if name == "creep":
        return (f"{base}; residual keeps moving in dwells after steps (dwell/after-step share of samples "
                f"{s.get('dwell_fraction', 0):.2f})")
    if name == "drift":
        return (f"{base}; |corr(residual, absolute time)| = {s.get('corr_time', 0):.2f}, "
                f"|corr(residual, time x output)| = {s.get('corr_time_output', 0):.2f}")
    if name == "rate":
        return f"{base}; residual follows the input velocity (rate-dependent loop width)"
    if name == "discretization":
        return f"{base} with n_h = {d.get('n_h')} (the grid is too coarse when a finer grid fits unseen data better)"
    return base


def _clean(x: Any) -> Any:
    """JSON-safe copy (NaN -> None, numpy scalars -> float)."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        f = float(x)
        return f if math.isfinite(f) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


class GapReport:
    """Result of :func:`preisach.diagnose`.

    Attributes: ``dominant_effect`` (an effect name or ``"none"``), ``noise_floor``,
    ``baseline`` (per-record RMSE of the baseline and its holdout RMSE), ``where``
    (per-record localization), ``split`` (what fitted and what scored), ``effects``
    (ranked: name, detected, score, evidence, params, rmse_before, rmse_after, shrink,
    ``at_bound``: the parameters that ended at a search bound), ``search_ranges`` (every
    scalar's range, from the data),
    ``augmented`` (the effects kept and the holdout RMSE of the augmented chain),
    ``seconds``; ``chain`` is the augmented :class:`~preisach.chain.Chain`."""

    def __init__(self, **kw: Any) -> None:
        self.dominant_effect: str = kw["dominant_effect"]
        self.noise_floor: float = kw["noise_floor"]
        self.baseline: dict[str, Any] = kw["baseline"]
        self.where: list[dict[str, Any]] = kw["where"]
        self.split: dict[str, Any] = kw["split"]
        self.effects: list[dict[str, Any]] = kw["effects"]
        self.augmented: dict[str, Any] = kw["augmented"]
        self.seconds: float = kw["seconds"]
        self.search_ranges: dict[str, Any] = kw.get("search_ranges", {})
        self.chain = kw["chain"]
        self.baseline_model = kw["baseline_model"]
        self._records = kw["records"]
        self._base_res = kw["base_residuals"]

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready report."""
        return _clean({
            "dominant_effect": self.dominant_effect, "noise_floor": self.noise_floor,
            "baseline": self.baseline, "where": self.where, "split": self.split,
            "effects": self.effects, "augmented": self.augmented, "seconds": self.seconds,
            "search_ranges": self.search_ranges,
        })

    def to_json(self) -> str:
        """The report as JSON text."""
        return json.dumps(self.to_dict(), indent=1, allow_nan=False)

    def augmented_chain_dict(self) -> dict[str, Any]:
        """The augmented chain as a ``preisach-chain`` dict."""
        return self.chain.to_dict()

    def baseline_model_dict(self) -> dict[str, Any]:
        """The baseline model as a ``preisach-model`` dict."""
        return self.baseline_model.to_dict()

    def summary(self) -> str:
        """A few lines for humans."""
        b = self.baseline
        rf = b.get("repeatability_floor")
        lines = [f"baseline (n_h={b['n_h']}) holdout RMSE {b['holdout_rmse']:.4g}; noise floor {self.noise_floor:.3g}"
                 + (f"; repeatability floor {rf:.3g}" if rf is not None else "")]
        if "reference_interpolated_holdout_rmse" in b:
            lines.append(f"hysteresis alone: interpolated {b['reference_interpolated_holdout_rmse']:.4g}"
                         + (f", finer {b['reference_finer_holdout_rmse']:.4g}"
                            if "reference_finer_holdout_rmse" in b else "")
                         + " (every shrink below is against the chain the effect was added to)")
        for w in self.where:
            seg = max(w["segments"].items(), key=lambda kv: kv[1]["share_of_error"])
            lines.append(f"  {w['record']}: RMSE {w['rmse']:.4g}, largest share of error {seg[0]} "
                         f"({100 * seg[1]['share_of_error']:.0f} %)")
        lines.append(f"dominant effect: {self.dominant_effect}")
        for e in self.effects:
            mark = "*" if e["detected"] else " "
            cur = e.get("rmse_current", e["rmse_before"])
            sh = e.get("shrink_vs_current", e["shrink"])
            lines.append(f" {mark} {e['name']:14s} shrink {100 * sh:6.1f} %  "
                         f"({cur:.4g} -> {e['rmse_after']:.4g})  {json.dumps(_clean(e['params']))}"
                         + (f"  [refused: {e['refused']}]" if e.get("refused") else ""))
            # (A candidate that did not help is not worth a line: its JSON lists its bounds.)
            for b in (e.get("at_bound") or []) if e["detected"] or sh > 0 else []:
                lines.append(f"   ! {e['name']}: {b} ended at its search bound: the effect lies outside the range "
                             f"searched or is no such effect (not called detected on it)")
        a = self.augmented
        lines.append(f"augmented chain {a['effects'] or '(no effects)'}: holdout RMSE {a['holdout_rmse']:.4g} "
                     f"({100 * a['shrink']:.0f} % below the baseline); {self.seconds:.1f} s")
        return "\n".join(lines)

    def plot(self, directory: Any) -> list[str]:
        """Write PNG plots (needs matplotlib: ``pip install 'preisach[plot]'``)."""
        from preisach.diagnose.plots import plot_report

        return plot_report(self, directory)

    def __repr__(self) -> str:
        found = [e["name"] for e in self.effects if e["detected"]]
        return f"GapReport(dominant_effect={self.dominant_effect!r}, effects={found})"
