"""The effects the diagnosis knows, one entry each.

Every effect declares the chain block it adds, the scalars its search moves (their
ranges come from the records: :func:`preisach.diagnose.ranges.search_ranges`), the
search that fits it (a :class:`~preisach.diagnose.search.Fitter` method), whether it
is recalibrated across records, whether it may be fitted on the holdouts
(cross-fitting), and its evidence: what makes a fit of it a real effect of that kind
(``trivial``: parameters too small or too large to be one) beyond the rule every effect
meets (it shrinks the holdout error of its chain, beats a finer hysteresis alone and the
repeatability floor, and no parameter ends at a search bound), and where it applies the
held-out evidence of its kind (``across_records``, ``beats_delay``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Optional

import numpy as np
from numpy.typing import NDArray

from preisach.diagnose.effects import Record, rate_branch, rmse
from preisach.diagnose.ranges import CREEP_TAU_MIN, Bound, Ranges
from preisach.diagnose.search import Effects, Fitter

Params = dict[str, Any]


@dataclass(frozen=True)
class Scale:
    """What tells a real effect from a trivial fit: the shortest delay the sampling
    cannot explain, the fit's sample period, the training record, the time the records
    span and the noise floor."""

    min_delay: float
    fit_dt: float
    train: Record
    t_span: float
    floor: float


@dataclass(frozen=True)
class Effect:
    """One effect: ``block`` (the chain block it adds), ``scalars`` (what its search
    moves), ``search`` (the :class:`~preisach.diagnose.search.Fitter` method that
    searches it; every search ends with a joint polish of the effects it trades off
    against), ``evidence`` (what makes a fit of it real), ``trivial`` (that test),
    ``slow`` (recalibrated across records by ``calibrate_slow``), ``cross_fit`` (how it
    is fitted on some holdouts and scored on the others when the training record does not
    show it: ``"halves"``, its search on half of a holdout, scored on the other halves;
    ``"added"``, only the delay added to the chain found; ``""``, not: a slow effect is
    calibrated across records anyway), ``agree`` (the folds of a cross-fit agree when
    ``agree[0]`` differs between them by at most the fraction ``agree[1]``),
    ``across_records`` (its parameters hold on a record they were not calibrated on:
    drift's trend runs on in absolute time, so calibrated on the other records it still
    shrinks each holdout's error; a record's own error, the model's on its input, does
    not carry over), ``beats_delay`` (at the records' frequencies it acts as a lag, so
    its chain must beat the same chain with a delay in its place: the record's timing or
    a real delay), ``acts_as_lag`` (it acts partly as a lag, so once a delay only the holdouts
    carry is in the chain it must still earn its place without that lag:
    ``steps.drop_standins``)."""

    name: str
    block: str
    scalars: tuple[str, ...]
    search: str
    evidence: str
    trivial: Callable[[Params, Scale], bool]
    slow: bool = False
    cross_fit: str = "halves"
    agree: tuple[str, float] = ("", 0.0)
    across_records: bool = False
    beats_delay: bool = False
    acts_as_lag: bool = False

    def ranges(self, ranges: Ranges) -> dict[str, Bound]:
        """This effect's search ranges (from the data)."""
        return ranges.get(self.name, {})

    def fit(self, fitter: Fitter, base: Effects, h: Optional[NDArray[np.float64]] = None,
            held: Optional[Callable[[Effects], float]] = None) -> Effects:
        """The chain ``base`` plus this effect, searched on ``fitter``'s record (``held``:
        a chain's cross-fitted error on the other records, for the effects whose search
        chooses on them)."""
        return fitter.add(base, self.name, h, held)


def _delay(p: Params, s: Scale) -> bool:
    return bool(p["delay_s"] <= s.min_delay)  # the sampling's own timing, not a delay


def _vibration(p: Params, s: Scale) -> bool:
    # A "mode" damped beyond 0.15 is a lag (the low-pass's business), not ringing.
    return bool(p["damping"] > 0.15 or p["frequency_hz"] > 0.4 / s.fit_dt)


def _lowpass(p: Params, s: Scale) -> bool:
    return bool(p["cutoff_hz"] > 0.3 / s.fit_dt)


def _creep(p: Params, s: Scale) -> bool:
    return float(sum(p["amplitudes"])) < 0.003 or min(p["taus_s"]) < 0.99 * CREEP_TAU_MIN


def _drift(p: Params, s: Scale) -> bool:
    y_span = float(np.ptp(s.train.y)) or 1.0
    return bool(abs(p["gain_per_s"]) * s.t_span * y_span + abs(p["offset_per_s"]) * s.t_span < 3 * s.floor)


def _rate(p: Params, s: Scale) -> bool:
    # A rate-dependent loop worth the name changes the output by a visible part of its
    # span; a branch of a few 1e-4 of it corrects the timing of other effects.
    rt: NDArray[np.float64] = rate_branch(p, s.train.t, s.train.u)
    return rmse(rt) < 2e-3 * (float(np.ptp(s.train.y)) or 1.0)


def _never(p: Params, s: Scale) -> bool:
    return False


#: The effects searched by adding a block to the chain, in the order of ``CANDIDATES``.
REGISTRY: dict[str, Effect] = {e.name: e for e in (
    Effect("delay", "delay", ("delay_s",), "Fitter.add: a grid of delays to a quarter of the slowest "
           "excitation's period, then parabolic steps; the delay/low-pass valley",
           "longer than two samples (shorter is the sampling's own timing)", _delay, cross_fit="added",
           agree=("delay_s", 0.25)),
    Effect("lowpass", "lowpass", ("cutoff_hz",), "Fitter.add: a grid of cutoffs of both orders keeping the "
           "chain's lag, then the other order", "a cutoff below 0.3 x the fit's rate", _lowpass,
           agree=("cutoff_hz", 0.5), acts_as_lag=True),
    Effect("vibration", "vibration", ("frequency_hz", "damping"), "Fitter.mode_band: the residual "
           "spectrum's peaks fitted in a band, judged on the profiled error",
           "damping at most 0.15 (more is a lag) and a frequency below 0.4 x the fit's rate", _vibration,
           agree=("frequency_hz", 0.03)),
    Effect("creep", "creep", ("taus_s", "amplitudes"), "Fitter.creep_held: a grid of time constants from 5 ms "
           "to 10 record lengths, the amplitude and masses fitted on the training record at each "
           "(Fitter.creep_amp), the time constant chosen by the chain's cross-fitted error on the held-out records "
           "(parabolic steps around the best that carries creep)",
           "amplitudes summing to 0.3 % or more, a time constant of 5 ms or more", _creep, slow=True,
           cross_fit=""),
    Effect("drift", "drift", ("gain_per_s",), "Fitter.add: a grid of gains on the slow fitter, the offset "
           "slope solved with the masses", "moves the output by more than 3 noise floors over the records; "
           "calibrated on the other records it shrinks each holdout's error", _drift, slow=True, cross_fit="",
           across_records=True),
    Effect("rate", "rate", ("tau_s",), "Fitter.add: a grid of time constants, the gain solved with the masses",
           "a rate branch of 0.2 % of the output's span or more; it beats a delay in its place", _rate,
           agree=("tau_s", 1.0), beats_delay=True, acts_as_lag=True),
)}

#: The order the candidates' fits start in: the slowest first (creep's, which scores its
#: time constants on the holdouts, then a mode's; the quick ones fill the other thread),
#: so a round ends with both threads busy.
SLOW_FIRST = ("creep", "vibration", "lowpass", "delay")

#: Effects handled by their own steps rather than by adding a block: a finer grid
#: (``discretization``) and each holdout's hysteresis memory at its start
#: (``initial_state``).
OWN_STEPS = ("discretization", "initial_state")


def effect(name: str) -> Optional[Effect]:
    """The registry entry of ``name`` (None for the effects with their own steps)."""
    return REGISTRY.get(name)


def trivial(name: str, p: Params, s: Scale) -> bool:
    """Parameters too small (or too large) to be a real effect of that kind."""
    e = REGISTRY.get(name)
    return e.trivial(p, s) if e is not None else False
