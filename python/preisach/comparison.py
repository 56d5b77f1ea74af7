"""How well a model reproduces measured records, as MATLAB's ``compare`` reports it.

For each record: the fit in percent, ``100 (1 - ‖y - ŷ‖ / ‖y - mean(y)‖)`` (the
normalized root-mean-square error fit of MATLAB's ``compare`` and ``goodnessOfFit(...,
'NRMSE')``: 100 is a perfect fit, 0 is no better than the record's mean, and it can be
negative), the RMSE and the largest absolute error, in the output's units.
:func:`preisach.plots.plot_compare` draws measured against model and the residual.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Optional, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from preisach._validate import as_signal
from preisach.io import PathLike

__all__ = ["Comparison", "compare", "fit_percent", "table"]


def fit_percent(y: ArrayLike, y_hat: ArrayLike) -> float:
    """The NRMSE fit ``100 (1 - ‖y - ŷ‖ / ‖y - mean(y)‖)`` in percent, as MATLAB's
    ``compare``. A constant record ``y`` gives ``-inf`` (``nan`` if also matched
    exactly), as the division does in MATLAB."""
    yy = as_signal("y", y)
    yh = as_signal("y_hat", y_hat)
    if yy.shape != yh.shape:
        raise ValueError(f"y_hat: length {yh.size} does not match y (length {yy.size})")
    # Scaled by the largest magnitude, so values near the float64 limits do not overflow.
    scale = float(max(np.abs(yy).max(), np.abs(yh).max())) or 1.0
    a, b = yy / scale, yh / scale
    num = float(np.linalg.norm(a - b))
    den = float(np.linalg.norm(a - a.mean()))
    if den == 0.0:
        return float("nan") if num == 0.0 else float("-inf")
    return 100.0 * (1.0 - num / den)


@dataclass(frozen=True)
class Comparison:
    """One record compared with a model: ``name``, ``fit_percent`` (NRMSE fit, see
    :func:`fit_percent`), ``rmse`` and ``max_error`` (largest ``|y - y_hat|``), in the
    output's units, and the arrays ``t``, ``u`` (input), ``y`` (measured) and ``y_hat``
    (model)."""

    name: str
    fit_percent: float
    rmse: float
    max_error: float
    t: NDArray[np.float64] = field(repr=False)
    u: NDArray[np.float64] = field(repr=False)
    y: NDArray[np.float64] = field(repr=False)
    y_hat: NDArray[np.float64] = field(repr=False)

    @property
    def residual(self) -> NDArray[np.float64]:
        """``y - y_hat``."""
        return self.y - self.y_hat

    def to_dict(self) -> dict[str, Any]:
        """The figures as a JSON-ready dict (no arrays; a fit of ``±inf``/``nan`` as None)."""
        fit = self.fit_percent if np.isfinite(self.fit_percent) else None
        return {"record": self.name, "samples": int(self.y.size), "fit_percent": fit, "rmse": self.rmse,
                "max_error": self.max_error}


def compare(model: Any, record: Union[PathLike, Mapping[str, ArrayLike]], name: Optional[str] = None) -> Comparison:
    """Compare a model's output with the measured ``y`` of a record.

    Parameters
    ----------
    model : PreisachModel, or an object with ``predict(t, u)``
        A :class:`~preisach.PreisachModel` (run on ``u``), or a chain (run on ``t`` and
        ``u``, as ``preisach predict`` runs a saved chain).
    record : path or dict
        A record file (CSV or ``.npz``, read with :func:`preisach.read_record`) or a dict
        with arrays ``t``, ``u`` and ``y``.
    name : str, optional
        What the record is called in tables, plots and errors (default: the file name,
        or ``"record"``).

    Returns
    -------
    Comparison
        ``fit_percent``, ``rmse``, ``max_error`` and the arrays.
    """
    from preisach.io import read_record
    from preisach.model import PreisachModel

    if isinstance(record, Mapping):
        label = name or "record"
        rec: Mapping[str, ArrayLike] = record
    else:
        label = name or Path(record).name
        rec = read_record(record, ["t", "u", "y"])
    missing = [k for k in ("t", "u", "y") if k not in rec]
    if missing:
        raise ValueError(f"{label}: missing column(s) {', '.join(missing)}")
    t, u, y = (as_signal(f"{label}: {k}", rec[k]) for k in ("t", "u", "y"))
    if not (t.size == u.size == y.size):
        raise ValueError(f"{label}: t, u and y have different lengths ({t.size}, {u.size}, {y.size})")
    y_hat = as_signal(f"{label}: model output", model.predict(u) if isinstance(model, PreisachModel)
                      else model.predict(t, u))
    if y_hat.size != y.size:
        raise ValueError(f"{label}: the model gave {y_hat.size} samples for {y.size}")
    err = y - y_hat
    return Comparison(name=label, fit_percent=fit_percent(y, y_hat), rmse=float(np.sqrt(np.mean(err**2))),
                      max_error=float(np.abs(err).max()), t=t, u=u, y=y, y_hat=y_hat)


def table(results: list[Comparison]) -> str:
    """The comparisons as a fixed-width text table (one line per record)."""
    width = max([len("record")] + [len(r.name) for r in results])
    lines = [f"{'record':{width}s} {'samples':>9s} {'fit [%]':>9s} {'RMSE':>12s} {'max |error|':>12s}"]
    for r in results:
        lines.append(f"{r.name:{width}s} {r.y.size:9d} {r.fit_percent:9.2f} {r.rmse:12.6g} {r.max_error:12.6g}")
    return "\n".join(lines)
