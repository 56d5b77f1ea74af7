"""Regenerate ``paper_ident.csv``: the paper's identification input (an increasing-
amplitude sine with 100 reversals, the paper §3.2, Fig. 6a) run through the simulated
``paper`` stage at 100 kHz (which starts at rest), kept at 10 kHz. Columns t [s], u [DAC V], y [sensor V]."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from preisach.io import write_csv
from preisach.sim import Stage

fs = 100_000.0
n_rev, f = 100, 20.0
t = np.arange(int(fs * n_rev / (2 * f))) / fs
u = 3.75 + 3.75 * np.linspace(0.02, 1.0, t.size) * np.sin(2 * np.pi * f * t)
stage = Stage.preset("paper")
y = stage.run(u)
keep = slice(None, None, 10)
out = Path(__file__).with_name("paper_ident.csv")
write_csv(out, {"t": t[keep], "u": u[keep], "y": y[keep]})
print(f"wrote {out} ({t[keep].size} samples)")
