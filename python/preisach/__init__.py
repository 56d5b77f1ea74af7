"""preisach: identify, invert, simulate and diagnose the Preisach hysteresis model for
piezoelectric nanopositioning stages and other smart-material actuators.

Rust core (``preisach._preisach``) with a thin Python API:

- :class:`PreisachModel`: ``fit``, ``predict``, ``stream``, ``invert``, ``inverter``,
  ``save`` / ``load``;
- :class:`Chain`: blocks in series (a stage, a model, a model plus effects), with
  ``predict`` / ``simulate`` on records, ``invert`` / ``inverter`` (feed-forward through
  the whole chain); :func:`load` reads any model, chain or stage file;
  :func:`refit_hysteresis` identifies a chain's hysteresis again behind its linear part (and
  :func:`refit_creep` its creep behind the hysteresis);
- :func:`read_record`: a record (CSV ``t,u,y`` or ``.npz``) as arrays;
- :func:`compare`: a model's fit on a record (fit %, RMSE, max error), as MATLAB's
  ``compare``; :mod:`preisach.plots` draws it;
- :mod:`preisach.sim`: the plant simulator (:class:`~preisach.sim.Stage`) and the
  100 kHz sample loop;
- :func:`diagnose`: where the sim-to-real gap lies and which effect causes it;
- :mod:`preisach.matlab`: dSPACE / MATLAB captures in, models out as MAT files.
"""
from __future__ import annotations

from preisach import plots, sim
from preisach._chain_inverse import ChainInversionInfo, ChainInverter
from preisach._preisach import __version__
from preisach._refit import refit_creep, refit_hysteresis
from preisach.chain import Chain, load
from preisach.comparison import Comparison, compare, fit_percent
from preisach.diagnose import GapReport, diagnose
from preisach.io import read_record
from preisach.model import FitReport, FittedModel, PreisachModel, PreisachWarning, Stream

__all__ = ["Chain", "ChainInversionInfo", "ChainInverter", "Comparison", "FitReport", "FittedModel", "GapReport",
           "PreisachModel", "PreisachWarning", "Stream", "__version__", "compare", "diagnose", "fit_percent", "load",
           "plots", "read_record", "refit_creep", "refit_hysteresis", "sim"]
