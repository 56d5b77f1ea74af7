"""Shared pieces of the fuzz tests (tests/test_fuzz_*.py) and of benches/fuzz_campaign.py:
hostile values, arrays and JSON mutations as hypothesis strategies, and the contract
every call must meet.

The contract (:func:`outcome`): a call either returns, or raises ``ValueError`` whose
message names one of the arguments it was given (or the file). Anything else fails the
test: a ``PanicException`` (pyo3; not an ``Exception``), the ``RuntimeError`` the glue
turns a Rust panic into, a ``TypeError``/``KeyError``/``RecursionError`` leaking from
the Python layer, a crash of the process. A hang is caught by :func:`watchdog`, which
ends the process with a traceback of every thread if one call takes too long.
"""
from __future__ import annotations

import atexit
import copy
import faulthandler
import json
import os
import re
import sys
from collections import Counter
from contextlib import contextmanager
from typing import Any, Callable, Iterable, Iterator

import numpy as np
from hypothesis import strategies as st

#: Seconds one fuzzed call may take before the process is ended as hung.
HANG_S = 60.0

#: Values that break naive numerics.
HOSTILE_FLOATS = (float("nan"), float("inf"), -float("inf"), 1e308, -1e308, 1e300, 5e-324, -5e-324, 2.2e-308,
                  1e-310, 0.0, -0.0, 1.0, -1.0, 1e-300, 2.0**53, 1e16)

#: Things that are not numbers where a number is expected.
NOT_NUMBERS = (None, "1", "x", b"\x00", [], {}, [1.0, 2.0], True, object())

hostile_float = st.one_of(st.sampled_from(HOSTILE_FLOATS), st.floats(allow_nan=True, allow_infinity=True))
finite_float = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)


@st.composite
def hostile_array(draw: Any, max_len: int = 40) -> Any:
    """A 1-D-ish array-like: empty, length 1, hostile values, a few wrong shapes and types."""
    kind = draw(st.sampled_from(["finite", "finite", "hostile", "empty", "one", "2d", "object", "ints", "scalar"]))
    n = draw(st.integers(2, max_len))
    if kind == "finite":
        return np.array(draw(st.lists(finite_float, min_size=n, max_size=n)))
    if kind == "hostile":
        vals = draw(st.lists(st.one_of(finite_float, hostile_float), min_size=n, max_size=n))
        return np.array(vals)
    if kind == "empty":
        return np.zeros(0)
    if kind == "one":
        return np.array([draw(st.one_of(finite_float, hostile_float))])
    if kind == "2d":
        return np.zeros((2, draw(st.integers(0, 3))))
    if kind == "object":
        return draw(st.sampled_from([["a", "b"], [None, 1.0], [[1.0], [2.0, 3.0]], "abc", {"x": 1}]))
    if kind == "ints":
        return np.arange(n, dtype=draw(st.sampled_from([np.int8, np.int64, np.uint16, np.float32])))
    return draw(st.one_of(hostile_float, st.sampled_from(NOT_NUMBERS)))


def sweep(n: int, lo: float = 0.0, hi: float = 10.0, reversals: int = 6) -> np.ndarray:
    """A valid identification input: a sine of increasing amplitude over [lo, hi]."""
    k = np.linspace(0.0, 1.0, n)
    return 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.linspace(0.1, 1.0, n) * np.sin(np.pi * reversals * k)


# --- JSON mutations ----------------------------------------------------------------
def _paths(x: Any, here: tuple[Any, ...] = ()) -> Iterator[tuple[Any, ...]]:
    """Every path (keys and indices) into nested dicts/lists, the root excluded."""
    if isinstance(x, dict):
        for k, v in x.items():
            yield here + (k,)
            yield from _paths(v, here + (k,))
    elif isinstance(x, list):
        for i, v in enumerate(x[:8]):
            yield here + (i,)
            yield from _paths(v, here + (i,))


def _parent(doc: Any, path: tuple[Any, ...]) -> Any:
    for k in path[:-1]:
        doc = doc[k]
    return doc


WRONG_VALUES = (None, "text", -1, 0, 1e308, -1e308, 2**64, [], {}, [[]], True, 1.5, {"a": 1}, [1e300] * 3)

MUTATIONS = ("remove", "wrong_type", "nest", "huge_array", "duplicate_key", "truncate", "garbage", "nan")


@st.composite
def mutated_json(draw: Any, doc: Any) -> str:
    """The JSON text of ``doc`` with one hostile change: a field removed, a value of the
    wrong type, a deep nesting, a huge array, a duplicate key, the text truncated, bytes
    of garbage, a NaN literal."""
    doc = copy.deepcopy(doc)
    how = draw(st.sampled_from(MUTATIONS))
    paths = list(_paths(doc))
    if how == "truncate":
        text = json.dumps(doc)
        return text[: draw(st.integers(0, max(0, len(text) - 1)))]
    if how == "garbage":
        text = json.dumps(doc)
        i = draw(st.integers(0, len(text)))
        junk = draw(st.sampled_from(["\x00", "\ufffd", "}}", "]", ",", "\"", "{", "1e99999", "NaN", "\\u0000"]))
        return text[:i] + junk + text[i:]
    path = draw(st.sampled_from(paths)) if paths else None
    if path is None:
        return json.dumps(draw(st.sampled_from(WRONG_VALUES)))
    parent, key = _parent(doc, path), path[-1]
    if how == "remove":
        if isinstance(parent, dict):
            del parent[key]
        else:
            parent.pop(key)
    elif how == "wrong_type":
        parent[key] = draw(st.sampled_from(WRONG_VALUES))
    elif how == "nest":
        depth = draw(st.sampled_from([3, 100, 5000, 100_000]))
        return _replace(doc, path, "[" * depth + "]" * depth)
    elif how == "huge_array":
        return _replace(doc, path, "[" + ",".join(["1e300"] * draw(st.sampled_from([1000, 100_000]))) + "]")
    elif how == "nan":
        return _replace(doc, path, draw(st.sampled_from(["NaN", "Infinity", "-Infinity", "1e400"])))
    elif how == "duplicate_key" and isinstance(parent, dict):
        text = json.dumps(doc)
        k = json.dumps(str(key))
        return text.replace(f"{k}:", f"{k}: null, {k}:", 1)
    return json.dumps(doc)


def _replace(doc: Any, path: tuple[Any, ...], raw: str) -> str:
    """``doc`` as JSON text with the value at ``path`` replaced by raw JSON text ``raw``."""
    marker = "__FUZZ_MARKER__"
    _parent(doc, path)[path[-1]] = marker
    return json.dumps(doc).replace(json.dumps(marker), raw, 1)


# --- corrupt files -----------------------------------------------------------------
@st.composite
def corrupt_bytes(draw: Any, good: bytes) -> bytes:
    """``good`` truncated, with bytes flipped, with binary garbage, or empty."""
    how = draw(st.sampled_from(["truncate", "flip", "garbage", "empty", "insert"]))
    if how == "truncate":
        return good[: draw(st.integers(0, max(0, len(good) - 1)))]
    if how == "flip":
        b = bytearray(good)
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, len(b) - 1))
            b[i] = draw(st.integers(0, 255))
        return bytes(b)
    if how == "garbage":
        return draw(st.binary(min_size=1, max_size=400))
    if how == "insert":
        i = draw(st.integers(0, len(good)))
        return good[:i] + draw(st.binary(min_size=1, max_size=40)) + good[i:]
    return b""


# --- the contract ------------------------------------------------------------------
@contextmanager
def watchdog(seconds: float = HANG_S) -> Iterator[None]:
    """End the process (with every thread's traceback) if the block takes longer than
    ``seconds``: a hung call inside Rust cannot be interrupted any other way."""
    faulthandler.dump_traceback_later(seconds, exit=True)
    try:
        yield
    finally:
        faulthandler.cancel_dump_traceback_later()


def names_one_of(message: str, names: Iterable[str]) -> bool:
    """True if ``message`` names one of ``names`` (as a whole word)."""
    return any(re.search(rf"(?<![\w]){re.escape(n)}(?![\w])", message) for n in names)


#: Calls per fuzz test and how they ended ("returned", "refused"), for the campaign's
#: table (benches/fuzz_campaign.py sets FUZZ_STATS to a file to receive them).
TALLY: Counter[tuple[str, str]] = Counter()


@atexit.register
def _write_tally() -> None:
    path = os.environ.get("FUZZ_STATS")
    if path and TALLY:
        with open(path, "a", encoding="utf-8") as f:
            for (test, how), n in sorted(TALLY.items()):
                f.write(json.dumps({"test": test, "how": how, "n": n}) + "\n")


def current_test(depth: int = 2) -> str:
    """Name of the test function calling (``depth`` frames up, or further up)."""
    frame = sys._getframe(depth)
    while frame is not None and not frame.f_code.co_name.startswith("test_"):
        frame = frame.f_back  # type: ignore[assignment]
    return frame.f_code.co_name if frame is not None else "?"


def outcome(call: Callable[[], Any], names: Iterable[str]) -> Any:
    """Run ``call()`` under the watchdog. Returns its result, or the ``ValueError`` it
    raised after checking that the message names one of ``names``. Any other exception
    propagates (and fails the test)."""
    names = tuple(names)
    test = current_test()
    with watchdog():
        try:
            got = call()
            TALLY[test, "returned"] += 1
            return got
        except ValueError as exc:
            TALLY[test, "refused"] += 1
            msg = str(exc)
            assert "\n" not in msg.strip() or len(msg) < 2000, f"error message is not one line: {msg!r}"
            assert names_one_of(msg, names), f"error does not name any of {names}: {msg!r}"
            return exc
