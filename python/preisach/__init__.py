"""preisach: identify, invert, simulate and diagnose the Preisach hysteresis model for
piezoelectric nanopositioning stages and other smart-material actuators.

Rust core (``preisach._preisach``) with a thin Python API:

- :class:`PreisachModel`: ``fit``, ``predict``, ``stream``, ``invert``, ``inverter``,
  ``save`` / ``load``;
- :class:`Chain`: blocks in series (a stage, a model, a model plus effects), with
  ``predict`` / ``simulate`` on records; :func:`load` reads any model, chain or stage file;
- :mod:`preisach.sim`: the plant simulator (:class:`~preisach.sim.Stage`) and the
  100 kHz sample loop;
- :func:`diagnose`: where the sim-to-real gap lies and which effect causes it.
"""
from __future__ import annotations

from preisach._preisach import __version__
from preisach.model import FitReport, PreisachModel, PreisachWarning, Stream
from preisach import sim
from preisach.chain import Chain, load
from preisach.diagnose import GapReport, diagnose

__all__ = ["Chain", "FitReport", "GapReport", "PreisachModel", "PreisachWarning", "Stream", "__version__",
           "diagnose", "load", "sim"]
