"""benchmarks/table54.py's plumbing: its settings, resumable steps and the --work guard. The study
itself runs as `python benchmarks/table54.py --setting smoke` (minutes), not in the suite."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from table54 import QAT_FRACTION, SETTINGS, THESIS, claim_work, step  # noqa: E402

from edgepick.models.config import Arch


@pytest.mark.parametrize("name", sorted(SETTINGS))
def test_every_setting_trains_known_archs_with_a_qat_epoch(name):
    s = SETTINGS[name]
    assert {Arch(a) for a in s.archs} and len(s.seeds) == len(set(s.seeds))
    assert round(QAT_FRACTION * s.epochs) >= 1  # hybrid-QaT 5% has at least one QaT epoch
    assert 0 < s.frame_calib and s.runs > 0 and s.warmup >= 0


def test_the_quick_and_gpu_settings_have_the_thesiss_four_and_three_seeds():
    for name in ("quick", "gpu"):
        assert set(THESIS) <= set(SETTINGS[name].archs) and len(SETTINGS[name].seeds) >= 3
    assert set(SETTINGS["gpu"].archs) == {a.value for a in Arch}


def test_a_step_is_made_once_and_records_its_time(tmp_path):
    calls = []

    def make() -> dict:
        calls.append(1)
        return {"value": 3}

    first = step(tmp_path / "s.json", make)
    again = step(tmp_path / "s.json", make)
    assert first == again and first["value"] == 3 and first["step_s"] >= 0 and calls == [1]
    assert not list(tmp_path.glob("*.partial"))


def test_work_is_refused_if_the_script_did_not_make_it_or_for_another_setting(tmp_path):
    theirs = tmp_path / "theirs"
    theirs.mkdir()
    (theirs / "notes.txt").write_text("keep me")
    with pytest.raises(SystemExit, match="did not make"):
        claim_work(theirs, SETTINGS["smoke"])
    assert [p.name for p in theirs.iterdir()] == ["notes.txt"]

    ours = tmp_path / "ours"
    claim_work(ours, SETTINGS["smoke"])  # a new folder
    claim_work(ours, SETTINGS["smoke"])  # resumed
    assert json.loads((ours / "table54.json").read_text()) == {"setting": "smoke"}
    with pytest.raises(SystemExit, match="holds the smoke setting's steps, not quick's"):
        claim_work(ours, SETTINGS["quick"])
    empty = tmp_path / "empty"
    empty.mkdir()
    claim_work(empty, SETTINGS["quick"])
