"""The Python face of the discrete Preisach model (the paper §2–3; conventions in
``docs/method/model.md``)."""
from __future__ import annotations

import json
import math
import warnings
from typing import TYPE_CHECKING, Any, Literal, Optional, Sequence, TypeVar, Union, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

from preisach import _preisach
from preisach._validate import as_n_h, as_number, as_range, as_signal, check_range_reached, one_thread, upper_triangular
from preisach.io import PathLike, write_text

if TYPE_CHECKING:
    from preisach._inverse import Inverter

_OUTPUTS = ("stepwise", "interpolated")
#: Default ``diagonal_floor`` of :meth:`PreisachModel.fit` (0.01).
DIAGONAL_FLOOR: float = _preisach.DEFAULT_DIAGONAL_FLOOR
_M = TypeVar("_M", bound="PreisachModel")


class PreisachWarning(UserWarning):
    """A pitfall of the paper (§3.3) met by the identification data (too few reversals,
    an input range short of or far beyond the model range), or references an inverse
    clipped because they lie beyond the model's reachable output."""


class FitReport:
    """What identification did. Attributes: ``rmse`` (training RMSE, output units),
    ``n_samples``, ``n_rows`` (distinct relay states after merging), ``reversals``,
    ``cells_never_excited`` (never switched on; fixed to 0), ``cells_switched_once``
    (switched on but never off), ``input_range``, ``u_range``, ``solver``,
    ``iterations``, ``time_rows_s`` and ``time_solve_s`` (wall time spent merging the
    samples into rows and solving the QP), ``warnings`` (list of sentences)."""

    rmse: float
    n_samples: int
    n_rows: int
    reversals: int
    cells_never_excited: int
    cells_switched_once: int
    input_range: tuple[float, float]
    u_range: tuple[float, float]
    solver: str
    iterations: int
    time_rows_s: float
    time_solve_s: float
    warnings: list[str]

    def __init__(self, d: dict[str, Any]) -> None:
        for k, v in d.items():
            setattr(self, k, v)

    def to_dict(self) -> dict[str, Any]:
        """The report as a plain dict (JSON-ready)."""
        return {k: v for k, v in vars(self).items()}

    def __repr__(self) -> str:
        return (
            f"FitReport(rmse={self.rmse:.6g}, reversals={self.reversals}, n_rows={self.n_rows}, "
            f"cells_never_excited={self.cells_never_excited}, solver={self.solver!r}, "
            f"warnings={len(self.warnings)})"
        )


def _state_array(state: Optional[ArrayLike]) -> NDArray[np.float64]:
    if state is None:
        return np.zeros(0)
    return as_signal("state", state, allow_empty=True)


class PreisachModel:
    """A discrete Preisach model.

    Parameters
    ----------
    weights : (n_h, n_h) array
        Masses ``w[i, j] >= 0`` at the cell centres: β-cell = row, α-cell = column, upper
        triangle including the diagonal. Entries below the diagonal must be zero (a cell
        with β above α does not exist); a non-zero one is a ``ValueError``.
    u_range : (lo, hi)
        Model range (β_m, α_m); input levels ``v_k = lo + k (hi - lo) / n_h``.
    offset : float
        The constant η0 added to ``sum w R`` (the paper's eq. 4).
    output : {"stepwise", "interpolated"}
        ``stepwise`` is the relay model of the paper (the output steps when the input
        crosses a cell centre). ``interpolated`` spreads each mass uniformly over its cell,
        so the output is continuous in the input and equals the stepwise model on the
        levels (``docs/method/fast-paths.md``); it is the forward map the continuous
        inverse inverts.

    Notes
    -----
    All relays start at −1 (negative saturation) unless a ``state`` is given.
    """

    report: Optional[FitReport]

    def __init__(self, weights: ArrayLike, u_range: Sequence[float], offset: float = 0.0,
                 output: str = "stepwise") -> None:
        try:
            w = np.array(weights, dtype=np.float64, order="C")
        except (TypeError, ValueError) as exc:
            raise ValueError(f"weights: cannot be converted to a float64 array ({exc})") from None
        if w.ndim != 2 or w.shape[0] != w.shape[1]:
            raise ValueError(f"weights: expected a square (n_h, n_h) array, got shape {w.shape}")
        if w.shape[0] < 1:
            raise ValueError("n_h: must be >= 1, got 0")
        upper_triangular("weights", w)
        lo, hi = as_range("u_range", u_range)
        if not isinstance(offset, (int, float, np.floating, np.integer)) or not math.isfinite(float(offset)):
            raise ValueError(f"offset: must be a finite number, got {offset!r}")
        if output not in _OUTPUTS:
            raise ValueError(f"output: expected 'stepwise' or 'interpolated', got {output!r}")
        self._core = _preisach.Model(w, lo, hi, float(offset))
        self._output = output
        self.report = None

    @classmethod
    def _wrap(cls: type[_M], core: Any, output: str = "stepwise") -> _M:
        m = cls.__new__(cls)
        m._core = core
        m._output = output
        m.report = None
        return m

    # --- identification -------------------------------------------------------------
    @classmethod
    def fit(cls, u: ArrayLike, y: ArrayLike, n_h: int, u_range: Optional[Sequence[float]] = None,
            reg: float = 0.0, solver: str = "auto", output: str = "stepwise",
            diagonal_floor: float = DIAGONAL_FLOOR) -> "FittedModel":
        """Identify a model from input ``u`` and measured output ``y`` (the paper §3.2–3.3).

        One exact QP: non-negative least squares on the masses with a free offset
        (the paper's alternation of lsqnonneg and lsqnonlin, solved as one problem).
        Samples with identical relay state are merged into one weighted row (exact).

        Parameters
        ----------
        u, y : 1-D arrays of equal length
            Recorded input and output.
        n_h : int
            Discretization level (cells per axis; n_h + 1 input levels).
        u_range : (lo, hi), optional
            Model range. Default: the input range shrunk by 0.5 % of its span at each end,
            so the input slightly exceeds the model range as the paper advises (§3.3). A
            range the input never enters (no relay would switch) is a ``ValueError``.
        reg : float
            Smoothness weight: adds ``reg * sum (w_a - w_b)^2`` over neighbouring cells to
            the mean squared residual (both in output units squared). Default 0.
        solver : {"auto", "active", "clarabel", "structured"}
            All are exact (the same optimum). ``active``: primal–dual active set on the
            sparse Everett-coordinate KKT system, a handful of sparse factorizations
            (fastest for small and mid-size n_h; hands over to ``structured`` if it has
            not settled after 40 steps). ``structured``: clarabel's interior point on the
            sparse QP in Everett coordinates, polished to the exact optimum; never forms
            the dense matrix. ``clarabel``: clarabel on the dense QP over the masses
            (AᵀWA formed; a reference, slow beyond a few hundred cells). All handle
            n_h <= 600.
            ``auto``: ``active`` up to 2000 free cells, else ``structured``.
            ``report.solver`` says which ran.
        output : {"stepwise", "interpolated"}
            Which model to fit (see the class docstring).
        diagonal_floor : float in [0, 1)
            Lower bound on the diagonal (reversible) masses of the excited cells, as a
            fraction of the major loop's average slope: each is at least
            ``diagonal_floor * (max(y) - min(y)) / (2 * excited levels)``, so every
            branch leaving a turn of the input starts with at least that fraction of the
            average slope. Default 0.01. Without it, lag or creep in the record often
            drives fitted diagonal masses to zero: the model is then flat for up to a
            cell after each turn and its continuous inverse jumps across the flat
            (``docs/method/inversion.md``). 0 gives the plain non-negative least-squares
            fit (exact recovery of any model's masses from noise-free data).

        Returns
        -------
        FittedModel
            The model, with ``.report`` (a :class:`FitReport`). The paper's pitfalls
            are also emitted as :class:`PreisachWarning`.
        """
        uu = as_signal("u", u)
        yy = as_signal("y", y)
        if uu.shape != yy.shape:
            raise ValueError(f"y: length {yy.size} does not match u (length {uu.size})")
        nh = as_n_h(n_h)
        rng = None if u_range is None else as_range("u_range", u_range)
        if rng is not None:
            check_range_reached("u_range", uu, rng, nh)
        if not isinstance(reg, (int, float, np.floating, np.integer)) or not math.isfinite(float(reg)) or reg < 0:
            raise ValueError(f"reg: must be a finite number >= 0, got {reg!r}")
        if output not in _OUTPUTS:
            raise ValueError(f"output: expected 'stepwise' or 'interpolated', got {output!r}")
        if (isinstance(diagonal_floor, bool) or not isinstance(diagonal_floor, (int, float, np.floating, np.integer))
                or not 0 <= float(diagonal_floor) < 1):
            raise ValueError(f"diagonal_floor: must be a number in [0, 1), got {diagonal_floor!r}")
        core, rep = _preisach.fit(uu, yy, nh, rng, float(reg), str(solver), output == "interpolated",
                                  float(diagonal_floor))
        model = FittedModel._wrap(core, output)
        model.report = FitReport(rep)
        for w in rep["warnings"]:
            warnings.warn(w, PreisachWarning, stacklevel=2)
        return model

    # --- attributes ----------------------------------------------------------------
    @property
    def n_h(self) -> int:
        """Discretization level (cells per axis)."""
        return int(self._core.n_h)

    @property
    def u_range(self) -> tuple[float, float]:
        """Model range (lo, hi) = (β_m, α_m)."""
        return (float(self._core.lo), float(self._core.hi))

    @property
    def levels(self) -> NDArray[np.float64]:
        """The n_h + 1 input levels."""
        return self._core.levels()

    @property
    def weights(self) -> NDArray[np.float64]:
        """Masses as an (n_h, n_h) array (a copy), zero below the diagonal."""
        return self._core.weights()

    @property
    def offset(self) -> float:
        """The constant output offset η0."""
        return float(self._core.offset)

    @property
    def output(self) -> str:
        """``"stepwise"`` or ``"interpolated"``."""
        return self._output

    def __repr__(self) -> str:
        lo, hi = self.u_range
        return (f"PreisachModel(n_h={self.n_h}, u_range=({lo:.6g}, {hi:.6g}), offset={self.offset:.6g}, "
                f"output={self._output!r})")

    # --- forward -------------------------------------------------------------------
    @overload
    def predict(self, u: ArrayLike, state: Optional[ArrayLike] = None, *, return_state: Literal[False] = False,
                output: Optional[str] = None) -> NDArray[np.float64]: ...

    @overload
    def predict(self, u: ArrayLike, state: Optional[ArrayLike] = None, *, return_state: Literal[True],
                output: Optional[str] = None) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...

    def predict(self, u: ArrayLike, state: Optional[ArrayLike] = None, *, return_state: bool = False,
                output: Optional[str] = None
                ) -> Union[NDArray[np.float64], tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """Model output for input ``u`` from ``state`` (default: all relays −1).

        ``state`` is a memory snapshot (``stream().state``, or the second value returned
        with ``return_state=True``): the dominant extrema and the last input, in input
        units. ``output`` overrides the model's own output kind. Returns a float64 array
        (and the final state if ``return_state``)."""
        uu = as_signal("u", u, allow_empty=True)
        kind = self._output if output is None else output
        if kind not in _OUTPUTS:
            raise ValueError(f"output: expected 'stepwise' or 'interpolated', got {kind!r}")
        y, st = self._core.predict(uu, _state_array(state), kind == "interpolated")
        return (y, st) if return_state else y

    def stream(self, state: Optional[ArrayLike] = None) -> "Stream":
        """A sample-by-sample operator (the memory staircase), for real-time loops."""
        return Stream(self._core.stream(_state_array(state)))

    # --- inversion (the paper §4) -----------------------------------------------------
    def invert(self, r: ArrayLike, method: str = "closest", lookahead: Optional[int] = None) -> NDArray[np.float64]:
        """Input that makes the model follow reference ``r`` (see :mod:`preisach._inverse`).

        ``method``: ``"closest"`` (closest match over the levels, Tan et al. 2001),
        ``"interpolated"`` (the paper's linear interpolation between the steps of the
        closest match, Fig. 9; ``lookahead`` samples of preview, None = whole record) or
        ``"continuous"`` (exact inverse of the interpolated model, no look-ahead)."""
        from preisach._inverse import invert

        return invert(self, r, method=method, lookahead=lookahead)

    def inverter(self, method: str = "closest", lookahead: Optional[int] = None) -> "Inverter":
        """A streaming inverter with ``.step(r)``, ``.process(block)`` and ``.state``."""
        from preisach._inverse import Inverter

        return Inverter(self, method=method, lookahead=lookahead)

    # --- persistence ---------------------------------------------------------------
    def to_json(self) -> str:
        """The JSON text :meth:`save` writes: a version-2 ``preisach-chain`` of one
        identified hysteresis block, with the fit report."""
        from preisach.chain import Chain

        return Chain(self).to_json()

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready dict :meth:`save` writes (see :meth:`to_json`)."""
        return dict(json.loads(self.to_json()))

    @classmethod
    def _of_chain(cls, chain: Any) -> Optional["PreisachModel"]:
        """The model of a chain that is one identified hysteresis block (no initial
        state), else None."""
        if chain.kinds() != ["hysteresis"] or chain.initial_input is not None:
            return None
        got = chain._core.identified_model(0)
        block = chain.blocks[0]
        if got is None or block.get("initial_extrema"):
            return None
        model = cls._wrap(*got)
        report = chain.to_dict().get("report")
        if isinstance(report, dict):
            model.report = FitReport(report)
        return model

    @classmethod
    def from_dict(cls, d: Any, source: str = "model") -> "PreisachModel":
        """Rebuild a model from :meth:`to_dict` output (or a version-1 model dict),
        validating every field."""
        from preisach.chain import Chain

        model = cls._of_chain(Chain.from_dict(d, source=source))
        if model is None:
            raise ValueError(f"{source}: a chain of blocks, not a single identified model; use preisach.load")
        return model

    def save(self, path: PathLike) -> None:
        """Write the model (atomically: temporary file, then rename) as a version-2
        ``preisach-chain`` of one identified hysteresis block, with its fit report."""
        write_text(path, self.to_json() + "\n")

    @classmethod
    def load(cls, path: PathLike) -> "PreisachModel":
        """Read a model saved by :meth:`save` (or a version-1 model file); rejects bad
        files, and chains of more than the model, with a clear ValueError."""
        from preisach.chain import Chain

        chain = Chain.load(path)
        model = cls._of_chain(chain)
        if model is None:
            raise ValueError(f"{path}: a chain ({' -> '.join(chain.kinds())}), not a single identified model: "
                             f"use preisach.load")
        return model


class FittedModel(PreisachModel):
    """What :meth:`PreisachModel.fit` returns: a :class:`PreisachModel` whose ``report``
    is always a :class:`FitReport` (type checkers see it as set, not ``Optional``)."""

    report: FitReport


class Stream:
    """Sample-by-sample forward operator. ``step(u) -> float``, ``process(block) ->
    ndarray``; ``state`` gets a snapshot (input values) and restores one when set.
    One stream serves one thread at a time: a call while another thread is inside it
    raises ``RuntimeError`` (give each thread its own stream)."""

    def __init__(self, core: Any) -> None:
        self._core = core

    @one_thread
    def step(self, u: float) -> float:
        """Advance one sample and return the output."""
        return float(self._core.step(as_number("u", u)))

    @one_thread
    def process(self, block: ArrayLike) -> NDArray[np.float64]:
        """Advance over a block of samples; returns the outputs."""
        return self._core.process(as_signal("block", block, allow_empty=True))

    @property
    @one_thread
    def state(self) -> NDArray[np.float64]:
        """Snapshot of the memory: dominant extrema then the current input (input units)."""
        return self._core.get_state()

    @state.setter
    @one_thread
    def state(self, value: ArrayLike) -> None:
        self._core.set_state(as_signal("state", value, allow_empty=True))
