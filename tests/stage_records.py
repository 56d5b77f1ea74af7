"""Records from the project's simulator for the diagnosis tests: a random hysteresis
(``independent_stage.true_hysteresis``) then ``blocks``; a training record and two
holdouts (triangle, steps), absolute time running on across them."""
from __future__ import annotations

from typing import Any, Sequence

import independent_stage as bv
import numpy as np
from preisach.sim import Stage, hysteresis_block


def stage_records(seed: int, blocks: Sequence[dict[str, Any]], fs: float = 20e3, noise: float = 0.003,
                  gap_s: float = 1.0, offsets: Sequence[float] = (0.0, 0.0, 0.0)
                  ) -> list[dict[str, np.ndarray]]:
    """The records, each with its session's output ``offsets`` and white ``noise``, ``gap_s``
    between them."""
    rng = np.random.default_rng(seed)
    stage = Stage([hysteresis_block(bv.true_hysteresis(rng))] + list(blocks), sample_rate_hz=fs)
    recs, t0 = [], 0.0
    for kind, off in zip(("train", "triangle", "steps"), offsets):
        u = bv.waveform(kind, fs, 1.5, rng)
        t = t0 + np.arange(u.size) / fs
        recs.append({"t": t, "u": u, "y": stage.simulate(t, u) + off + noise * rng.standard_normal(u.size)})
        t0 = float(t[-1]) + gap_s
    return recs
