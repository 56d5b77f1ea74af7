"""PNG plots of models, comparisons and tracking runs (the paper's figures 6b, 8 and 12).

matplotlib is an optional extra (``pip install 'preisach[plot]'``); it is imported only
when a plot is drawn, with the non-interactive Agg backend. Every function takes plain
arrays (or a :class:`~preisach.PreisachModel`, or :class:`~preisach.Comparison`
results), writes one PNG and returns its path. :func:`available` tells whether
matplotlib is installed without importing it.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Any, Mapping, Optional, Sequence

import numpy as np
from numpy.typing import ArrayLike

from preisach._validate import as_number, as_signal
from preisach.io import PathLike, atomic_write

__all__ = ["HINT", "available", "plot_compare", "plot_errors", "plot_loop", "plot_spectra", "plot_tracking",
           "plot_weights"]

#: How to get the plots when matplotlib is missing.
HINT = "plots need matplotlib: pip install 'preisach[plot]'"


def available() -> bool:
    """True if matplotlib can be imported (without importing it)."""
    return importlib.util.find_spec("matplotlib") is not None


def _plt() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ValueError(HINT) from None
    return plt


def _signals(**arrays: ArrayLike) -> list[Any]:
    """The arrays as 1-D finite float64 of one length; errors name the argument."""
    out = [as_signal(name, x) for name, x in arrays.items()]
    first = next(iter(arrays))
    for name, a in zip(arrays, out):
        if a.size != out[0].size:
            raise ValueError(f"{name}: length {a.size} does not match {first} (length {out[0].size})")
    return out


def _save(fig: Any, path: PathLike) -> str:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    import matplotlib.pyplot as plt

    try:
        atomic_write(p, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))
    finally:
        plt.close(fig)
    return str(p)


def plot_weights(model: Any, path: PathLike, input_unit: str = "V", output_unit: str = "V") -> str:
    """The Preisach weights as a heatmap over the (α, β) half plane (the paper's Fig. 6b): α
    (switch-on level) across, β (switch-off level) up, cells below the diagonal blank."""
    from preisach.model import PreisachModel

    if not isinstance(model, PreisachModel):
        raise ValueError(f"model: expected a preisach.PreisachModel, got {type(model).__name__}")
    plt = _plt()
    w = np.asarray(model.weights, dtype=np.float64)
    n = w.shape[0]
    lo, hi = model.u_range
    shown = np.where(np.triu(np.ones((n, n), dtype=bool)), w, np.nan)
    fig, ax = plt.subplots(figsize=(6.4, 5.4))
    im = ax.imshow(shown, origin="lower", extent=(lo, hi, lo, hi), cmap="viridis", interpolation="nearest")
    ax.set(xlabel=f"α, switch-on level [{input_unit}]", ylabel=f"β, switch-off level [{input_unit}]",
           title=f"Preisach weights, n_h = {n} (blank: β > α)")
    fig.colorbar(im, ax=ax, label=f"weight [{output_unit}]")
    return _save(fig, path)


def plot_loop(t: ArrayLike, u: ArrayLike, measured: ArrayLike, model: ArrayLike, path: PathLike,
              input_unit: str = "V", output_unit: str = "V", title: str = "") -> str:
    """Model vs measurement (the paper's Fig. 8): (a) both over time, (b) the hysteresis loop
    output against input."""
    t, u, ym, yp = _signals(t=t, u=u, measured=measured, model=model)
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.6))
    ax[0].plot(t, ym, "k", lw=0.9, label="measured")
    ax[0].plot(t, yp, "tab:red", lw=0.9, ls="--", label="model")
    ax[0].set(xlabel="time [s]", ylabel=f"output [{output_unit}]", title=f"(a) {title}".strip())
    ax[0].legend(loc="best")
    ax[1].plot(u, ym, "k", lw=0.9, label="measured")
    ax[1].plot(u, yp, "tab:red", lw=0.9, ls="--", label="model")
    ax[1].set(xlabel=f"input [{input_unit}]", ylabel=f"output [{output_unit}]", title="(b) hysteresis loop")
    ax[1].legend(loc="best")
    for a in ax:
        a.grid(alpha=0.3)
    return _save(fig, path)


def plot_tracking(t: ArrayLike, reference: ArrayLike, measured: ArrayLike, path: PathLike,
                  unit: str = "V", title: str = "") -> str:
    """Tracking (the paper's Fig. 12): (a) reference, measurement and error over time,
    (b) measurement against reference (a straight line when hysteresis is compensated)."""
    t, r, y = _signals(t=t, reference=reference, measured=measured)
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(12, 4.6))
    ax[0].plot(t, r, "k", lw=0.9, label="reference")
    ax[0].plot(t, y, "tab:blue", lw=0.8, label="measured")
    ax[0].plot(t, r - y, "tab:red", lw=0.8, label="error")
    ax[0].set(xlabel="time [s]", ylabel=f"position [{unit}]", title=f"(a) {title}".strip())
    ax[0].legend(loc="best")
    ax[1].plot(r, y, "tab:blue", lw=0.8, label="measured")
    lim = [float(min(r.min(), y.min())), float(max(r.max(), y.max()))]
    ax[1].plot(lim, lim, "k--", lw=0.8, label="ideal")
    ax[1].set(xlabel=f"reference [{unit}]", ylabel=f"measured [{unit}]", title="(b) measured vs reference")
    ax[1].legend(loc="best")
    for a in ax:
        a.grid(alpha=0.3)
    return _save(fig, path)


def plot_errors(errors: Mapping[str, tuple[ArrayLike, ArrayLike]], path: PathLike, unit: str = "V",
                title: str = "") -> str:
    """Tracking errors over time, one line per run (label -> (t, error))."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(10, 4.2))
    for label, (t, e) in errors.items():
        ax.plot(np.asarray(t, dtype=np.float64), np.asarray(e, dtype=np.float64), lw=0.8, label=label)
    ax.set(xlabel="time [s]", ylabel=f"error [{unit}]", title=title)
    ax.grid(alpha=0.3)
    ax.legend(loc="best")
    return _save(fig, path)


def plot_spectra(signals: Mapping[str, ArrayLike], sample_rate_hz: float, path: PathLike, unit: str = "V",
                 title: str = "", mark_hz: Optional[float] = None) -> str:
    """Amplitude spectra (Hann window, one-sided, amplitude units) of several signals,
    e.g. the inverted inputs of each method; ``mark_hz`` draws a dotted line (such as
    the stage's resonance)."""
    if not isinstance(signals, Mapping) or not signals:
        raise ValueError(f"signals: expected a non-empty dict of name -> array, got {type(signals).__name__}")
    arrays = {str(name): as_signal(f"signals[{name!r}]", x) for name, x in signals.items()}
    fs = as_number("sample_rate_hz", sample_rate_hz)
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"sample_rate_hz: must be finite and > 0, got {fs}")
    plt = _plt()
    fig, ax = plt.subplots(figsize=(9, 4.8))
    for name, a in arrays.items():
        a = a - a.mean()
        win = np.hanning(a.size)
        spec = 2 * np.abs(np.fft.rfft(a * win)) / win.sum()
        f = np.fft.rfftfreq(a.size, 1.0 / fs)
        ax.loglog(f[1:], np.maximum(spec[1:], 1e-12), lw=0.7, label=name)
    if mark_hz:
        ax.axvline(mark_hz, color="k", ls=":", lw=0.8, label=f"{mark_hz:g} Hz")
    ax.set(xlabel="frequency [Hz]", ylabel=f"amplitude [{unit}]", title=title or "amplitude spectrum",
           ylim=(1e-8, None))
    ax.grid(alpha=0.3, which="both")
    ax.legend(loc="best")
    return _save(fig, path)


def plot_compare(results: Sequence[Any], path: PathLike, input_unit: str = "", output_unit: str = "",
                 title: str = "") -> str:
    """Measured against model, one row per record (from :func:`preisach.compare`): (a)
    both over time, titled with the fit in percent and the RMSE, (b) both against the
    input, the hysteresis loop (the paper's Fig. 8), (c) the residual ``y - y_hat``."""
    if not results:
        raise ValueError("results: nothing to plot")
    plt = _plt()
    n = len(results)
    fig, axes = plt.subplots(n, 3, figsize=(15, 3.4 * n + 0.4 * bool(title)), squeeze=False)
    out = f" [{output_unit}]" if output_unit else ""
    inp = f" [{input_unit}]" if input_unit else ""
    for (a, b, c), r in zip(axes, results):
        a.plot(r.t, r.y, "k", lw=0.9, label="measured")
        a.plot(r.t, r.y_hat, "tab:red", lw=0.9, ls="--", label="model")
        a.set(xlabel="time [s]", ylabel=f"output{out}", title=f"{r.name}: fit {r.fit_percent:.2f} %, RMSE {r.rmse:.3g}")
        a.legend(loc="best")
        b.plot(r.u, r.y, "k", lw=0.7, label="measured")
        b.plot(r.u, r.y_hat, "tab:red", lw=0.7, ls="--", label="model")
        b.set(xlabel=f"input{inp}", ylabel=f"output{out}", title="hysteresis loop")
        c.plot(r.t, r.y - r.y_hat, "tab:blue", lw=0.8)
        c.axhline(0.0, color="k", lw=0.6)
        c.set(xlabel="time [s]", ylabel=f"residual y - model{out}", title=f"max |error| {r.max_error:.3g}")
        for ax in (a, b, c):
            ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    return _save(fig, path)
