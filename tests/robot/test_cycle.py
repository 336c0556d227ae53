"""CycleResult (robot/cycle.py): checked on creation, and its to_dict() is the cycle `pick` prints, its
keys in the order they always came, for a cycle skipped, planned, carried out or stopped."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from edgepick.robot.cycle import CycleResult, verdicts
from edgepick.robot.pick import PickConfig, plan_pick
from edgepick.robot.verdict import Verdict
from tests.conftest import make_grasp

BOX = make_grasp("box", (0.28, 0.0, 0.05, math.pi, 0.0, 0.0))
MEASURED = Verdict(True, measured=True, position_error_m=0.002)


def cycle(outcome: str, **fields) -> CycleResult:
    chosen = None if outcome == "skipped" else BOX
    return CycleResult(3, "synth-0-000002", 2, {"grasp": 1.5}, 4.25, outcome, chosen=chosen, **fields)


def test_a_skipped_cycle_says_why_then_how_it_was_judged():
    skipped = cycle("skipped", reason="box: cut by the image border", frame_to_frame_ms=80.0,
                    verdict=Verdict(False, "unreachable"), undetected=1, physics=Verdict(False, "unreachable"))
    assert list(skipped.to_dict()) == ["cycle", "frame", "objects", "stage_ms", "plan_ms", "frame_to_frame_ms",
                                       "outcome", "reason", "verdict", "undetected", "physics"]
    assert skipped.to_dict()["verdict"] == {"success": False, "failure": "unreachable"}
    assert skipped.target is None and not skipped.carried_out


def test_a_planned_cycle_prints_its_plan_and_a_carried_out_one_its_times():
    plan = plan_pick(BOX, PickConfig())
    planned = cycle("planned", plan=plan, grasp_error_m=0.002, within_1cm=True)
    assert list(planned.to_dict()) == ["cycle", "frame", "objects", "stage_ms", "plan_ms", "target", "pixel",
                                       "pose_robot", "grasp_error_m", "within_1cm", "outcome", "plan"]
    assert planned.to_dict()["pixel"] == list(BOX.pixel) and len(planned.to_dict()["plan"]) == len(plan)
    done = replace(planned, outcome="done", scene={"lighting": "single"}, frame_to_command_ms=12.0, motion_s=3.5,
                   verdict=MEASURED, undetected=0, round={"round": 1})
    assert list(done.to_dict()) == ["cycle", "frame", "objects", "stage_ms", "plan_ms", "scene", "target", "pixel",
                                    "pose_robot", "grasp_error_m", "within_1cm", "verdict", "undetected",
                                    "frame_to_command_ms", "motion_s", "outcome", "reason", "round"]
    stopped = replace(done, outcome="stopped", reason="protective stop", verdict=MEASURED.stopped())
    assert stopped.to_dict()["verdict"] == {"success": False, "failure": "robot stopped", "position_error_m": 0.002,
                                            "angle_error_deg": None}
    assert verdicts([planned, done, stopped]) == [MEASURED, MEASURED.stopped()] and verdicts([done], "physics") == []


@pytest.mark.parametrize("fields", [
    {"outcome": "waved"},
    {"outcome": "skipped", "chosen": BOX},
    {"outcome": "planned", "chosen": None},
    {"outcome": "planned", "chosen": make_grasp("box", None)},
    {"outcome": "planned", "chosen": BOX, "verdict": MEASURED},  # judged, but no undetected count
    {"outcome": "planned", "chosen": BOX, "physics": MEASURED},  # physics without the geometric verdict
])
def test_a_cycle_that_cannot_be_is_refused(fields):
    with pytest.raises(ValueError):
        CycleResult(1, "f", 0, {}, 1.0, **fields)
