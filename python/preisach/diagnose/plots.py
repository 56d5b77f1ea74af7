"""PNG plots of a diagnosis (matplotlib is an optional extra, imported lazily)."""
from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

from preisach.diagnose.where import spectrum
from preisach.io import atomic_write


def _plt() -> Any:
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        raise ValueError("--plots needs matplotlib: pip install 'preisach[plot]'") from None
    return plt


def _save_png(fig: Any, path: str) -> None:
    fig.savefig(path, dpi=90, format="png")


def plot_report(rep: Any, directory: Any) -> list[str]:
    """Residual vs time per record (worst windows shaded), residual spectrum with the
    detected peaks, before/after overlays of model and measurement. Returns the files."""
    plt = _plt()
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    files = []
    for i, r in enumerate(rep._records):
        res = rep._base_res[r.name]
        w = rep.where[i]
        fig, ax = plt.subplots(3, 1, figsize=(10, 9))
        ax[0].plot(r.t, res, lw=0.5)
        for win in w["worst_windows"]:
            ax[0].axvspan(win["t0"], win["t1"], color="tab:red", alpha=0.12)
        ax[0].set(title=f"{r.name}: baseline residual (shaded: largest error)", xlabel="t [s]", ylabel="y - model")
        f, asd = spectrum(res, r.dt)
        ax[1].loglog(f[1:], asd[1:], lw=0.7)
        for p in w["peaks"]:
            ax[1].axvline(p["frequency_hz"], color="tab:red", ls=":", lw=0.8)
        ax[1].set(title="residual amplitude spectrum (dotted: peaks)", xlabel="f [Hz]", ylabel="ASD")
        yb = rep.baseline_model.predict(r.u) if not rep.baseline["effects"] else r.y - res
        ya = rep.chain.predict(r.t, r.u)
        ax[2].plot(r.t, r.y, "k", lw=0.6, label="measured")
        ax[2].plot(r.t, yb, lw=0.6, label="baseline")
        ax[2].plot(r.t, ya, lw=0.6, label="augmented")
        ax[2].legend(loc="best")
        ax[2].set(xlabel="t [s]", ylabel="y")
        fig.tight_layout()
        name = d / f"record{i}_{Path(r.name).stem.replace(' ', '_')}.png"
        atomic_write(name, functools.partial(_save_png, fig))
        plt.close(fig)
        files.append(str(name))
    return files
