"""preisach: identify, invert, simulate and diagnose the Preisach hysteresis model."""
from __future__ import annotations

from preisach._preisach import __version__

__all__ = ["__version__"]
