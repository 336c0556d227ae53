"""Clutter-removal rounds (sim/clutter.py, MuJoCo): a table laid out once and picked from until it is
empty, the picked part gone and the rest settled before the next frame, which is a fresh render of
the settled table; the round's end rules; `pick --rounds` end to end, and its refusals."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

pytest.importorskip("mujoco")

from edgepick.data.render import CLASSES  # noqa: E402
from edgepick.errors import ParameterError  # noqa: E402
from edgepick.intervals import wilson  # noqa: E402
from edgepick.robot.clearance import HandShape  # noqa: E402
from edgepick.robot.grippers import DigitalGripper  # noqa: E402
from edgepick.robot.loop import Cell, run_cycles  # noqa: E402
from edgepick.robot.messages import rotation  # noqa: E402
from edgepick.robot.pick import CommandLog, PickConfig  # noqa: E402
from edgepick.sim.clutter import ClutterRound, RoundConfig, round_summary, run_rounds  # noqa: E402
from edgepick.sim.oracle import TruthPipeline  # noqa: E402
from edgepick.sim.physics_scene import settle  # noqa: E402
from edgepick.sim.robot import SimRobot  # noqa: E402
from tests.conftest import run_cli  # noqa: E402

PICK = PickConfig(hand=HandShape())


def _run(cell: ClutterRound, pick: PickConfig = PICK, physics: bool = True) -> tuple[list[dict], list]:
    """A round with the true labels: each cycle's result, and the (frame, SceneChange) of each cycle."""
    seen: list = []
    read, after = cell.read, cell.after

    def reading():
        seen.append([read(), None])
        return seen[-1][0]

    def settling(result, record, frame):
        seen[-1][1] = after(result, record, frame)
        return seen[-1][1]

    cell.read, cell.after = reading, settling
    robot = SimRobot()
    with robot:
        picking = Cell(cell, TruthPipeline(list(CLASSES), cell.calibration()), robot, DigitalGripper(robot, 0),
                       CommandLog(None), cell.calibration(), physics=cell.physics_judge(pick) if physics else None)
        results = run_cycles(picking, cfg=pick, cycles=cell.cap, echo=lambda line: None, after=settling)
    return results, seen


def test_round_config_refuses_what_no_round_can_be():
    with pytest.raises(ParameterError, match="max_cycles=0"):
        RoundConfig(max_cycles=0)
    with pytest.raises(ParameterError, match="max_cycles=-3"):
        RoundConfig(max_cycles=-3)
    with pytest.raises(ParameterError, match="objects=.5, 4."):
        RoundConfig(objects=(5, 4))
    assert RoundConfig().cap(7) == 16 and RoundConfig(max_cycles=3).cap(7) == 3


@pytest.mark.parametrize("seed, index", [(5, 1), (5, 2), (5, 3), (0, 191)])  # (0, 191): a draw with parts at the edge
def test_a_round_lays_out_4_to_10_parts_at_rest_in_the_pick_area(seed, index):
    cell = ClutterRound(640, 480, seed=seed, index=index)
    assert 4 <= len(cell.parts) <= 10 and cell.laid_out == len(cell.parts)
    (x0, x1), (y0, y1) = cell.PICK_AREA_M
    assert all(x0 - 0.05 <= p.base[0] <= x1 + 0.05 and y0 - 0.05 <= p.base[1] <= y1 + 0.05 for p in cell.parts)
    again = settle(cell.mujoco, [p.solid() for p in cell.parts], cell.physics_cfg)  # at rest: nothing moves
    assert max(float(np.linalg.norm(base - p.base)) for p, (base, _) in zip(cell.parts, again)) < 0.002
    frame = cell.read()
    ids = sorted(t["id"] for t in frame.truth + frame.hidden)
    assert ids == sorted(p.key for p in cell.parts)
    assert frame.scene["round"] == index and frame.scene["pick"] == 1
    # the camera sees the whole tray: no part's pixels come near the frame's edges
    margin = int(0.04 * frame.labels.shape[1])
    inner = np.zeros(frame.labels.shape, bool)
    inner[margin:-margin, margin:-margin] = True
    assert not (frame.labels[~inner] > 0).any()


def test_a_part_laid_out_partly_out_of_view_is_left_out():
    cell = ClutterRound(640, 480, seed=5, index=1)
    part = cell.parts[0]
    assert cell._in_view(part)
    part.base = part.base + [0.0, 0.30, 0.0]  # towards the frame's edge (robot +y: the image's left)
    assert not cell._in_view(part)


def test_a_rounds_frame_after_a_pick_is_a_fresh_render_of_the_settled_table():
    """After a pick the part taken is gone, the rest lie where they settled, and the next frame is
    what a fresh renderer draws of that table: the same image, depth, labels and truth."""
    cell = ClutterRound(640, 480, seed=0, index=4, cfg=RoundConfig(max_cycles=2))
    parts_after_first: list = []
    after = cell.after

    def keep(result, record, frame):
        change = after(result, record, frame)
        if not parts_after_first:
            parts_after_first.extend(copy.deepcopy(cell.parts))
        return change

    cell.after = keep
    results, seen = _run(cell)
    (first, change), (second, _) = seen
    assert results[0].physics.success and change.removed is not None
    assert len(change.after) == len(change.before) - 1
    assert change.removed not in [t["id"] for t in second.truth + second.hidden]
    fresh = ClutterRound(640, 480, seed=0, index=4)  # its own renderer and layout, the table set as the round left it
    fresh.parts, fresh.picks = parts_after_first, 1
    again = fresh.read()
    assert np.array_equal(again.rgb, second.rgb) and np.array_equal(again.depth, second.depth)
    assert np.array_equal(again.labels, second.labels) and again.truth == second.truth and again.hidden == second.hidden
    assert not np.array_equal(first.labels, second.labels)
    # the recorded poses (what a recording holds, to the micrometre) put each part where the frame shows it
    cal = cell.calibration()
    for part in change.after:
        truth = next(t for t in second.truth + second.hidden if t["id"] == part["id"])
        base = cal.apply(np.asarray(truth["solid"]["base_camera_m"]))
        assert np.linalg.norm(base - part["pose"][:3]) < 1e-5
        up = cal.R @ np.asarray(truth["solid"]["up_camera"])
        assert np.allclose(up, rotation(part["pose"][3:])[:, 2], atol=1e-5)


def test_a_round_ends_when_the_table_is_empty():
    results, seen = _run(ClutterRound(640, 480, seed=0, index=4))
    change = seen[-1][1]
    assert change.ended == "cleared" and change.after == []
    assert results[-1].round == {"round": 4, "pick": len(results), "removed": change.removed, "fell": [], "left": 0,
                                    "ended": "cleared"}


def test_a_round_ends_after_two_failures_in_a_row_or_at_its_cap():
    """Only a class the table lacks wanted: nothing is chosen, the table stays as it was."""
    cell = ClutterRound(640, 480, seed=0, index=1)
    lacking = [c for c in CLASSES[1:] if c not in [p.model.cls for p in cell.parts]]
    results, seen = _run(cell, PickConfig(classes=lacking[:1], hand=HandShape()), physics=False)
    assert len(results) == 2 and seen[-1][1].ended == "two failures in a row"
    assert all(r.verdict.failure == "no object seen" for r in results)
    assert seen[0][1].after == seen[0][1].before  # nothing taken, nothing moved
    capped, _ = _run(ClutterRound(640, 480, seed=0, index=4, cfg=RoundConfig(max_cycles=1)))
    assert len(capped) == 1 and capped[0].round["ended"] == "cycle cap"


def test_round_summary_sums_the_rounds_with_their_intervals():
    cal = ClutterRound(640, 480, seed=0, index=1).calibration()
    results: list[dict] = []
    robot = SimRobot()
    with robot:
        rounds = run_rounds(TruthPipeline(list(CLASSES), cal), robot, DigitalGripper(robot, 0), rounds=3, pick=PICK,
                            log=CommandLog(None), seed=0, judge=True, echo=lambda line: None, done=results)
    s = round_summary(rounds, results)
    assert s["verdict"] == "physics" and s["rounds"] == 3 and s["picks"] == len(results) == sum(d["picks"] for d in rounds)
    assert s["parts"] == sum(d["parts"] for d in rounds) and s["removed"] == s["success"]  # a success takes its part
    assert s["clearance"] == round(s["removed"] / s["parts"], 4)
    assert s["clearance_ci95"] == [round(v, 4) for v in wilson(s["removed"], s["parts"])]
    assert s["success_ci95"] == [round(v, 4) for v in wilson(s["success"], s["picks"])]
    assert sum(s["failures"].values()) == s["picks"] - s["success"]
    assert sum(d["picks"] for d in s["by_lighting"].values()) == s["picks"]
    assert [d["round"] for d in s["per_round"]] == [1, 2, 3] and sum(s["ended"].values()) == 3
    assert s["time_per_pick_s"] > 0


@pytest.mark.slow
def test_pick_rounds_end_to_end_with_a_recording_per_round(tmp_path):
    proc = run_cli("pick", "--rounds", "2", "--max-cycles", "3", "--verdict", "physics", "--record",
                   str(tmp_path / "run.mcap"), "--log", str(tmp_path / "log.jsonl"))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    r = summary["rounds"]
    assert r["rounds"] == 2 and r["picks"] == summary["cycles"] <= 6 and len(r["per_round"]) == 2
    assert [x["cycle"] for x in summary["results"]] == list(range(1, summary["cycles"] + 1))  # numbered on across rounds
    assert summary["record"] == [str(tmp_path / "run-round001.mcap"), str(tmp_path / "run-round002.mcap")]
    assert "round 1: " in proc.stderr and "round 2: " in proc.stderr
    assert summary["success_ci95"] is not None and summary["physics"]["success_ci95"] is not None


@pytest.mark.parametrize("args, message", [
    (["--rounds", "0"], "--rounds 0: must be at least 1"),
    (["--rounds", "2", "--max-cycles", "-1"], "--max-cycles -1: must be at least 1"),
    (["--rounds", "2", "--max-cycles", "0"], "--max-cycles 0: must be at least 1"),
    (["--max-cycles", "3"], "--max-cycles 3: caps the cycles of a round; it needs --rounds"),
    (["--rounds", "2", "--camera", "realsense"], "--rounds 2: needs the synthetic cell"),
    (["--rounds", "2", "--camera", "synth:3"], "--rounds 2: needs the synthetic cell"),
    (["--rounds", "2", "--cycles", "5"], "--cycles 5 with --rounds 2"),
    (["--rounds", "2", "--overlap"], "--overlap with --rounds"),
    (["--rounds", "2", "--robot", "ur:127.0.0.9"], "--rounds 2: needs --robot sim"),
])
def test_pick_rounds_refuses_bad_input_in_one_line_with_nothing_written(tmp_path, capfd, args, message):
    from edgepick.cli import run

    code = run(["pick", *args, "--record", str(tmp_path / "run.mcap"), "--log", str(tmp_path / "log.jsonl"),
                "--overlay-dir", str(tmp_path / "overlays")])
    out, err = capfd.readouterr()
    assert code == 2 and out == "" and err.count("\n") == 1 and message in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_a_round_cannot_read_its_next_frame_ahead():
    cell = ClutterRound(640, 480, seed=0, index=1)
    robot = SimRobot()
    with pytest.raises(ParameterError, match="overlap=True"):
        run_cycles(Cell(cell, TruthPipeline(list(CLASSES), cell.calibration()), robot, DigitalGripper(robot, 0),
                        CommandLog(None)), cfg=PICK, cycles=2, overlap=True, after=cell.after)
