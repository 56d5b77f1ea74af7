"""A low-pass or a delay: the record's timing is not a low-pass.

At the frequencies a record excites well below its cutoff, a low-pass acts as a delay of
its group delay: a capture's own lag (a sample of ADC latency, half a sample of the
DAC's hold, an anti-aliasing filter near Nyquist) is fitted as well by either. A
low-pass whose group delay is no longer than the shortest lag the diagnosis calls a
delay (two samples) is such a lag unless it beats the chain with the same lag as a pure
delay (its group delay added to the chain's delay) by the rule any candidate must pass:
it shrinks that chain's holdout RMSE by ``min_shrink`` and by more than half the floor
(noise or repeatability). The two chains share the masses: only the block differs. A
low-pass in the band of the records' excitation does: it loses gain as well as phase,
which no delay does.
"""
from __future__ import annotations

from typing import Any, Callable

from preisach.diagnose.effects import FitState
from preisach.diagnose.search import group_delay, less

Effects = dict[str, dict[str, Any]]


def delay_equivalent(eff: Effects) -> Effects:
    """The chain with its low-pass replaced by a delay of the low-pass's group delay
    (added to the chain's delay)."""
    return less(eff, "lowpass")


def is_timing(score: Callable[[FitState], float], st: FitState, sc: float, min_shrink: float, floor: float,
              min_delay: float) -> bool:
    """Whether the chain's low-pass is the record's timing: its group delay is no longer
    than ``min_delay`` (the shortest lag called a delay) and the chain ``st`` (holdout RMSE
    ``sc``) does not beat its delay equivalent (the same masses: the holdout error of
    masses refitted elsewhere moves with the fit itself) by the candidates' rule."""
    if group_delay(st.effects["lowpass"]) > min_delay:
        return False
    sc_d = score(FitState(st.model, delay_equivalent(st.effects), st.train_rmse))
    return sc_d - sc < max(min_shrink * sc_d, 0.5 * floor)

#: Why a low-pass that does no better than a delay of its lag is refused.
TIMING = "no better than a delay of its lag (the record's timing)"
