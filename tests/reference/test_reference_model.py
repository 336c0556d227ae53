"""The shipped reference int8 model (edgepick/reference/): small enough to ship, described by its
card (the card's sha256 is the file's), loadable by the torch-free runtime, and it picks in the
synthetic cell."""

from __future__ import annotations

import re

from edgepick.data.render import CLASSES
from edgepick.files import sha256_of
from edgepick.reference import CARD, reference_model
from edgepick.robot.cycle import verdicts
from edgepick.robot.grippers import DigitalGripper
from edgepick.robot.loop import Cell, run_cycles
from edgepick.robot.pick import CommandLog, PickConfig
from edgepick.robot.verdict import summarize
from edgepick.runtime.pipeline import Pipeline
from edgepick.runtime.session import Segmenter
from edgepick.sim.camera import SynthCamera
from edgepick.sim.robot import SimRobot


def test_reference_model_is_small_int8_and_its_card_describes_it():
    model = reference_model()
    assert model is not None and model.stat().st_size <= 15e6
    card = CARD.read_text()
    assert re.search(r"sha256[^\n]*" + sha256_of(model), card), "MODEL_CARD.md names another file"
    assert "bash benchmarks/reference_model.sh" in card and "benchmarks/results/table56/" in card
    info = Segmenter(model, threads=1).info
    assert info.precision == "int8" and info.classes == list(CLASSES)


def test_reference_model_picks_in_the_synthetic_cell():
    """Eight cycles on scenes no result file uses (seed 31): most succeed. A regression in the
    runtime, the grasp step or the model file shows here; the rate itself is benchmarks' business."""
    camera, robot = SynthCamera(seed=31, mount_height_m=0.7), SimRobot()
    truth = camera.calibration()
    with camera, robot:
        cell = Cell(camera, Pipeline(Segmenter(reference_model(), threads=2), truth), robot, DigitalGripper(robot, 0),
                    CommandLog(None), truth)
        results = run_cycles(cell, cfg=PickConfig(), cycles=8, echo=lambda line: None)
    assert summarize(verdicts(results))["success"] >= 6, [r.verdict for r in results]
