"""The masses a record identifies.

A chain's model range is a little wider than the training input (``make_fitters``), so
some cells' relays never switch after the record's first sample: those whose rising
threshold lies above every input, and those switched up by the first input whose
falling threshold lies below every input. Their columns in the least squares are
constant, the offset's own: the record does not identify their masses, and the
solver spreads the offset over them in some way of its own. A further record that
starts elsewhere (lower, or after other history) switches them, and their arbitrary
masses then show as an offset on it, which the effects (drift, a per-record offset,
an initial state) take for one of theirs. So a fitted model keeps only the masses the
record identifies: the others are zero, their constant contribution moved to the
offset (the same output on the record, to rounding).
"""
from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from preisach.model import PreisachModel


def unidentified(model: PreisachModel, u: NDArray[np.float64]) -> NDArray[np.bool_]:
    """The cells (``model.weights``' shape: falling threshold's cell by rising
    threshold's cell) whose relay does not switch after the first sample of input ``u``
    (from every relay down)."""
    lv = model.levels
    n = model.n_h
    lo_cell = np.arange(n)
    beta_hi = lv[1:][:, None]  # the falling threshold's cell, upper edge (rows)
    alpha_lo, alpha_hi = lv[:-1][None, :], lv[1:][None, :]  # the rising threshold's cell (columns)
    never_up = float(np.max(u)) <= alpha_lo
    up_first_never_down = (float(u[0]) >= alpha_hi) & (float(np.min(u)) >= beta_hi)
    upper = lo_cell[:, None] <= lo_cell[None, :]
    out: NDArray[np.bool_] = (never_up | up_first_never_down) & upper
    return out


def identified(model: PreisachModel, u: NDArray[np.float64]) -> PreisachModel:
    """``model`` with the masses input ``u`` does not identify set to zero and their
    constant contribution on ``u`` moved into the offset (the model as given when that
    contribution is not constant: a layout the rule above does not describe)."""
    w = model.weights
    cells = unidentified(model, u)
    if w.shape != cells.shape or not np.any(cells & (w != 0)):
        return model
    part = PreisachModel(np.where(cells, w, 0.0), model.u_range, 0.0, model.output).predict(u)
    if float(np.ptp(part)) > 1e-9 * max(1.0, float(np.sum(np.abs(w)))):
        return model
    return PreisachModel(np.where(cells, 0.0, w), model.u_range, model.offset + float(part[0]), model.output)
