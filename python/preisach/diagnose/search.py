"""The search over augmented chains, on the profiled training error.

For a chain (effects with parameters), the masses that fit the training record best are a
linear least-squares problem, solved exactly behind the chain's linear blocks by the core
(``_preisach.Behind``: rows built once per delayed input, conjugate gradients
preconditioned by the unfiltered Gram matrix, warm-started). So every effect parameter is
searched on the *profiled* error ``J(θ) = min over masses of the training MSE``: the
masses absorb part of any unmodelled effect (a delay widens the loops, creep scales them),
and only with the masses refitted at every trial value does the search land on the truth.
The coefficients that enter linearly are solved with the masses (drift offset slope, rate
gain). The masses >= 0 (the NNLS fit, made unique by a small smoothness term) are computed
only for chains that are scored.

Effects that trade off against each other (a delay and a low-pass share the low-frequency
lag; creep and drift both make slow trends; a mode's ringing phase needs the timing) are
polished jointly: after a candidate's own search, coordinate steps on every scalar of the
chain. A chain with a mode or a low-pass always carries a delay as the sub-sample timing
of the record (a DAC's zero-order hold delays the dynamics by half a sample); it is
reported as a detected delay only when it is longer than the sampling can explain.
"""
from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, Callable, Iterator, Optional, Sequence, TypeVar

import numpy as np
from numpy.typing import NDArray

from preisach.chain import Chain
from preisach.diagnose.effects import (
    FitState,
    Record,
    _grid_then_parabola,
    _mode_guess,
    _parabolic_search,
    rate_branch,
    rmse,
)
from preisach.diagnose.identified import identified
from preisach.diagnose.initial import predict_from
from preisach.diagnose.pool import Sessions
from preisach.diagnose.ranges import CREEP_AMP_MAX, CREEP_TAU_MIN, Ranges, delay_grid, search_ranges
from preisach.diagnose.rest import fast_blocks, start_mode, transient
from preisach.model import PreisachModel

Effects = dict[str, dict[str, Any]]
T = TypeVar("T")
R = TypeVar("R")

#: The same across records (``calibrate_slow``): every record restarts the element, so
#: the amplitude and the time constant separate better than on one record.
CREEP_CAL_TAU_MAX_RECORDS = 10.0
#: Creep time constants per decade of the grid whose chains the held-out records score.
CREEP_PER_DECADE = 2
#: Parabolic steps of creep's held-out choice after its grid: each refines the time
#: constant the masses are fitted with, which decides how well the chain holds on other
#: records (docs/method/diagnosis.md, "Creep's time constant from the held-out records").
CREEP_HELD_STEPS = 3
#: How much better (a share of the held-out RMSE) the midpoint to the grid's end must
#: score than the end to move creep's search off it: the share an effect must shrink the
#: holdouts' error by (``diagnose``'s default ``min_shrink``).
CREEP_END_SHRINK = 0.10
#: The amplitude of the creep chain ``Fitter.creep_held`` returns when no time constant
#: beats no creep: a token the registry's rule calls trivial, which keeps the time constant.
CREEP_TOKEN = 1e-4
#: The weight of the samples before a fit's start (``Fitter(start=)``).
PART_FLOOR = 1e-6

#: Scalars polished per effect: (parameter, first step: relative, or in log units; the
#: ranges come from the data, ``preisach.diagnose.ranges``). A mode's frequency needs
#: small steps: a long ringing turns its phase quickly with the frequency, so the error
#: is smooth only within a fraction of a percent.
SCALARS: dict[str, list[tuple[str, float]]] = {
    "delay": [("delay_s", 0.1)],
    "lowpass": [("cutoff_hz", 0.1)],
    "vibration": [("frequency_hz", 0.002), ("damping", 0.15)],
    "creep": [("tau", 0.2), ("amp", 0.2)],
    "drift": [("gain_per_s", 0.1)],
    "rate": [("tau_s", 0.2)],
}
DYNAMIC = ("vibration", "lowpass")
#: The delay's shares of a chain's lag the held-out records choose among (``Fitter.lag_held``;
#: up to the chain's delay before the low-pass, which is tried as well).
LAG_SHARES = (0.0, 0.15, 0.3, 0.45, 0.6, 0.75, 0.9)
#: Columns from full-rate runs a fitter keeps (``Fitter._kept``; each is one averaged record).
COLUMNS_KEPT = 128
#: The chains with masses >= 0 a fitter keeps (``Fitter.state``: a projection costs
#: as much as a hundred conjugate-gradient steps, and the steps ask for some chains again).
STATES_KEPT = 64
#: Effects whose parameters trade off against each other's (polished together): a delay
#: and the dynamics share the lag; a low-pass and creep both shape the step response.
#: (Creep and drift trade off too, but one record cannot tell them apart: polishing one
#: against the other on it only wanders along the valley. Across records they separate,
#: which is where ``calibrate_slow`` splits them.)
COUPLED: dict[str, tuple[str, ...]] = {
    "delay": ("lowpass", "vibration"),
    "lowpass": ("delay", "vibration", "creep"),
    "vibration": ("delay", "lowpass"),
    "creep": ("lowpass",),
    "drift": (),
    "rate": (),
}


def _get(eff: Effects, name: str, key: str) -> float:
    p = eff[name]
    if name == "creep":
        return float(p["taus_s"][0] if key == "tau" else p["amplitudes"][0])
    return float(p[key])


def _set(eff: Effects, name: str, key: str, v: float) -> Effects:
    e = {k: dict(p) for k, p in eff.items()}
    if name == "creep":
        if key == "tau":
            e[name]["taus_s"] = [float(v)]
        else:
            e[name]["amplitudes"] = [float(v)]
    else:
        e[name][key] = float(v)
    return e


#: Marks the threads of the trials' pool (a map inside one runs inline).
_worker = threading.local()


class Cancelled(Exception):
    """A trial asked to start after the diagnosis was interrupted (see :meth:`Trials.cancel`)."""


class Trials:
    """Threads for the independent trials of a search (its starting points, a grid), used
    only while a CPU would otherwise idle: while fewer searches run than there are
    workers. (Trials beside a busy CPU only add work: each thread's fit session
    warm-starts from its own last solve.) After :meth:`cancel` (Ctrl-C) no trial starts."""

    def __init__(self, workers: int) -> None:
        self.workers = max(1, int(workers))
        self.pool = ThreadPoolExecutor(self.workers, thread_name_prefix="preisach-trial") if self.workers > 1 else None
        self._searches = 0
        self._lock = threading.Lock()
        self._cancelled = threading.Event()
        #: The run's fit sessions, built once per problem and copied for each fitter's
        #: threads (``preisach.diagnose.pool``).
        self.sessions = Sessions()

    @contextmanager
    def search(self) -> Iterator[None]:
        """Marks a running search (a candidate's fit, a refit)."""
        with self._lock:
            self._searches += 1
        try:
            yield
        finally:
            with self._lock:
                self._searches -= 1

    def idle(self) -> bool:
        return self.pool is not None and self._searches < self.workers and not getattr(_worker, "busy", False)

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> list[R]:
        """``fn`` on every item: in the pool when a CPU idles, else inline (also when
        called from a pool thread: a nested map would wait on its own threads)."""
        if len(items) < 2 or not self.idle():
            return [fn(x) for x in items]

        def run(x: T) -> R:
            _worker.busy = True
            try:
                return fn(x)
            finally:
                _worker.busy = False
        assert self.pool is not None
        return list(self.pool.map(run, items))

    def check(self) -> None:
        """Raises :class:`Cancelled` once :meth:`cancel` was called (before each solve)."""
        if self._cancelled.is_set():
            raise Cancelled("the diagnosis was interrupted")

    def cancel(self) -> None:
        """Start nothing new: queued trials are dropped, running searches stop at their
        next solve (a solve already in the core runs to its end)."""
        self._cancelled.set()
        if self.pool is not None:
            self.pool.shutdown(wait=False, cancel_futures=True)

    @contextmanager
    def tasks(self, workers: int) -> Iterator[ThreadPoolExecutor]:
        """A thread pool for the diagnosis's own tasks (candidate fits, a refit). On Ctrl-C
        the trials are cancelled and the pool is left at once, its queued tasks dropped."""
        ex = ThreadPoolExecutor(max_workers=workers)
        try:
            yield ex
        except KeyboardInterrupt:
            self.cancel()
            ex.shutdown(wait=False, cancel_futures=True)
            raise
        except BaseException:
            ex.shutdown(cancel_futures=True)
            raise
        ex.shutdown()

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=not self._cancelled.is_set())


def group_delay(p: dict[str, Any]) -> float:
    """Low-frequency group delay of a Butterworth low-pass (order 1: 1/wc; 2: sqrt(2)/wc)."""
    wc = 2 * math.pi * p["cutoff_hz"]
    return (1.0 if int(p["order"]) == 1 else math.sqrt(2.0)) / wc


def less(eff: Effects, name: str) -> Effects:
    """The chain ``eff`` less effect ``name``; a low-pass's group delay (its lag at the
    records' frequencies) goes to the delay."""
    e = {k: dict(p) for k, p in eff.items() if k != name}
    if name == "lowpass":
        e["delay"] = {"delay_s": float(eff.get("delay", {}).get("delay_s", 0.0)) + group_delay(eff["lowpass"])}
    return e


def _key(eff: Effects) -> tuple[Any, ...]:
    out = []
    for k in sorted(eff):
        p = eff[k]
        out.append((k, tuple((kk, tuple(v) if isinstance(v, list) else v) for kk, v in sorted(p.items())
                             if kk not in ("offset_per_s", "gain_s", "offset"))))
    return tuple(out)


def window_mean(x: NDArray[np.float64], stride: int) -> NDArray[np.float64]:
    """Means of consecutive windows of ``stride`` samples (the last partial one dropped)."""
    n = x.size // stride
    return np.ascontiguousarray(x[:n * stride].reshape(n, stride).mean(axis=1))


class Fitter:
    """Profiled-error fits of chains on one training record, on windows of ``stride``
    samples averaged (the record's rate divided by ``stride``; see the core's
    ``Behind``: averaging commutes with the dynamics and keeps the timing of steps).
    ``tol``: the conjugate gradients stop when two steps in a row lower the training error
    by less than this fraction of it (3e-5: along a mode's frequency the profiled error
    rises the same as at 1e-5 to within 2 %, at 13 % fewer iterations). Its fit sessions
    come from the run's pool (``trials.sessions``: each problem built once, the masses'
    projection shared by every window of an input and grid). ``start``: the fit's error
    counts from this sample of the record on; the samples before it only set the
    hysteresis memory and the dynamics' state there (a later part of a record does not
    start at rest). ``extrema``: the hysteresis memory at the record's start is the one
    after these alternating extrema (a history nobody recorded; none: every relay at -1)."""

    def __init__(self, rec: Record, n_h: int, u_range: tuple[float, float], stride: int = 1,
                 tol: float = 3e-5, trials: Optional[Trials] = None, ranges: Optional[Ranges] = None,
                 start: int = 0, extrema: Sequence[float] = ()) -> None:
        from preisach import _preisach

        self._tie = _preisach.PROJECTION_TIE
        self.rec = rec
        self.stride = max(1, int(stride))
        self.n_h = n_h
        self.u_range = (float(u_range[0]), float(u_range[1]))
        self.tol = tol
        self._sessions: dict[int, Any] = {}
        self._lock = threading.Lock()
        self._memo: dict[tuple[Any, ...], tuple[float, list[float], Optional[float]]] = {}
        self._columns: dict[tuple[Any, ...], Optional[NDArray[np.float64]]] = {}
        self._states: dict[tuple[Any, ...], FitState] = {}
        self._others: dict[tuple[int, tuple[float, ...]], Fitter] = {}
        self.evaluations = 0
        self._u = np.ascontiguousarray(rec.u, dtype=np.float64)
        self.extrema = tuple(float(x) for x in extrema)
        # The averaged record the chains are fitted to.
        self.t = window_mean(rec.t, self.stride)
        self.y = window_mean(rec.y, self.stride)
        self.dt = rec.dt * self.stride
        #: The weights of the windows the error counts on (None: all; the window the
        #: start falls in by its share after the start), and the first such window. The
        #: windows before weigh ``PART_FLOOR``: they count for nothing, but an Everett
        #: value only they observe stays determined (left free, the conjugate gradients
        #: can break down on it).
        self.weights: Optional[NDArray[np.float64]] = None
        self.start, self.first = start, 0
        if start > 0:
            share = window_mean((np.arange(rec.y.size) >= start).astype(np.float64), self.stride)
            self.first = int(np.argmax(share > 0))
            self.weights = np.maximum(share, PART_FLOOR)
        #: Every scalar's search range (from the data; see ``preisach.diagnose.ranges``).
        self.ranges: Ranges = ranges if ranges is not None else search_ranges(
            rec.u, rec.dt, float(rec.t[-1] - rec.t[0]), self.dt)
        #: A fitter on longer windows for the slow effects' own searches (creep, drift:
        #: the window average is exact for any chain, and a slow trend's error landscape
        #: is the same on it at a fraction of the cost); their polish runs here.
        self.slow: Optional[Fitter] = None
        #: Threads for independent trials (the core releases the GIL; none by default).
        self.trials = trials if trials is not None else Trials(1)
        #: The record starts with a step from an unknown rest level: its transient is one
        #: more linear coefficient of every fit (``preisach.diagnose.rest``).
        self.rest = False
        #: The shortest lag called a delay (two samples of the fastest record; the
        #: diagnosis sets it from all the records): :meth:`timing` fits below it.
        self.min_delay = 2.0 * rec.dt

    def Jmany(self, effs: Sequence[Effects], above: Optional[float] = None) -> list[float]:
        """``J`` of several chains (the ones the memo does not answer, in parallel)."""
        todo = [e for e in effs if self._memoized(_key(e), above) is None]
        self.trials.map(lambda e: self.J(e, above), todo)
        return [self.J(e, above) for e in effs]

    def along(self, chain: Callable[[float], Effects], above: Optional[float] = None
              ) -> tuple[Callable[[float], float], Callable[[list[float]], list[float]]]:
        """The error along a one-parameter family of chains, as the searches take it:
        one point (``f``) and several at once, in parallel (``fmany``); ``above``: as in
        :meth:`J`."""
        return (lambda x: self.J(chain(x), above)), (lambda xs: self.Jmany([chain(x) for x in xs], above))

    def coarse(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """A full-rate signal of the training record, averaged like the fit's target."""
        return window_mean(x, self.stride)

    def _delayed(self, x: NDArray[np.float64], eff: Effects) -> NDArray[np.float64]:
        """A full-rate signal delayed like the chain delays its output, then averaged."""
        d = eff.get("delay", {}).get("delay_s", 0.0)
        return self.coarse(Chain(None, {"delay": {"delay_s": d}}).predict(self.rec.t, x) if d > 0 else x)

    def hysteresis(self, model: PreisachModel, eff: Effects) -> NDArray[np.float64]:
        """The model's output on the training input, delayed like the chain, averaged."""
        return self._delayed(self._started(model, {}) if self.extrema else model.predict(self._u), eff)

    def _started(self, model: PreisachModel, eff: Effects) -> NDArray[np.float64]:
        """Chain ``model`` + ``eff`` on the training record, the memory at its start
        after ``extrema``."""
        return predict_from(FitState(model, eff), self.rec, list(self.extrema))

    def predict(self, st: FitState) -> NDArray[np.float64]:
        """The chain's output on the averaged training record (a delay commutes with the
        linear blocks, and the average with all of them)."""
        eff = st.effects
        x = self._started(st.model, {k: v for k, v in eff.items() if k == "rate"})
        rest = {k: v for k, v in eff.items() if k not in ("rate", "delay")}
        return _run(rest, self.t, self._delayed(x, eff))

    # -- the profiled objective -----------------------------------------------------
    def _session(self) -> Any:
        """This thread's fit session (a session serves one thread at a time, and
        warm-starts from its previous solve: the neighbouring trial of the same search).
        A session whose thread has ended (a round's tasks) is taken over; a new one is a
        copy from the run's pool (``preisach.diagnose.pool``)."""
        me = threading.get_ident()
        with self._lock:
            sess = self._sessions.get(me)
            if sess is None:
                alive = {t.ident for t in threading.enumerate()}
                orphan = next((k for k in self._sessions if k not in alive), None)
                if orphan is not None:
                    sess = self._sessions[me] = self._sessions.pop(orphan)
        if sess is None:
            sess = self.trials.sessions.session(self._u, self.n_h, self.u_range, self.stride, self._tie,
                                                self.extrema)
            with self._lock:
                self._sessions[me] = sess
        return sess

    def _solve(self, pb: dict[str, Any], nnls: bool = False, above: Optional[float] = None) -> dict[str, Any]:
        """One solve on this thread's session (:meth:`_session`)."""
        self.trials.check()
        sess = self._session()
        return sess.solve(pb["z"], self.dt, pb["chain"]._core, pb["w"], pb["pre"], pb["post"], self.tol,
                          nnls=nnls, above=above)

    def _problem(self, eff: Effects) -> dict[str, Any]:
        t, y = self.t, self.y
        chain = Chain(None, {k: eff[k] for k in ("creep", "vibration", "lowpass", "delay") if k in eff})
        z, w, post, pre, q = y, self.weights, None, None, None
        if "drift" in eff:
            q = 1 + eff["drift"]["gain_per_s"] * t
            z = y / q
            w = q * q if w is None else w * q * q
            # y = (1 + g t)(chain + c) + o'' t: the constant stays in the model's offset.
            post = np.ascontiguousarray((t / q)[None, :])
        if "rate" in eff:
            pre = self._rate_column(eff)
        c = self._rest_column(eff) if self.rest else None
        if c is not None:  # (in z's units: the transient is part of the chain's output)
            post = np.ascontiguousarray(c if post is None else np.vstack([post, c]))
        return {"z": np.ascontiguousarray(z), "chain": chain, "w": w, "pre": pre, "post": post, "q": q}

    def _cached(self, store: dict[tuple[Any, ...], Any], limit: int, key: tuple[Any, ...],
                make: Callable[[], Any]) -> Any:
        """``store[key]``, made by ``make`` when missing; the oldest entry goes when
        ``store`` holds ``limit``."""
        with self._lock:
            if key in store:
                return store[key]
        got = make()
        with self._lock:
            if len(store) >= limit:
                del store[next(iter(store))]
            store[key] = got
        return got

    def _kept(self, key: tuple[Any, ...], make: Callable[[], Optional[NDArray[np.float64]]]) -> Any:
        """A column of the fit made from a full-rate run, kept by ``key`` (the
        parameters it depends on, which a search over another scalar does not move)."""
        return self._cached(self._columns, COLUMNS_KEPT, key, make)

    def _rate_column(self, eff: Effects) -> NDArray[np.float64]:
        """The rate branch of gain 1 on the training input, delayed like the chain and
        averaged."""
        tau, d = float(eff["rate"]["tau_s"]), float(eff.get("delay", {}).get("delay_s", 0.0))
        return self._kept(("rate", tau, d), lambda: np.ascontiguousarray(self._delayed(
            rate_branch({"gain_s": 1.0, "tau_s": tau}, self.rec.t, self._u), eff)[None, :]))  # type: ignore[no-any-return]

    def _rest_column(self, eff: Effects) -> Optional[NDArray[np.float64]]:
        """The transient of a step from rest through the chain's fast blocks, averaged
        (``preisach.diagnose.rest``; None without one)."""
        def make() -> Optional[NDArray[np.float64]]:
            col = transient(eff, self.rec.t)
            return None if col is None else self.coarse(col)[None, :]
        return self._kept(("rest",) + _key(fast_blocks(eff)), make)  # type: ignore[no-any-return]

    def _linear(self, eff: Effects, extra: list[float]) -> Effects:
        e = {k: dict(p) for k, p in eff.items()}
        i = 0
        if "rate" in e:
            e["rate"]["gain_s"] = float(extra[i])
            i += 1
        if "drift" in e:
            e["drift"]["offset"] = 0.0
            e["drift"]["offset_per_s"] = float(extra[i])
        return e

    def J(self, eff: Effects, above: Optional[float] = None) -> float:
        """Training MSE with the masses (unconstrained) and the linear coefficients
        refitted; memoized. ``above``: an MSE the caller needs to know only whether the
        chain beats; a fit that cannot get below it gives up (the core's ``above``), and
        the value is then where it stopped, above ``above`` and above the optimum's."""
        k = _key(eff)
        got = self._memoized(k, above)
        if got is not None:
            return got
        pb = self._problem(eff)
        scale = 1.0 if pb["q"] is None else float(np.average(pb["q"] ** 2, weights=self.weights))
        res = self._solve(pb, above=None if above is None else math.sqrt(above / scale))
        mse = res["rmse"] ** 2 * scale  # back to the output's units
        self.evaluations += 1
        with self._lock:
            self._memo[k] = (mse, list(res["extra"]), above if res["gave_up"] else None)
        return mse

    def _memoized(self, k: tuple[Any, ...], above: Optional[float]) -> Optional[float]:
        """The memoized ``J`` of the chain keyed ``k`` when it answers a search with
        ceiling ``above``: an exact value answers every search, a value given up above a
        ceiling every search with one as low."""
        with self._lock:
            got = self._memo.get(k)
        if got is not None and (got[2] is None or (above is not None and above <= got[2])):
            return got[0]
        return None

    def with_linear(self, eff: Effects) -> Effects:
        """``eff`` with its linear coefficients from the profiled fit."""
        self.J(eff)
        return self._linear(eff, self._memo[_key(eff)][1])

    def state(self, eff: Effects, n_h: Optional[int] = None) -> FitState:
        """The chain with masses >= 0 (the NNLS projection, with the small smoothness term
        that makes its masses unique, ``_preisach.PROJECTION_TIE``; the masses the record
        does not identify zero, ``preisach.diagnose.identified``) and its linear
        coefficients refitted with them."""
        if n_h is not None and n_h != self.n_h:
            return self.other(n_h).state(eff)
        def make() -> FitState:
            res = self._solve(self._problem(eff), nnls=True)
            model = identified(PreisachModel._wrap(res["model"], "interpolated"), self._u)
            st = FitState(model, self._linear(eff, res["extra_nnls"]))
            st.train_rmse = rmse((self.predict(st) - self.y)[self.first:])
            return st

        st = self._cached(self._states, STATES_KEPT, (self.rest,) + _key(eff), make)
        return FitState(st.model, {n: dict(p) for n, p in st.effects.items()}, st.train_rmse)

    def other(self, n_h: int, extrema: Optional[Sequence[float]] = None) -> Fitter:
        """The fitter of the same record and windows with ``n_h`` levels and, when given,
        the memory at the record's start after ``extrema`` (kept: its sessions are the
        costly part)."""
        ex = self.extrema if extrema is None else tuple(float(x) for x in extrema)
        with self._lock:
            f = self._others.get((n_h, ex))
            if f is None:
                f = self._others[(n_h, ex)] = Fitter(self.rec, n_h, self.u_range, self.stride, self.tol,
                                                     self.trials, self.ranges, start=self.start, extrema=ex)
        f.rest = self.rest
        return f

    # -- one-dimensional searches on J ----------------------------------------------
    def line(self, eff: Effects, name: str, key: str, scale: float = 1.0, refine: int = 2) -> tuple[Effects, float]:
        """Narrow search on one scalar from its current value (parabolic steps; the first
        step is the scalar's own, times ``scale``)."""
        rel = next(s for s in SCALARS[name] if s[0] == key)[1] * scale
        b = self.ranges[name][key]
        logs, lo, hi = b.log, b.lo, b.hi
        x0 = _get(eff, name, key)
        if logs:
            c = math.log(max(x0, 1e-300))
            f, fm = self.along(lambda x: _set(eff, name, key, math.exp(x)))
            lo_, hi_ = math.log(lo), math.log(hi)
            c = min(max(c, lo_), hi_)
            pts = sorted({max(lo_, c - rel), c, min(hi_, c + rel)})
        else:
            step = rel * abs(x0) if x0 != 0 else rel * (hi - lo) * 0.01
            f, fm = self.along(lambda x: _set(eff, name, key, x))
            x0 = min(max(x0, lo), hi)
            pts = sorted({max(lo, x0 - step), x0, min(hi, x0 + step)})
            lo_, hi_ = lo, hi
        x, fx = _parabolic_search(f, pts, lo_, hi_, refine=refine, expand=3, fmany=fm)
        return _set(eff, name, key, math.exp(x) if logs else x), fx

    def split_lag(self, eff: Effects, share: float) -> Effects:
        """The chain with its low-frequency lag (delay plus the low-pass's group delay)
        kept and the share ``share`` of it given to the delay."""
        lag = eff["delay"]["delay_s"] + group_delay(eff["lowpass"])
        share = min(max(share, 0.0), 0.97)
        p = dict(eff["lowpass"])
        k = 1.0 if int(p["order"]) == 1 else math.sqrt(2.0)
        p["cutoff_hz"] = k / (2 * math.pi * (1 - share) * lag)
        return dict(eff, delay={"delay_s": share * lag}, lowpass=p)

    def line_lag(self, eff: Effects) -> tuple[Effects, float]:
        """Search along the valley of a delay and a low-pass: the same total lag split
        differently (coordinate steps cross it only slowly)."""
        lag = eff["delay"]["delay_s"] + group_delay(eff["lowpass"])
        s0 = eff["delay"]["delay_s"] / lag if lag > 0 else 0.0
        f, fm = self.along(lambda sh: self.split_lag(eff, sh))
        grid = np.unique(np.clip(np.concatenate([[s0], np.linspace(0.0, 0.9, 7)]), 0.0, 0.97))
        sh, fx = _grid_then_parabola(f, grid, fmany=fm)
        return (self.split_lag(eff, sh), fx) if fx < self.J(eff) else (eff, self.J(eff))

    def polish(self, eff: Effects, names: list[str], sweeps: int = 1, scale: float = 1.0,
               refine: int = 2, valley: bool = True) -> tuple[Effects, float]:
        """Coordinate steps on every scalar of ``names`` (the coupled effects re-balance),
        and along the delay/low-pass valley when the chain has both (``valley``)."""
        fx = self.J(eff)
        for _ in range(sweeps):
            f0 = fx
            if valley and "delay" in eff and "lowpass" in eff and ("delay" in names or "lowpass" in names):
                eff, fx = self.line_lag(eff)
            for n in names:
                if n not in eff:
                    continue
                if n == "creep" and len(eff["creep"]["taus_s"]) > 1:
                    continue  # a given chain's creep of several elements is kept
                if n == "creep":
                    # Only the amplitude: the time constant is the held-out records' choice
                    # (``creep_held``), which one record rarely makes well.
                    tau, c0 = float(eff["creep"]["taus_s"][0]), float(eff["creep"]["amplitudes"][0])
                    c, fx = self.creep_amp({k: v for k, v in eff.items() if k != "creep"}, tau, c0, refine)
                    eff = dict(eff, creep={"taus_s": [tau], "amplitudes": [c], "normalized": True})
                    continue
                for key, _ in SCALARS[n]:
                    eff, fx = self.line(eff, n, key, scale, refine)
            if fx > 0.999 * f0:
                break
        return eff, fx

    # -- candidate searches -----------------------------------------------------------
    def add(self, base: Effects, name: str, h: Optional[NDArray[np.float64]] = None,
            held: Optional[Callable[[Effects], float]] = None) -> Effects:
        """Chain ``base`` plus effect ``name``: the effect's own search with the others
        fixed, then a joint polish of the coupled effects. ``held``: a chain's error on
        records it was not fitted on (cross-fitted); with it, creep's time constant is
        chosen on them (:meth:`creep_held`)."""
        r = self.rec
        eff = {k: dict(p) for k, p in base.items()}
        j_base = self.J(eff)
        if name == "delay" and "delay" in eff and any(k in eff for k in DYNAMIC):
            # The chain's timing delay was searched with its dynamics (and polished with
            # them): only a narrow search, the dynamics re-balanced below.
            eff, _ = self.line(eff, "delay", "delay_s", 3.0)
        elif name == "delay":
            grid = delay_grid(r.dt / 2, self.ranges["delay"]["delay_s"].hi)
            f, fm = self.along(lambda d: dict(eff, delay={"delay_s": d}))
            d, _ = _grid_then_parabola(f, grid, fmany=fm)
            eff["delay"] = {"delay_s": float(max(d, 0.0))}
            if "lowpass" in eff:
                eff, _ = self.line_lag(eff)  # the low-pass may have taken the delay's lag
        elif name == "lowpass":
            d0 = eff.get("delay", {}).get("delay_s", 0.0)
            best = None
            bc = self.ranges["lowpass"]["cutoff_hz"]
            for order in (1, 2):
                def lp(lf: float, order: int = order) -> Effects:
                    p = {"cutoff_hz": math.exp(lf), "order": order}
                    e = dict(eff, lowpass=p)
                    if "delay" in eff:
                        # The delay absorbed the low-pass's lag: keep the total.
                        e["delay"] = {"delay_s": max(0.0, d0 - group_delay(p))}
                    return e
                grid = np.log(np.geomspace(bc.lo, bc.hi, max(10, int(round(1.5 * math.log2(bc.hi / bc.lo))))))
                # (A cutoff whose fit stays worse than the chain without it is given up.)
                f, fm = self.along(lp, above=j_base)
                # (Every other cutoff first: the error changes slowly over two grid steps,
                # a factor 2.5 of the cutoff.)
                lf, fx = _grid_then_parabola(f, grid, fmany=fm, coarse_first=True)
                if best is None or fx < best[1]:
                    best = (lf, fx, order)
            assert best is not None
            p = {"cutoff_hz": float(math.exp(best[0])), "order": best[2]}
            eff["lowpass"] = p
            if "delay" in eff:
                eff["delay"] = {"delay_s": max(0.0, d0 - group_delay(p))}
        elif name == "vibration":
            eff = self.mode_band(eff, h)
            if self.rest:
                eff = start_mode(self.along, eff)
        elif name == "creep":
            # Without held-out records the training record chooses (as well as it can).
            return self.with_linear(self.creep_held(eff, held if held is not None else self.J))
        elif name == "drift":
            gmax = min(0.1, 0.5 * self.ranges["drift"]["gain_per_s"].hi)
            f, fm = (self.slow or self).along(
                lambda g: dict(eff, drift={"gain_per_s": g, "offset": 0.0, "offset_per_s": 0.0}))
            g, _ = _grid_then_parabola(f, np.linspace(-gmax, gmax, 7), fmany=fm)
            eff["drift"] = {"gain_per_s": float(g), "offset": 0.0, "offset_per_s": 0.0}
        elif name == "rate":
            f, fm = self.along(lambda lt: dict(eff, rate={"gain_s": 0.0, "tau_s": math.exp(lt)}))
            br = self.ranges["rate"]["tau_s"]
            n = max(5, int(math.ceil(math.log(br.hi / br.lo) / math.log(3.0))) + 1)
            lt, _ = _grid_then_parabola(f, np.log(np.geomspace(br.lo, br.hi, n)), fmany=fm)
            eff["rate"] = {"gain_s": 0.0, "tau_s": float(math.exp(lt))}
        else:
            raise ValueError(f"unknown effect {name!r}")
        if any(k in eff for k in DYNAMIC) and "delay" not in eff:
            eff["delay"] = {"delay_s": 0.0}  # the record's sub-sample timing (polished below)
        if "lowpass" in eff and name != "lowpass" and eff["lowpass"]["cutoff_hz"] > 0.4 / self.dt:
            del eff["lowpass"]  # a band-fit nuisance beyond what the fit resolves
        if self.J(eff, j_base) >= j_base * (1 - 1e-4):
            return self.with_linear(eff)  # its own search found nothing: no polish to pay for
        # The new effect and those it trades off against are polished together (the rest
        # of the chain stays; the chain found is polished as a whole at the end).
        names = [name] + [k for k in eff if k != name and (k in COUPLED[name] or name in COUPLED[k])]
        eff, _ = self.polish(eff, names, sweeps=2, refine=1)
        if name == "lowpass":
            eff = self.other_order(eff)
            if held is not None:
                eff = self.lag_held(eff, held, float(base.get("delay", {}).get("delay_s", 0.0)))
        return self.with_linear(eff)

    def lag_held(self, eff: Effects, held: Callable[[Effects], float], d0: float) -> Effects:
        """The low-pass's order and its share of the chain's lag, chosen by the held-out
        records. A slow identification sine shows a low-pass only as a lag, which a delay
        gives as well: the training record rarely tells them apart (nor the orders). Steps
        and faster sines do (a low-pass's lag shrinks at their high frequencies and it
        rounds their edges; a delay's does not). So: the chain's low-frequency lag (delay
        plus group delay) kept; the chain the training record chose, and for each order
        the delay on a grid from 0 to ``d0`` (the chain's delay before the low-pass: the
        grid adds a low-pass, not a delay) with the low-pass taking the rest of the lag
        (cutoffs within the range); the masses fitted on the
        training record, each chain scored by ``held`` (its error on the other records,
        judged cross-fitted by the caller; a chain that fits the training record worse
        than without the low-pass is then refused as any candidate is)."""
        lag = eff["delay"]["delay_s"] + group_delay(eff["lowpass"])
        hi = self.ranges["lowpass"]["cutoff_hz"].hi
        if lag <= 0:
            return eff
        top = min(d0, lag) / lag
        chains = [eff]
        for order in (1, 2):
            for share in sorted({s for s in LAG_SHARES if s < top} | {top} - {1.0}):
                fc = (1.0 if order == 1 else math.sqrt(2.0)) / (2 * math.pi * (1.0 - share) * lag)
                if fc <= hi:
                    chains.append(dict(eff, delay={"delay_s": share * lag},
                                       lowpass={"cutoff_hz": fc, "order": order}))
        scores = self.trials.map(held, chains)
        return chains[int(np.argmin(scores))]

    def other_order(self, eff: Effects) -> Effects:
        """Try the other low-pass order with the same low-frequency group delay."""
        p = eff["lowpass"]
        o2 = 3 - int(p["order"])
        fc2 = p["cutoff_hz"] * (math.sqrt(2.0) if o2 == 2 else 1 / math.sqrt(2.0))
        e2 = dict(eff, lowpass={"cutoff_hz": fc2, "order": o2})
        e2, f2 = self.polish(e2, ["lowpass", "delay"], sweeps=1)
        return e2 if f2 < self.J(eff) else eff

    def creep_amp(self, eff: Effects, tau: float, c0: float = 0.03, refine: int = 2) -> tuple[float, float]:
        """The best creep amplitude for time constant ``tau`` (parabolic steps; amplitude
        0 is the chain without creep, whose error is known)."""
        f, fm = self.along(lambda c: dict(eff, creep={"taus_s": [float(tau)], "amplitudes": [c], "normalized": True}))
        amax = self.ranges["creep"]["amp"].hi
        c0 = min(max(c0, 0.01), 0.5 * amax)
        a, b = c0 / 3, c0
        known = {0.0: self.J({k: v for k, v in eff.items() if k != "creep"})}
        c, fx = _parabolic_search(f, [0.0, a, b], 0.0, amax, refine=refine, expand=4, known=known,
                                  fmany=fm)
        if c == 0.0:
            # Best at no creep: the parabola through 0, a, b may still dip inside (0, a).
            fa, fb = f(a), f(b)
            den = b * (fa - known[0.0]) - a * (fb - known[0.0])
            if den > 0:
                v = 0.5 * (b * b * (fa - known[0.0]) - a * a * (fb - known[0.0])) / den
                if 0.02 * a < v < a:
                    fv = f(v)
                    if fv < fx:
                        c, fx = v, fv
        return float(c), fx

    def timing(self, eff: Effects) -> Effects:
        """The chain with the record's own timing: a delay shorter than ``min_delay`` (what
        the sampling explains: an ADC's latency, a DAC's hold), fitted on the profiled
        error (a grid, then parabolic steps); the chain as given when the best is none.
        At the drive's frequency such a lag widens the loops as a creep element does, and
        the amplitude fitted to a record that shows little else of the creep takes it."""
        hi = float(np.nextafter(self.min_delay, 0.0))
        f, fm = self.along(lambda d: dict(eff, delay={"delay_s": d}))
        d, _ = _grid_then_parabola(f, np.linspace(0.0, hi, 9), fmany=fm)
        d = min(max(d, 0.0), hi)
        return dict(eff, delay={"delay_s": float(d)}) if d > 0 else eff

    def creep_held(self, eff: Effects, held: Callable[[Effects], float]) -> Effects:
        """Creep (one element) whose time constant the held-out records choose. One record
        rarely tells creep's time constants apart: an identification sine shows an element
        only as a phase lag at its own frequency and a slow trend of its mean, which a fast
        element of one amplitude fits as well as a slow one of another (and a slow one as
        well as a drift). Records with other input histories (steps held for as long as the
        creep) tell them apart. So: time constants on a grid (``CREEP_PER_DECADE`` per
        decade over the range), at each the amplitude and the masses fitted on the training
        record (profiled), the chain scored by ``held`` (its error on the other records;
        ``Fitter.add`` passes the training error when there are none); then
        ``CREEP_HELD_STEPS`` parabolic steps on that score around the best time constant
        that fits the training record better than no creep (the others score as no
        creep; at the grid's end, the midpoint to its neighbour, kept when it scores
        ``CREEP_END_SHRINK`` better), kept when it scores better than no creep. The
        chain's own timing is fitted first (:meth:`timing`)."""
        bt = self.ranges["creep"]["tau"]
        slow = self.slow or self
        if "delay" not in eff:
            eff = slow.timing(eff)
        j0 = slow.J(eff)
        amps: dict[float, float] = {}  # by log time constant; 0: no better than no creep

        def chain(lt: float, amp: float) -> Effects:
            return dict(eff, creep={"taus_s": [float(math.exp(lt))], "amplitudes": [amp], "normalized": True})

        def fit(lt: float) -> float:
            """The training error at ``lt``, its amplitude kept in ``amps``."""
            c, fx = slow.creep_amp(eff, math.exp(lt), refine=1)
            amps[lt] = c if fx < j0 else 0.0
            return fx

        n = max(3, int(math.ceil(CREEP_PER_DECADE * math.log10(bt.hi / bt.lo))) + 1)
        grid = [float(x) for x in np.log(np.geomspace(bt.lo, bt.hi, n))]
        fits = self.trials.map(fit, grid)
        if not any(amps.values()):
            return chain(grid[int(np.argmin(fits))], CREEP_TOKEN)
        none = held(eff)  # (a time constant that does not fit the training record scores as no creep)

        def score(lt: float) -> float:
            if lt not in amps:
                fit(lt)
            return held(chain(lt, amps[lt])) if amps[lt] > 0 else none

        known = dict(zip(grid, self.trials.map(score, grid)))
        # The steps refine the best time constant that carries creep (the others score as
        # no creep: a plateau that, best by a hair, would stop them at the grid's end).
        real = {x: v for x, v in known.items() if amps[x] > 0}
        b = min(real, key=real.__getitem__)
        if b in (grid[0], grid[-1]):  # (the grid has three points or more)
            # At the grid's end the steps cannot start; the held-out score can be narrower
            # than the grid's step, so the midpoint to the end's neighbour is tried. It
            # counts when it beats the end as an effect must (flat scores leave the end,
            # where the time constant is flagged at its bound).
            mid = 0.5 * (b + (grid[1] if b == grid[0] else grid[-2]))
            v = score(mid)
            if amps[mid] > 0 and v < (1 - CREEP_END_SHRINK) * real[b]:
                real[mid] = v
        lt, best = _parabolic_search(score, [], min(real), max(real), refine=CREEP_HELD_STEPS, expand=0, known=real)
        return chain(lt, amps[lt] if amps[lt] > 0 and best < none else CREEP_TOKEN)

    def mode_band(self, eff: Effects, h: Optional[NDArray[np.float64]]) -> Effects:
        """A lightly damped mode: frequency and damping fitted on the error in a band
        around the largest peaks of the residual spectrum (0.6x to 1.6x), with masses
        fixed. In the band a delay is a phase shift, a low-pass a phase shift and an
        attenuation, so the lag around the mode is fitted with it: either the chain's own
        delay and low-pass are kept, or they are replaced by a nuisance fitted in the band
        (a delay of 0 to 1.5 ms, or a first- or second-order low-pass of 100 Hz to 20 kHz:
        an unmodelled 0.3 ms puts a 1.5 kHz ringing out of phase, and a low-pass taken in
        first for a mode's lag hides the ringing). Every peak's fits are judged on the
        profiled training error (the band ratio alone can prefer a broad peak fitted by a
        heavily damped "mode"). Returns the chain with the mode (and the nuisance block)."""
        from preisach.diagnose.effects import _golden, _grid_then_golden

        t, dt, part = self.t, self.dt, slice(self.first, None)  # (the spectra of the part fitted)
        y = self.y[part]
        others = {k: v for k, v in eff.items() if k != "vibration"}
        if h is None:
            h = self.hysteresis(self.state(others).model, {})
        if "rate" in others:
            h = h + self.coarse(rate_branch(others["rate"], self.rec.t, self._u))
        lin = {k: v for k, v in others.items() if k not in ("rate", "delay")}
        n = y.size
        f = np.fft.rfftfreq(n, dt)
        ramp = np.linspace(0.0, 1.0, n)
        nyq = 0.5 / dt

        def spec(x: NDArray[np.float64]) -> NDArray[np.complex128]:
            return np.fft.rfft(x - x[0] - (x[-1] - x[0]) * ramp)

        Y = spec(y)
        # The chain as it is (its delay a phase factor), for the peaks and the variant
        # that keeps its lag.
        d0 = others.get("delay", {}).get("delay_s", 0.0)
        base_keep = _run(lin, t, h)[part]
        B_keep = np.multiply(spec(base_keep), _response({"delay": {"delay_s": d0}}, f))
        # Without its delay and low-pass, for the variant whose lag is fitted in the band.
        B_free = spec(_run({k: v for k, v in lin.items() if k != "lowpass"}, t, h)[part])
        dgrid = np.arange(0.0, 1.5e-3, 2e-5)
        cgrid = np.geomspace(100.0, 2e4, 24)

        def fit_variant(B: NDArray[np.complex128], nuisance: bool) -> Any:
            found: list[tuple[str, float, int]] = [("delay", 0.0, 0)]
            masks: dict[tuple[float, float], NDArray[np.intp]] = {}
            phc: dict[tuple[float, float], NDArray[np.complex128]] = {}
            power: dict[tuple[float, float], tuple[NDArray[np.float64], float, NDArray[np.float64],
                                                   NDArray[np.float64]]] = {}

            def band_err(p: Optional[dict[str, Any]], m: tuple[float, float]) -> float:
                # The mode's analog response times the rest of the chain's spectrum (the
                # blocks commute): no simulation per trial. At most about 600 lines of the
                # band (a mode's peak spans several at that).
                if m not in masks:
                    idx = np.flatnonzero((f > m[0]) & (f < m[1]))
                    masks[m] = idx[::max(1, -(-idx.size // 600))]
                    if nuisance:
                        fm = f[masks[m]]
                        phc[m] = np.vstack([_response({"delay": {"delay_s": d}}, fm) for d in dgrid]
                                           + [_response({"lowpass": {"cutoff_hz": c, "order": o}}, fm)
                                              for o in (1, 2) for c in cgrid])
                    else:
                        phc[m] = np.ones((1, masks[m].size), dtype=np.complex128)
                mk = masks[m]
                if p is None:
                    P = B[mk]  # no mode: the band error to compare with
                else:
                    P = mode_response(p, f[mk]) * B[mk]
                if nuisance:
                    # sum |P h - Y|^2 for every nuisance's response h, as matrix products:
                    # |h|^2 |P|^2 - 2 Re(h P conj(Y)) + |Y|^2, summed over the band.
                    if m not in power:  # (the parts contiguous: a product with a strided view copies)
                        power[m] = (np.abs(phc[m]) ** 2, float(np.sum(np.abs(Y[mk]) ** 2)),
                                    np.ascontiguousarray(phc[m].real), np.ascontiguousarray(phc[m].imag))
                    h2, y2, hr, hi = power[m]
                    q = P * np.conj(Y[mk])
                    errs = h2 @ (P.real ** 2 + P.imag ** 2) - 2.0 * (hr @ q.real - hi @ q.imag) + y2
                else:
                    errs = np.array([np.sum(np.abs(P - Y[mk]) ** 2)])
                k = int(np.argmin(errs))
                if nuisance and k < dgrid.size:
                    found[0] = ("delay", float(dgrid[k]), 0)
                elif nuisance:
                    j = k - dgrid.size
                    found[0] = ("lowpass", float(cgrid[j % cgrid.size]), 1 + j // cgrid.size)
                return float(errs[k])

            def refine(f0: float, span: float) -> tuple[float, float, tuple[str, float, int], float]:
                m = (0.6 * f0, 1.6 * f0)
                lz, _ = _grid_then_golden(lambda lz: band_err({"frequency_hz": f0, "damping": math.exp(lz)}, m),
                                          np.linspace(math.log(2e-3), math.log(0.3), 12), 8)
                zeta = math.exp(lz)
                lf, _ = _grid_then_golden(lambda lf: band_err({"frequency_hz": math.exp(lf), "damping": zeta}, m),
                                          np.linspace(math.log(f0 * (1 - span)),
                                                      math.log(min(f0 * (1 + span), 0.45 * nyq)), 15), 8)
                f0 = math.exp(lf)
                lz, _ = _golden(lambda lz: band_err({"frequency_hz": f0, "damping": math.exp(lz)}, m),
                                lz - 0.4, min(lz + 0.4, math.log(0.5)), 10)
                zeta = math.exp(lz)
                none = band_err(None, m)
                err = band_err({"frequency_hz": f0, "damping": zeta}, m)
                return f0, zeta, found[0], err / max(none, 1e-300)

            return refine

        variants = [(B_keep, False)]
        if "delay" in others or "lowpass" in others or d0 == 0.0:
            variants.append((B_free, True))
        # Band fits on the 16 largest peaks (cheap: no simulation); the profiled training
        # error then judges the four whose mode explains the largest share of their band
        # (a drive's harmonics and the noise's top end make peaks too, which a light
        # mode explains poorly).
        fits = []
        for fc in (_mode_guess(y - base_keep, dt, 16) or [1000.0]):
            for B, nuisance in variants:
                f1, z1, nz, ratio = fit_variant(B, nuisance)(fc, 0.03)
                fits.append((z1 > 0.15, ratio, f1, z1, nz, nuisance))
        fits.sort(key=lambda x: (x[0], x[1]))
        trials = []
        for _, _, f1, z1, nz, nuisance in fits[:4]:
            e = dict(eff, vibration={"frequency_hz": f1, "damping": z1})
            if nuisance:
                e.pop("lowpass", None)
                e["delay"] = {"delay_s": nz[1] if nz[0] == "delay" else 0.0}
                if nz[0] == "lowpass":
                    e["lowpass"] = {"cutoff_hz": nz[1], "order": nz[2]}
            trials.append(e)
        js = self.Jmany(trials)
        return trials[int(np.argmin(js))]

    def without(self, eff: Effects, name: str) -> Effects:
        """The chain less ``name``, the rest polished (backward elimination)."""
        e = less(eff, name)
        if not any(k in e for k in DYNAMIC) and "delay" in e and e["delay"]["delay_s"] <= 0:
            del e["delay"]
        e, _ = self.polish(e, list(e), sweeps=1)
        return self.with_linear(e)


def normalized_creep(st: FitState) -> FitState:
    """The chain with its creep in the DC-gain-1 form the search uses (``y = x + c (LP[x]
    - x)``): a chain file's creep (``y = x + c LP[x]``, DC gain ``1 + S``) is the same
    with the model scaled by ``1 + S`` and the amplitudes divided by it."""
    cr = st.effects.get("creep")
    if cr is None or cr.get("normalized"):
        return st
    S = float(sum(cr["amplitudes"]))
    eff = {k: dict(v) for k, v in st.effects.items()}
    eff["creep"] = {"taus_s": list(cr["taus_s"]), "amplitudes": [c / (1 + S) for c in cr["amplitudes"]],
                    "normalized": True}
    if "rate" in eff:
        eff["rate"]["gain_s"] = float(eff["rate"]["gain_s"] * (1 + S))
    m = st.model
    return FitState(PreisachModel(m.weights * (1 + S), m.u_range, m.offset * (1 + S), m.output), eff,
                    st.train_rmse)


#: ``calibrate_slow`` fits on window averages down to about this rate: the least squares
#: over every record at full rate dominated a chain's scoring.
CAL_RATE_HZ = 5e3


def calibrate_slow(st: FitState, data: list[tuple[Record, slice]],
                   outputs: Optional[dict[Any, Any]] = None) -> FitState:
    """The slow effects of a chain (drift, creep) recalibrated across records, the masses
    and the other effects fixed. One short training record cannot tell them apart: within
    a record both are slow trends, and the masses absorb part of either. Across records
    they differ (creep starts again at rest with every record, drift runs on in absolute
    time), so the diagnoser calibrates them on the training record and the other half of
    each holdout (two-fold cross-fitting: no sample is scored with parameters fitted on
    it), and the saved chain on every record.

    With ``x`` the chain's output without drift and creep (its masses fitted with the
    drift, so referred to time 0), and ``k = LP_tau[x] - x`` the creep element's response
    (at rest at each record's start; it commutes with the other linear blocks),
    ``y - x ~ g t x + o'' t + c k`` is linear, solved for the creep's time constant on a
    grid (and its current one) by least squares on the given parts. Only what changes
    with time or restarts with the records is calibrated: the level and scale stay the
    training record's (recalibrating them would credit any effect with a free
    adjustment to the holdouts). The least squares run on window averages of every
    column (about ``CAL_RATE_HZ``: the averaged equations hold exactly, and their
    solution is that of the full-rate ones up to the noise). ``outputs``: the records'
    ``x`` by ``id(record)`` and their creep columns (``_creep_columns``), computed here
    when missing and stored (the folds of one chain share them)."""
    return _slow_fit(st, data, outputs, level=False)[0]


def level_calibrated(st: FitState, data: list[tuple[Record, slice]]) -> tuple[FitState, float]:
    """``calibrate_slow`` of a chain with drift and creep, its level and scale free as
    well (columns ``x`` and 1): the slow effects a record's masses would carry if they
    were fitted with them, and the scale those masses lack (0 when they carry the creep
    the records show). A proposal for the pair's search (:mod:`preisach.diagnose.slowpair`),
    never a score: the free scale and level adjust the chain to the records."""
    return _slow_fit(st, data, {}, level=True)


def _slow_fit(st: FitState, data: list[tuple[Record, slice]], outputs: Optional[dict[Any, Any]],
              level: bool) -> tuple[FitState, float]:
    """``calibrate_slow`` (``level``: with the scale and level free, and the scale
    coefficient returned; 0 without)."""
    # A creep of several elements (a given baseline chain's) stays as it is.
    creep = "creep" in st.effects and len(st.effects["creep"]["taus_s"]) == 1
    if "drift" not in st.effects and not creep:
        return st, 0.0
    if creep:
        st = normalized_creep(st)
    eff0 = st.effects
    pre = _without_slow(st)
    full_x: list[NDArray[np.float64]] = []
    windows: list[tuple[int, slice]] = []  # per record: window length, windows in its part
    for rec, sl in data:
        if outputs is not None and id(rec) in outputs:
            x = outputs[id(rec)]
        else:
            x = pre.predict(rec)
            if outputs is not None:
                outputs[id(rec)] = x
        full_x.append(x)
        k = max(1, int(round(1.0 / (rec.dt * CAL_RATE_HZ))))
        start, stop, _ = sl.indices(rec.y.size)
        windows.append((k, slice(-(-start // k), stop // k)))

    def averaged(cols: list[NDArray[np.float64]]) -> NDArray[np.float64]:
        """A full-rate column per record, window-averaged on the records' parts."""
        return np.concatenate([window_mean(c, k)[cut] for (k, cut), c in zip(windows, cols)])

    times = [rec.t for rec, _ in data]
    x, t, y = averaged(full_x), averaged(times), averaged([rec.y for rec, _ in data])
    drift = "drift" in eff0
    base = [averaged([xf * tf for xf, tf in zip(full_x, times)]), t] if drift else []
    if level:
        base += [x, np.ones_like(x)]
    target = y - x - (eff0["drift"]["offset"] if drift else 0.0)

    def solve(extra: list[NDArray[np.float64]]) -> tuple[NDArray[np.float64], float]:
        A = np.column_stack(base + extra)
        coef = np.linalg.lstsq(A, target, rcond=None)[0].astype(np.float64)
        return coef, float(np.sum((A @ coef - target) ** 2))

    tau = None
    if creep:
        T = max(float(rec.t[-1] - rec.t[0]) for rec, _ in data)
        fits: dict[float, tuple[NDArray[np.float64], float]] = {}

        def sse_at(lt: float) -> float:
            cols = [_creep_columns(xf, rec, math.exp(lt), k, drift, outputs)
                    for xf, (rec, _), (k, _) in zip(full_x, data, windows)]
            col = np.concatenate([c[0][cut] for c, (_, cut) in zip(cols, windows)])
            # With a drift, its gain also scales the creep (the t k column).
            tcol = [np.concatenate([c[1][cut] for c, (_, cut) in zip(cols, windows)])] if drift else []
            coef, sse = solve([col] + tcol)
            ci = -2 if drift else -1
            if not 0.0 <= coef[ci] <= CREEP_AMP_MAX:
                # The amplitude at its bound, the rest refitted (a clipped joint solution
                # would leave the other coefficients compensating an amplitude not used).
                cb = min(max(coef[ci], 0.0), CREEP_AMP_MAX)
                A = np.column_stack(base) if base else np.zeros((t.size, 0))
                r0 = target - cb * col
                if A.shape[1]:
                    sub, *_ = np.linalg.lstsq(A, r0, rcond=None)
                    sse = float(np.sum((A @ sub - r0) ** 2))
                    coef = np.concatenate([sub, [cb, 0.0] if drift else [cb]])
                else:
                    sse = float(np.sum(r0 ** 2))
                    coef = np.array([cb])
            fits[lt] = (coef, sse)
            return sse

        grid = np.log(np.geomspace(CREEP_TAU_MIN, max(0.05, CREEP_CAL_TAU_MAX_RECORDS * T), 14))
        lt, _ = _grid_then_parabola(sse_at, grid)
        lt0 = math.log(float(eff0["creep"]["taus_s"][0]))
        if sse_at(lt0) < fits[lt][1]:
            lt = lt0
        coef, tau = fits[lt][0], math.exp(lt)
        if drift:
            coef = coef[:-1]  # drop the t k coefficient (g c): the creep's is next to last
    else:
        coef, _ = solve([])
    if not np.isfinite(coef).all():
        return st, 0.0
    eff = {k: dict(v) for k, v in eff0.items()}
    if drift:
        eff["drift"] = {"gain_per_s": float(coef[0]), "offset": float(eff0["drift"]["offset"]),
                        "offset_per_s": float(coef[1])}
    if tau is not None:
        c = min(max(float(coef[-1]), 0.0), CREEP_AMP_MAX)
        eff["creep"] = {"taus_s": [float(tau)], "amplitudes": [c], "normalized": True}
    return FitState(st.model, eff, st.train_rmse), (float(coef[2 if drift else 0]) if level else 0.0)


def _without_slow(st: FitState) -> FitState:
    """The chain without the slow effects ``calibrate_slow`` calibrates (its drift, its
    creep of one element)."""
    cr = st.effects.get("creep")
    one = cr is not None and len(cr["taus_s"]) == 1
    return FitState(st.model, {k: v for k, v in st.effects.items() if k != "drift" and not (k == "creep" and one)})


def slow_predict(cal: FitState, rec: Record, outputs: dict[Any, Any]) -> NDArray[np.float64]:
    """``cal.predict(rec)`` for a chain ``calibrate_slow`` returned, from its output
    without the slow effects (``outputs``, by ``id(rec)``; computed and stored when
    missing): a creep element commutes with the other linear blocks (each at rest at the
    record's start), so the slow blocks run on that output (the creep, then the drift).
    The same output up to rounding, at the cost of a first-order filter instead of the
    chain."""
    fast = _without_slow(cal)
    x = outputs.get(id(rec))
    if x is None:
        x = outputs[id(rec)] = fast.predict(rec)
    return _run({k: v for k, v in cal.effects.items() if k not in fast.effects}, rec.t, x)


def _creep_columns(x: NDArray[np.float64], rec: Record, tau: float, k: int, drift: bool,
                   cache: Optional[dict[Any, Any]]) -> tuple[NDArray[np.float64], Any]:
    """The creep element's response ``LP_tau[x] - x`` on the whole of ``rec`` averaged
    over windows of ``k`` samples, and (with a drift) the same times the record's time;
    stored in ``cache`` by record and time constant (the folds of a chain's calibration
    take the same columns on other parts of the records). Computed from the window sums
    of the full-rate recursion (``lp_window_sums``): the same numbers as the full-rate
    response averaged, up to rounding."""
    key = (id(rec), tau, k, drift)
    if cache is not None and key in cache:
        return cache[key]  # type: ignore[no-any-return]
    s0, s1 = lp_window_sums(x, tau, rec.dt, k)
    xk = (id(rec), "x", k, drift)
    if cache is not None and xk in cache:
        xm, xtm = cache[xk]
    else:
        xm, xtm = window_mean(x, k), (window_mean(x * rec.t, k) if drift else None)
        if cache is not None:
            cache[xk] = (xm, xtm)
    col = s0 / k - xm
    tcol = None
    if drift:
        # The window's times are its first sample's plus whole samples (the sampling is regular).
        t0 = rec.t[:s0.size * k:k]
        tcol = (t0 * s0 + rec.dt * s1) / k - xtm
    out = (col, tcol)
    if cache is not None:
        cache[key] = out
    return out


def lp_window_sums(x: NDArray[np.float64], tau: float, dt: float,
                   k: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Window sums of a first-order low-pass's response ``w = LP_tau[x]`` (DC gain 1, at
    rest with ``x[0]``; sampled as the chain samples it, exact for ``x`` linear between
    samples), over windows of ``k`` samples (the last partial one dropped): ``sum_m w_m``
    and ``sum_m m w_m`` (``m`` the sample's place in its window), without the full-rate
    response. Per sample ``w_n = a w_{n-1} + f_n`` with ``f_n = b0 x_{n-1} + b1 x_n``;
    within a window every ``w_m`` is the state before the window times ``a^(m+1)`` plus
    the window's own ``f`` weighted by powers of ``a``, so the sums and the next state
    are fixed weights on each window's ``f`` (matrix products) and the state runs over
    the windows only (a first-order recursion, by cumulative sums in blocks short
    enough that the powers of ``a`` stay finite)."""
    n = x.size // k
    h = dt / tau
    # The exact integrals of the hold's two ramps (as the chain's first-order hold).
    if h < 1e-4:
        phi1, phi2 = 1.0 - h / 2 + h * h / 6, 0.5 - h / 6 + h * h / 24
    else:
        em1 = math.expm1(-h)
        phi1, phi2 = -em1 / h, (em1 + h) / (h * h)
    b0, b1 = h * (phi1 - phi2), h * phi2
    xs = x[:n * k]
    f = np.empty(n * k)
    if n == 0:
        return f, f
    f[0] = -math.expm1(-h) * xs[0]  # at rest: the state before the record is x[0]
    g = f[1:]  # b0 x[n-1] + b1 x[n], in place (no full-rate temporaries)
    g[:] = xs[:-1]
    g *= b0 / b1
    g += xs[1:]
    g *= b1
    F = f.reshape(n, k)
    m = np.arange(k, dtype=np.float64)
    lag = np.subtract.outer(m, m)
    L = np.tril(np.exp(-h * np.maximum(lag, 0.0)))  # L[m, i] = a^(m - i), i <= m
    pw = np.exp(-h * (m + 1.0))  # the state before the window, at each sample
    s = _first_order_states(h * k, F @ L[k - 1], float(xs[0]))
    return s * pw.sum() + F @ L.sum(axis=0), s * float(m @ pw) + F @ (m @ L)


def _first_order_states(hk: float, E: NDArray[np.float64], s0: float) -> NDArray[np.float64]:
    """``s_0 = s0``, ``s_{j+1} = A s_j + E_j`` with ``A = e^-hk``: the states ``s_0 ..
    s_{n-1}`` for ``n = E.size``, by cumulative sums of ``E_i / A^(i+1)`` in blocks over
    which ``1 / A`` to the block's length stays below ``e^300`` (``A`` below ``e^-300``
    forgets the state at once)."""
    n = E.size
    out = np.empty(n)
    out[0] = s0
    if hk > 300.0:
        out[1:] = E[:-1]
        return out
    A = math.exp(-hk)
    step = max(1, int(300.0 / max(hk, 1e-300)))
    s = s0
    for j in range(0, n, step):
        e = E[j:j + step]
        Aq = np.exp(-hk * np.arange(e.size, dtype=np.float64))
        acc = np.cumsum(e / (Aq * A))
        out[j:j + e.size] = Aq * (s + np.concatenate([[0.0], acc[:-1]]))
        s = Aq[-1] * A * (s + acc[-1])
    return out


def _run(effects: Effects, t: NDArray[np.float64], x: NDArray[np.float64]) -> NDArray[np.float64]:
    """The effects (no hysteresis, no rate) applied to ``x`` sampled at ``t``."""
    return Chain(None, effects).predict(t, x) if effects else x


def _response(effects: Effects, f_hz: Any) -> NDArray[np.complex128]:
    """The analog frequency response of linear effects at ``f_hz``."""
    return Chain(None, effects).response(f_hz)


def mode_response(p: dict[str, Any], f_hz: Any) -> NDArray[np.complex128]:
    """The vibration block's response ``w^2 / (s^2 + 2 zeta w s + w^2)`` of one mode at
    ``f_hz`` (what ``_response`` gives, without building a chain: a mode's band fit asks
    for thousands)."""
    w = 2 * math.pi * float(p["frequency_hz"])
    s = 2j * math.pi * np.asarray(f_hz, dtype=np.float64)
    out: NDArray[np.complex128] = w * w / (s * s + 2.0 * float(p["damping"]) * w * s + w * w)
    return out
