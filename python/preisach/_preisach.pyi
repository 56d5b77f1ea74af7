"""Type stubs of the compiled module `preisach._preisach` (checked by mypy.stubtest)."""
from typing import Any, Optional, Sequence

import numpy as np
from numpy.typing import NDArray
from typing_extensions import final

__version__: str
__all__ = [
    "__version__", "Model", "Stream", "fit", "fit_behind", "lti", "Behind", "regression_rows", "invert",
    "InverseStream", "Chain", "run_loop",
]

# --- core (model, stream, identification) ---
@final
class Model:
    def __new__(cls, weights: NDArray[np.float64], lo: float, hi: float, offset: float) -> Model: ...
    def weights(self) -> NDArray[np.float64]: ...
    @property
    def n_h(self) -> int: ...
    @property
    def lo(self) -> float: ...
    @property
    def hi(self) -> float: ...
    @property
    def offset(self) -> float: ...
    def levels(self) -> NDArray[np.float64]: ...
    def predict(
        self, u: NDArray[np.float64], state: NDArray[np.float64], interpolated: bool = False
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]: ...
    def stream(self, state: NDArray[np.float64]) -> Stream: ...

@final
class Stream:
    def step(self, u: float) -> float: ...
    def process(self, block: NDArray[np.float64]) -> NDArray[np.float64]: ...
    def get_state(self) -> NDArray[np.float64]: ...
    def set_state(self, state: NDArray[np.float64]) -> None: ...

def fit(
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    n_h: int,
    u_range: Optional[tuple[float, float]] = None,
    reg: float = 0.0,
    solver: str = "auto",
    interpolated: bool = False,
) -> tuple[Model, dict[str, Any]]: ...
def fit_behind(
    u: NDArray[np.float64],
    z: NDArray[np.float64],
    n_h: int,
    u_range: tuple[float, float],
    dt: float,
    blocks: list[tuple[list[tuple[float, float]], list[tuple[float, float]], float]],
    weights: Optional[NDArray[np.float64]] = None,
    tol: float = 1e-6,
    max_iter: int = 200,
) -> tuple[Model, dict[str, Any]]: ...
def lti(
    x: NDArray[np.float64],
    dt: float,
    poles: Sequence[tuple[float, float]],
    residues: Sequence[tuple[float, float]],
    direct: float = 0.0,
) -> NDArray[np.float64]: ...

@final
class Behind:
    def __new__(cls, u: NDArray[np.float64], n_h: int, u_range: tuple[float, float], stride: int = 1) -> Behind: ...
    @property
    def n_out(self) -> int: ...
    def solve(
        self,
        z: NDArray[np.float64],
        dt: float,
        blocks: list[tuple[list[tuple[float, float]], list[tuple[float, float]], float]],
        weights: Optional[NDArray[np.float64]] = None,
        pre: Optional[NDArray[np.float64]] = None,
        post: Optional[NDArray[np.float64]] = None,
        tol: float = 1e-4,
        max_iter: int = 300,
        warm: bool = True,
        nnls: bool = False,
        delay: float = 0.0,
    ) -> dict[str, Any]: ...

def regression_rows(
    u: NDArray[np.float64],
    y: NDArray[np.float64],
    n_h: int,
    u_range: tuple[float, float],
    interpolated: bool = False,
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]: ...

# --- inversion ---
def invert(
    model: Model, r: NDArray[np.float64], method: str = "closest", lookahead: int | None = None
) -> tuple[NDArray[np.float64], int]: ...

@final
class InverseStream:
    def __new__(cls, model: Model, method: str = "closest", lookahead: int | None = None) -> InverseStream: ...
    def step(self, r: float) -> float: ...
    def process(self, block: NDArray[np.float64]) -> NDArray[np.float64]: ...
    def reset(self) -> None: ...
    @property
    def saturated(self) -> int: ...
    @property
    def method(self) -> str: ...
    @property
    def lookahead(self) -> int: ...
    def get_state(
        self,
    ) -> tuple[NDArray[np.float64], int, int, float, float, NDArray[np.uint64], NDArray[np.float64], float]: ...
    def set_state(
        self,
        memory: NDArray[np.float64],
        saturated: int,
        t: int,
        u_prev: float,
        last_cm: float,
        knot_t: NDArray[np.uint64],
        knot_v: NDArray[np.float64],
        r_prev: float,
    ) -> None: ...

# --- simulator ---
@final
class Chain:
    @staticmethod
    def from_json(text: str) -> Chain: ...
    @staticmethod
    def preset(name: str, overrides_json: str) -> Chain: ...
    def to_json(self) -> str: ...
    @property
    def sample_rate_hz(self) -> float: ...
    @property
    def time_s(self) -> float: ...
    @time_s.setter
    def time_s(self, t: float) -> None: ...
    def kinds(self) -> list[str]: ...
    def step(self, u: float) -> float: ...
    def run(self, u: NDArray[np.float64]) -> NDArray[np.float64]: ...
    def reset(self) -> None: ...
    def reset_state(self) -> None: ...
    def copy(self) -> Chain: ...

def run_loop(
    model: Model | None,
    chain: Chain,
    reference: NDArray[np.float64],
    method: str = "continuous",
    lookahead: int | None = None,
) -> dict[str, Any]: ...
