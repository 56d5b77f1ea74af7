"""Every version-1 file in ``tests/data/v1`` (written, with its outputs, by the build
that wrote version 1: ``tests/data/v1/record.py``) loads, gives the same outputs to
rounding, and round-trips through version 2 exactly."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import preisach
from preisach import Chain, PreisachModel
from preisach.sim import Stage

DATA = Path(__file__).resolve().parent / "data" / "v1"
OUT = np.load(DATA / "outputs.npz")
MODELS = ["model_stepwise", "model_interpolated"]
STAGES = ["stage_paper", "stage_paper_delay_drift", "stage_every_block"]


def _close(y: np.ndarray, want: np.ndarray, lsb: float = 0.0) -> None:
    """Equal to rounding; with an ADC of step ``lsb`` at the end, a value within rounding
    of a code boundary may land on the next code (at most a few samples)."""
    tol = 1e-10 * max(1.0, float(np.max(np.abs(want))))
    off = np.abs(y - want) > tol
    assert off.sum() <= (3 if lsb else 0), f"{off.sum()} samples differ, max {np.max(np.abs(y - want))}"
    assert np.all(np.abs(y - want)[off] <= lsb + tol)


def _round_trip(chain: Chain) -> Chain:
    """Version 2 written, read and written again: the same text and dict."""
    text = chain.to_json()
    back = Chain.from_json(text)
    assert back.to_json() == text
    d = json.loads(text)
    assert d["format"] == "preisach-chain" and d["version"] == 2
    assert Chain.from_dict(d).to_dict() == d
    return back


@pytest.mark.parametrize("name", MODELS)
def test_version_1_models(name: str) -> None:
    m = preisach.load(DATA / f"{name}.json")
    assert isinstance(m, PreisachModel)
    _close(m.predict(OUT["chain_u"]), OUT[name])
    v2 = _round_trip(Chain(m))
    back = PreisachModel.from_dict(v2.to_dict())
    np.testing.assert_array_equal(back.weights, m.weights)
    assert back.output == m.output and back.offset == m.offset
    if name == "model_stepwise":
        assert m.report is not None and back.report is not None
        assert m.report.to_dict() == back.report.to_dict() == json.loads((DATA / f"{name}.json").read_text())["report"]


def test_version_1_chain_of_every_effect() -> None:
    ch = preisach.load(DATA / "chain_effects.json")
    assert isinstance(ch, Chain)
    assert ch.kinds() == ["hysteresis", "rate", "creep", "vibration", "lowpass", "delay", "drift"]
    t, u = OUT["chain_t"], OUT["chain_u"]
    _close(ch.predict(t, u), OUT["chain_effects"])
    back = _round_trip(ch)
    np.testing.assert_array_equal(back.predict(t, u), ch.predict(t, u))
    # The pinned view of a model and its effects is unchanged by the conversion.
    v1 = json.loads((DATA / "chain_effects.json").read_text())
    assert ch.effects == {e["name"]: e["params"] for e in v1["effects"]}


@pytest.mark.parametrize("name", STAGES)
def test_version_1_stages(name: str) -> None:
    text = (DATA / f"{name}.json").read_text()
    v1 = json.loads(text)
    st = Stage.from_json(text)
    assert st.sample_rate_hz == v1["sample_rate_hz"]
    assert st.kinds() == [b["type"] for b in v1["blocks"]]
    adc = v1["blocks"][-1].get("adc") or {}
    lsb = (adc["range"][1] - adc["range"][0]) / (2 ** adc["bits"] - 1) if adc else 0.0
    y = st.run(OUT["stage_u"])
    _close(y, OUT[name], lsb)
    back = _round_trip(st)
    np.testing.assert_array_equal(Stage.from_json(back.to_json()).run(OUT["stage_u"]), y)
