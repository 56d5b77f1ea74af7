"""diagnose: the effect registry and the steps; effects cross-fitted on the holdouts; a
simulator kept as the baseline. Records from the independent rig (``tests/rig.py``) and
from the project's simulated stage (``preisach.sim.Stage``)."""
import inspect
import math

import numpy as np
import pytest

from preisach.diagnose import steps
from preisach.diagnose.effects import CANDIDATES, Record
from preisach.diagnose.ranges import search_ranges
from preisach.diagnose.registry import REGISTRY, SLOW_FIRST, Scale, trivial


# ----------------------------------------------------------------- the registry
def _scale(fs=10e3):
    t = np.arange(2000) / fs
    u = 5 + 4 * np.sin(2 * np.pi * 5 * t)
    return Scale(min_delay=2 / fs, fit_dt=1 / fs, train=Record("train", t, u, 0.2 * u, 1 / fs), t_span=1.0,
                 floor=1e-3)


def test_every_candidate_has_one_registry_entry_with_ranges_and_a_search():
    assert tuple(REGISTRY) == CANDIDATES
    assert set(SLOW_FIRST) <= set(REGISTRY)
    t = np.arange(5000) / 10e3
    ranges = search_ranges(np.sin(2 * np.pi * 10 * t), 1e-4, 0.5, 1e-4)
    from preisach.diagnose.search import SCALARS, Fitter

    for name, e in REGISTRY.items():
        assert e.block == name and e.ranges(ranges), name
        # The search named is a Fitter method; the scalars polished are the entry's.
        assert callable(getattr(Fitter, e.search.split(":")[0].split(".")[1])), name
        assert {k for k, _ in SCALARS[name]} <= set(e.scalars) | {"tau", "amp"}, name
        if e.cross_fit == "halves":
            assert e.agree[0] in e.scalars and e.agree[1] > 0, name
        assert e.slow == (name in ("creep", "drift")) and (e.cross_fit == "") == e.slow


@pytest.mark.parametrize("name, small, real", [
    ("delay", {"delay_s": 1e-4}, {"delay_s": 5e-4}),  # two samples at 10 kHz: 2e-4 s
    ("vibration", {"frequency_hz": 800.0, "damping": 0.3}, {"frequency_hz": 800.0, "damping": 0.02}),
    ("vibration", {"frequency_hz": 4500.0, "damping": 0.02}, {"frequency_hz": 3500.0, "damping": 0.02}),
    ("lowpass", {"cutoff_hz": 3500.0, "order": 1}, {"cutoff_hz": 2500.0, "order": 1}),
    ("creep", {"taus_s": [0.1], "amplitudes": [0.002]}, {"taus_s": [0.1], "amplitudes": [0.01]}),
    ("creep", {"taus_s": [1e-3], "amplitudes": [0.05]}, {"taus_s": [6e-3], "amplitudes": [0.05]}),
    ("drift", {"gain_per_s": 0.0, "offset_per_s": 1e-3}, {"gain_per_s": 0.0, "offset_per_s": 1e-2}),
    ("rate", {"gain_s": 1e-6, "tau_s": 1e-3}, {"gain_s": 1e-3, "tau_s": 1e-3}),
])
def test_each_effect_declares_what_a_trivial_fit_of_it_is(name, small, real):
    s = _scale()
    assert trivial(name, small, s) and not trivial(name, real, s)


def test_every_step_fits_on_a_screen():
    import preisach.diagnose as d
    from preisach.diagnose import crossfit, outcome

    for mod in (steps, outcome, crossfit, d):
        for name, fn in inspect.getmembers(mod, inspect.isfunction):
            if fn.__module__ == mod.__name__:
                assert len(inspect.getsource(fn).splitlines()) <= 70, (mod.__name__, name)
