"""diagnose: bad input, report format, CLI, and a small blind validation whose ground
truth is simulated independently (benches/blind_validation.py, SciPy filters)."""
import argparse
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benches"))
import blind_validation as bv  # noqa: E402

from preisach.chain import Chain  # noqa: E402
from preisach.diagnose import diagnose, run_cli  # noqa: E402

DYNAMIC = {"delay", "lowpass", "vibration", "creep", "drift", "rate"}


def _rec(r):
    return {k: r[k] for k in "tuy"}


@pytest.fixture(scope="module")
def delay_stage():
    return bv.make_stage(11, ("delay",))


def test_bad_records_name_the_record_and_problem(delay_stage):
    tr = _rec(delay_stage["train"])
    ho = _rec(delay_stage["holdouts"][0])
    bad = dict(ho)
    bad["y"] = bad["y"].copy()
    bad["y"][5] = np.nan
    with pytest.raises(ValueError, match=r"holdout 1: NaN in y at sample 5"):
        diagnose(tr, [bad], progress=False)
    short = dict(ho, u=ho["u"][:-3])
    with pytest.raises(ValueError, match=r"holdout 1: mismatched lengths"):
        diagnose(tr, [short], progress=False)
    mono = dict(tr, u=np.linspace(0, 100, tr["u"].size))
    with pytest.raises(ValueError, match=r"train: the input has no reversals"):
        diagnose(mono, [ho], progress=False)
    with pytest.raises(ValueError, match="holdouts"):
        diagnose(tr, [], progress=False)


def test_delay_found_with_parameters_and_cli_outputs(delay_stage, tmp_path):
    st = delay_stage
    from preisach.io import write_csv

    paths = []
    for i, r in enumerate([st["train"]] + st["holdouts"]):
        p = tmp_path / f"r{i}.csv"
        write_csv(p, {k: r[k] for k in "tuy"})
        paths.append(str(p))
    # The second holdout at a different sample rate (decimated by 2) must be fine.
    h2 = st["holdouts"][1]
    p = tmp_path / "r2.csv"
    write_csv(p, {k: h2[k][::2] for k in "tuy"})
    paths[2] = str(p)
    ns = argparse.Namespace(train=paths[0], holdout=paths[1:], n_h=40, baseline=None,
                            json=str(tmp_path / "rep.json"), save_model=str(tmp_path / "aug.json"), plots=None)
    assert run_cli(ns) == 0
    rep = json.loads((tmp_path / "rep.json").read_text())
    for k in ("dominant_effect", "noise_floor", "baseline", "where", "split", "effects"):
        assert k in rep
    assert rep["dominant_effect"] == "delay"
    top = rep["effects"][0]
    for k in ("name", "detected", "score", "evidence", "params", "rmse_before", "rmse_after", "shrink"):
        assert k in top
    true_d = st["params"]["delay"]["delay_s"]
    assert abs(top["params"]["delay_s"] / true_d - 1) < 0.10
    assert top["rmse_after"] < 0.5 * top["rmse_before"]
    # Noise floor recovered from the data (simulated white noise sigma = 0.003).
    assert 0.002 < rep["noise_floor"] < 0.0045
    # The saved chain runs on the blind record and beats the baseline there.
    ch = Chain.load(tmp_path / "aug.json")
    b = st["blind"]
    from preisach import PreisachModel

    base = PreisachModel.fit(st["train"]["u"], st["train"]["y"], 40)
    e_aug = np.sqrt(np.mean((ch.predict(b["t"], b["u"]) - b["y"]) ** 2))
    e_base = np.sqrt(np.mean((base.predict(b["u"]) - b["y"]) ** 2))
    assert e_aug < 0.5 * e_base


@pytest.mark.parametrize("names,seed", [
    ((), 21), (("vibration",), 22), (("lowpass",), 24), (("drift",), 23), (("creep",), 25),
])
def test_small_blind_validation(names, seed):
    """Key goals on a few fixed-seed stages: right top-1, no false alarm, mode within 3 %,
    drift gain within 10 %, creep element within 25 %, realised shrink >= 70 % on the
    unseen record."""
    st = bv.make_stage(seed, names)
    rep = diagnose(st["train"], [_rec(h) for h in st["holdouts"]], progress=False)
    found = {e["name"] for e in rep.effects if e["detected"]}
    if not names:
        assert not (found & DYNAMIC), f"false alarm {found}"
        return
    assert rep.dominant_effect == names[0]
    got = {e["name"]: e["params"] for e in rep.effects if e["detected"]}
    true = st["params"][names[0]]
    if names[0] == "vibration":
        assert abs(got["vibration"]["frequency_hz"] / true["frequency_hz"] - 1) < 0.03
    if names[0] == "drift":
        assert abs(got["drift"]["gain_per_s"] / true["gain_per_s"] - 1) < 0.10
    if names[0] == "creep":
        # One element recovered: time constant and gain within 25 %.
        assert abs(got["creep"]["taus_s"][0] / true["taus_s"][0] - 1) < 0.25
        assert abs(got["creep"]["amplitudes"][0] / true["amplitudes"][0] - 1) < 0.25
    b = st["blind"]
    ch = Chain.from_dict(rep.augmented_chain_dict())
    from preisach import PreisachModel

    base = PreisachModel.from_dict(rep.baseline_model_dict())
    e_aug = np.sqrt(np.mean((ch.predict(b["t"], b["u"]) - b["y"]) ** 2))
    e_base = np.sqrt(np.mean((base.predict(b["u"]) - b["y"]) ** 2))
    # The goal: realised shrink >= 70 % on the unseen record.
    assert e_aug < 0.3 * e_base
