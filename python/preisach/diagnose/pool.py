"""The fit sessions of one diagnosis, built once per problem.

A fit session (``_preisach.Behind``) serves one thread at a time, so every fitter builds
one per thread, and the diagnosis makes many fitters of the same record (each candidate's
cross-fits, the finer grid, the slow effects' windows). Building a session means the
rows of every sample and the Gram matrix of the preconditioner: on a noisy input, a row
per sample and most of a second of work. The pool builds each problem (input, grid,
window, smoothness weight, memory at the start) once, as a template that never solves,
and hands out copies (``Behind.fork``: the same rows, a preconditioner of its own, a
cold start), so a copy fits exactly as a session built anew would. The templates of one
input, memory and grid at other windows share the masses' projection (``Behind.share``):
it depends on the input's samples only, and is built once, by the first projection of
any of their copies.
"""
from __future__ import annotations

import hashlib
import threading
from typing import Any

import numpy as np
from numpy.typing import NDArray

#: Templates kept (the oldest goes first): a diagnosis fits on a handful of inputs (the
#: training record, its halves, the holdouts' parts) at two or three windows each.
KEPT = 12


class Sessions:
    """Templates of fit sessions by problem, and copies of them for the fitters."""

    def __init__(self, kept: int = KEPT) -> None:
        self.kept = kept
        self._lock = threading.Lock()
        self._templates: dict[tuple[Any, ...], Any] = {}
        #: One lock per problem: a second fitter waits for the template being built
        #: rather than build it again; other problems build meanwhile.
        self._building: dict[tuple[Any, ...], threading.Lock] = {}

    def session(self, u: NDArray[np.float64], n_h: int, u_range: tuple[float, float], stride: int,
                tie: float, extrema: tuple[float, ...] = ()) -> Any:
        """A new session of the problem (``u`` C-contiguous float64; ``extrema``: the
        memory at its start, ``Behind``'s ``initial_extrema``)."""
        from preisach import _preisach

        problem = (hashlib.blake2b(u.data, digest_size=16).digest(), u.size, n_h, u_range, tie, extrema)
        key = (problem, stride)
        with self._lock:
            building = self._building.setdefault(key, threading.Lock())
        with building:
            with self._lock:
                template = self._templates.get(key)
            if template is None:
                template = _preisach.Behind(u, n_h, u_range, stride, tie=tie, initial_extrema=list(extrema))
                with self._lock:
                    peer = next((t for (p, _), t in self._templates.items() if p == problem), None)
                    if peer is not None:
                        template.share(peer)
                    if len(self._templates) >= self.kept:
                        old = next(iter(self._templates))
                        del self._templates[old]
                        self._building.pop(old, None)
                    self._templates[key] = template
        return template.fork()
