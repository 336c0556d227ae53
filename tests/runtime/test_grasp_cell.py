"""runtime/grasp.py on the synthetic cell's frames: the same records as the grasp step made before
a change (tests/runtime/fixtures/cell_frames, written by benchmarks/grasp_identity.py --fixture),
on the reference model's labels (stored as PNG) and on the scenes' true labels. Every field of every
record must match, and its keys come in the same order (`grasp` prints them so): the pick loop's
choice, plan and verdict follow from them."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest

from edgepick.data.render import CLASSES
from edgepick.runtime.grasp import Laps, grasp_records
from edgepick.runtime.grasp_record import Grasp
from edgepick.sim.camera import SynthCamera

FIXTURE = Path(__file__).parent / "fixtures" / "cell_frames"
STORED = json.loads((FIXTURE / "records.json").read_text())


def as_json(grasps: list[Grasp]) -> str:
    """The records `grasp` prints for GRASPS, as JSON text: their values and their keys' order."""
    return json.dumps([g.to_dict() for g in grasps])


def cell_frame(name: str):
    """The synthetic cell's frame NAME (synth-SEED-INDEX), rendered again."""
    _, seed, index = name.split("-")
    camera = SynthCamera(640, 480, seed=int(seed), mount_height_m=STORED["mount_height_m"])
    camera.index = int(index)
    frame = camera.read()
    assert frame.name == name
    return frame, camera.calibration()


@pytest.mark.parametrize("stored", STORED["frames"], ids=lambda f: f["frame"])
def test_the_grasp_step_makes_the_records_it_made_before(stored):
    frame, calibration = cell_frame(stored["frame"])
    labels = cv2.imread(str(FIXTURE / stored["labels"]), cv2.IMREAD_UNCHANGED)
    assert as_json(grasp_records(labels, frame.depth, frame.intrinsics, CLASSES, calibration)) == \
        json.dumps(stored["model_records"])
    assert as_json(grasp_records(frame.labels, frame.depth, frame.intrinsics, CLASSES, calibration)) == \
        json.dumps(stored["truth_records"])


def test_the_fixture_covers_every_class_and_objects_cut_by_the_border_or_under_others():
    records = [r for f in STORED["frames"] for r in f["model_records"]]
    assert {r["class"] for r in records} == set(CLASSES[1:])
    assert len(STORED["frames"]) >= 30
    assert sum(r["partial"] for r in records) > 0 and sum(r["occluded"] > 0 for r in records if "occluded" in r) > 0


def test_a_record_read_back_is_the_grasp_it_was_made_from():
    records = [r for f in STORED["frames"] for r in f["model_records"] + f["truth_records"]]
    assert [Grasp.from_dict(r).to_dict() for r in records] == records


def test_laps_time_every_sub_step_without_changing_the_records():
    stored = STORED["frames"][0]
    frame, calibration = cell_frame(stored["frame"])
    laps = Laps()
    assert as_json(grasp_records(frame.labels, frame.depth, frame.intrinsics, CLASSES, calibration, laps=laps)) == \
        json.dumps(stored["truth_records"])
    assert set(laps.ms) == set(Laps.STEPS) and all(v >= 0 for v in laps.ms.values())
    assert laps.ms["filters"] > 0 and laps.ms["moments"] > 0 and laps.ms["depth"] > 0
