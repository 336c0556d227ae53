"""`pick --record` and `calibrate collect --record`: a real MCAP file from the synthetic cell, read back
with the `mcap` reader and decoded from the Protobuf schemas stored in it, as a viewer does."""

from __future__ import annotations

import json
import math
import signal
import time

import cv2
import numpy as np
import pytest

pytest.importorskip("mcap_protobuf")

from mcap.reader import make_reader  # noqa: E402
from mcap_protobuf.decoder import DecoderFactory  # noqa: E402

from edgepick.cli.cameras import open_camera  # noqa: E402
from edgepick.robot.messages import robot_pose, rotation  # noqa: E402
from edgepick.runtime.calibration import kabsch, read_pairs  # noqa: E402
from tests.cli.test_signals import _start, _wait_for  # noqa: E402
from tests.conftest import run_cli  # noqa: E402

PER_FRAME = ("/camera/color", "/camera/depth", "/camera/calibration", "/segmentation/labels", "/segmentation/overlay",
             "/camera/annotations", "/grasp/markers", "/grasp/points", "/plan/targets", "/pick/cycle", "/log")


def read(path) -> tuple[dict, dict, list]:
    """(message count per topic from the summary, metadata, every (topic, log_time, message) in file order)."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None, "no summary: the file was not finished"
        counts = {c.topic: summary.statistics.channel_message_counts.get(c.id, 0) for c in summary.channels.values()}
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        messages = [(ch.topic, raw.log_time, msg) for _, ch, raw, msg in reader.iter_decoded_messages(log_time_order=False)]
    return counts, meta, messages


def on(messages: list, topic: str) -> list:
    return [m for t, _, m in messages if t == topic]


def assert_in_time_order(messages: list) -> None:
    """Each topic's log times never go back, and each message's own timestamp is its log time."""
    last: dict[str, int] = {}
    for topic, log_time, message in messages:
        assert log_time >= last.get(topic, 0), topic
        last[topic] = log_time
        if message.DESCRIPTOR.fields_by_name.get("timestamp") is not None:
            assert message.timestamp.ToNanoseconds() == log_time, topic


@pytest.fixture(scope="module")
def picked(tmp_path_factory):
    """Three cycles of `pick` in the synthetic cell with the shipped model, recorded."""
    root = tmp_path_factory.mktemp("rec")
    proc = run_cli("pick", "--cycles", "3", "--record", str(root / "run.mcap"), "--log", str(root / "log.jsonl"))
    assert proc.returncode == 0, proc.stderr
    return root, json.loads(proc.stdout)


def test_pick_records_every_topic_of_each_cycle(picked):
    root, summary = picked
    assert summary["done"] == 3 and summary["record"].endswith("run.mcap")
    assert [p.name for p in root.iterdir() if p.name.startswith(".")] == []  # no partial file left
    counts, meta, messages = read(root / "run.mcap")
    log = [json.loads(line) for line in (root / "log.jsonl").read_text().splitlines()]
    moves = [e for e in log if e["command"] == "moveL"]
    grips = [e for e in log if e["command"] != "moveL"]
    assert {t: counts[t] for t in PER_FRAME} == dict.fromkeys(PER_FRAME, 3)
    assert counts["/robot/tcp_command"] == len(moves) and counts["/robot/gripper"] == len(grips) == 9
    assert counts["/robot/tcp"] == len(log)  # the reported TCP after every step
    assert counts["/tf"] == 3 + len(log)  # base -> camera (and tcp) per frame, base -> tcp per step
    assert sum(counts.values()) == len(messages)
    assert_in_time_order(messages)
    assert json.loads(meta["edgepick"]["classes"])[1:] == ["bearing", "disk", "adapter", "box"]
    assert json.loads(meta["camera"]["fx"]) > 0 and json.loads(meta["camera"]["depth_scale"]) == 0.001

    cycles = on(messages, "/pick/cycle")
    assert [c.cycle for c in cycles] == [1, 2, 3] and all(c.outcome == "done" and c.judged for c in cycles)
    for c, result in zip(cycles, summary["results"], strict=True):
        assert json.loads(c.result_json) == result and c.target == result["target"]
        assert c.inference_ms == result["stage_ms"]["inference"] and c.frame_to_command_ms > 0
        assert c.success == result["verdict"]["success"]
    gripper = on(messages, "/robot/gripper")
    assert [g.command for g in gripper[:3]] == ["open", "grip", "release"] and gripper[1].closed
    for commanded, entry in zip(on(messages, "/robot/tcp_command"), moves, strict=True):
        assert np.allclose(robot_pose(commanded.pose), entry["target"], atol=1e-6)


def test_images_are_the_frames_the_model_saw(picked):
    root, summary = picked
    _, _, messages = read(root / "run.mcap")
    depth, labels = on(messages, "/camera/depth")[0], on(messages, "/segmentation/labels")[0]
    assert (depth.encoding, depth.width, depth.height, depth.step) == ("16UC1", 640, 480, 1280)
    camera = open_camera("synth-cell")
    with camera:
        frame = camera.read()  # the cell's first frame, as `pick` read it
    assert np.array_equal(np.frombuffer(depth.data, np.uint16).reshape(480, 640), frame.depth)
    assert labels.encoding == "mono8" and set(np.unique(np.frombuffer(labels.data, np.uint8))) <= set(range(5))
    assert on(messages, "/camera/color")[0].format == "jpeg"
    k = on(messages, "/camera/calibration")[0].K
    assert list(k) == [frame.intrinsics.fx, 0, frame.intrinsics.cx, 0, frame.intrinsics.fy, frame.intrinsics.cy, 0, 0, 1]


def test_transform_is_the_calibration_and_markers_are_the_plan(picked):
    root, summary = picked
    _, _, messages = read(root / "run.mcap")
    truth = open_camera("synth-cell").calibration()  # the cell's calibration, which `pick` used
    cameras = [tf for m in on(messages, "/tf") for tf in m.transforms if tf.child_frame_id == "camera"]
    assert len(cameras) == 3
    for tf in cameras:
        assert tf.parent_frame_id == "base"
        assert np.allclose(rotation(tf.rotation), truth.R, atol=1e-9)
        assert np.allclose([tf.translation.x, tf.translation.y, tf.translation.z], truth.t, atol=1e-12)
    log = [json.loads(line) for line in (root / "log.jsonl").read_text().splitlines()]
    for update, result in zip(on(messages, "/grasp/markers"), summary["results"], strict=True):
        entities = {e.id: e for e in update.entities}
        targets = [e["target"] for e in log if e["cycle"] == result["cycle"] and e["command"] == "moveL"]
        spheres = [[s.pose.position.x, s.pose.position.y, s.pose.position.z] for s in entities["plan"].spheres]
        assert np.allclose(spheres, [t[:3] for t in targets], atol=1e-12)
        assert np.allclose([robot_pose(s.pose) for s in entities["plan"].spheres], targets, atol=1e-6)
        chosen = [a for a in entities["grasps"].arrows if a.color.g > 0.8]  # the chosen object's arrow is green
        assert len(chosen) == 1 and np.allclose(robot_pose(chosen[0].pose), result["pose_robot"], atol=1e-6)
        cloud = on(messages, "/plan/targets")[result["cycle"] - 1]
        assert cloud.frame_id == "base" and [f.name for f in cloud.fields][:3] == ["x", "y", "z"]
        xyz = np.frombuffer(cloud.data, np.uint8).reshape(-1, cloud.point_stride)[:, :12].copy().view("<f4")
        assert np.allclose(xyz, [t[:3] for t in targets], rtol=0, atol=1e-7)  # float32
        annotations = on(messages, "/camera/annotations")[result["cycle"] - 1]
        assert any(math.dist((c.position.x, c.position.y), result["pixel"]) < 1e-9 for c in annotations.circles)


def test_the_readme_pictures_draw_from_a_recording(picked):
    """benchmarks/recording_views.py's panels (the README's picture) come from a recording's messages."""
    import sys

    from tests.conftest import REPO

    sys.path.insert(0, str(REPO / "benchmarks"))
    from recording_views import panels

    root, summary = picked
    panels(root / "run.mcap", 2, root / "panels.png")
    picture = cv2.imread(str(root / "panels.png"))
    assert picture is not None and picture.shape[1] > 900 and picture.std() > 20


def test_replay_chooses_what_the_run_chose(picked):
    root, summary = picked
    proc = run_cli("replay", str(root / "run.mcap"))
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["cycles"] == 3 and out["same"] == 3 and out["labels"] == "recorded"
    for r, result in zip(out["results"], summary["results"], strict=True):
        assert r["replayed"]["target"] == result["target"] and r["replayed"]["pixel"] == result["pixel"]
        assert r["replayed"]["pose_robot"] == result["pose_robot"] and r["shift_px"] == 0


def test_replay_with_a_model_segments_the_recorded_frames(picked):
    root, summary = picked
    proc = run_cli("replay", str(root / "run.mcap"), "--model", summary["model"])
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["labels"] == "model" and out["same"] == 3  # JPEG noise moves a centroid by hundredths of a pixel
    assert all(r["shift_px"] < 0.5 for r in out["results"])


def test_a_clutter_removal_round_is_one_recording_that_replay_steps_through(tmp_path):
    """`pick --rounds 1 --record`: one file for the round; per cycle the table before the pick (at the frame's
    time) and where the rest settled (after the cycle's commands), as /round/scene and as solids on
    /scene/objects; replay steps through the round's picks and chooses what the run chose."""
    pytest.importorskip("mujoco")
    proc = run_cli("pick", "--rounds", "1", "--max-cycles", "4", "--verdict", "physics", "--record",
                   str(tmp_path / "run.mcap"), "--log", str(tmp_path / "log.jsonl"))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    path = tmp_path / "run-round001.mcap"
    assert summary["record"] == [str(path)] and not (tmp_path / "run.mcap").exists()
    counts, meta, messages = read(path)
    cycles = summary["cycles"]
    assert counts["/round/scene"] == counts["/scene/objects"] == 2 * cycles and counts["/pick/cycle"] == cycles
    assert json.loads(meta["edgepick"]["round"])["round"] == 1
    assert_in_time_order(messages)
    scenes = on(messages, "/round/scene")
    assert [m.stage for m in scenes] == ["before", "settled"] * cycles
    for (before, settled), result in zip(zip(scenes[::2], scenes[1::2]), summary["results"], strict=True):
        parts, rest = json.loads(before.objects_json), json.loads(settled.objects_json)
        removed = result["round"]["removed"]
        assert (settled.removed if settled.removed >= 0 else None) == removed
        assert len(rest) == len(parts) - (removed is not None) - len(result["round"]["fell"])
        assert removed not in [o["id"] for o in rest]
    assert len(on(messages, "/camera/color")) == cycles
    solids = on(messages, "/scene/objects")[0].entities[0]
    assert len(solids.cubes) + len(solids.cylinders) == len(json.loads(scenes[0].objects_json))
    replayed = run_cli("replay", str(path))
    assert replayed.returncode == 0, replayed.stderr
    out = json.loads(replayed.stdout)
    assert out["cycles"] == cycles and out["same"] == cycles
    assert [r["round"]["pick"] for r in out["results"]] == list(range(1, cycles + 1))
    assert out["results"][0]["round"]["parts_before"] == summary["rounds"]["parts"]
    assert "(round 1, pick 1: " in replayed.stderr


@pytest.mark.parametrize("target", ["proc", "under-a-file", "a-folder"])
def test_an_unwritable_record_path_fails_before_the_first_frame(tmp_path, target):
    (tmp_path / "file").write_text("")
    path = {"proc": "/proc/run.mcap", "under-a-file": str(tmp_path / "file" / "run.mcap"), "a-folder": str(tmp_path)}
    proc = run_cli("pick", "--cycles", "1", "--record", path[target], "--log", str(tmp_path / "log.jsonl"))
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "--record" in proc.stderr, proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]  # no log, no partial recording


def test_a_run_that_ends_before_its_first_frame_leaves_no_recording(tmp_path):
    proc = run_cli("pick", "--gripper", "rg2:127.0.0.1", "--record", str(tmp_path / "run.mcap"),
                   "--log", str(tmp_path / "log.jsonl"))
    assert proc.returncode == 3 and "cannot reach the RG2" in proc.stderr, proc.stderr
    assert json.loads(proc.stdout)["record"] is None and list(tmp_path.iterdir()) == []


def test_a_recording_stopped_by_ctrl_c_is_a_readable_file(tmp_path):
    out = tmp_path / "run.mcap"
    proc = _start("pick", "--cycles", "500", "--record", str(out), "--log", str(tmp_path / "log.jsonl"))
    lines: list[str] = []

    def two_cycles() -> bool:
        lines.append(proc.stderr.readline())
        return sum(line.startswith("cycle ") for line in lines) >= 2

    _wait_for(proc, two_cycles, "two cycles")
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=60) == 130
    assert "interrupted" in proc.stderr.read()
    counts, _, messages = read(out)
    assert 2 <= counts["/pick/cycle"] < 500 and counts["/camera/color"] >= counts["/pick/cycle"]
    assert_in_time_order(messages)
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_a_recording_stopped_by_a_robot_halt_is_a_readable_file(tmp_path):
    from edgepick.reference import reference_model
    from edgepick.robot.grippers import DigitalGripper
    from edgepick.robot.loop import Cell, run_cycles
    from edgepick.robot.pick import CommandLog, PickConfig
    from edgepick.robot.recording import Recorder, pick_metadata
    from edgepick.runtime.grasp_config import GraspConfig
    from edgepick.runtime.pipeline import Pipeline
    from edgepick.runtime.session import Segmenter
    from edgepick.sim.robot import SimRobot

    camera = open_camera("synth-cell")
    pipeline = Pipeline(Segmenter(str(reference_model())), camera.calibration())
    robot = SimRobot(protective_stop_on=3)  # the third moveL: the descent of cycle 1 stops half-way
    cfg = PickConfig()
    with Recorder(tmp_path / "halt.mcap", pick_metadata("m", pipeline.classes, cfg, GraspConfig(), robot.envelope),
                  pipeline.calib) as recorder, camera, robot:
        cell = Cell(camera, pipeline, robot, DigitalGripper(robot, 0), CommandLog(None), camera.calibration(), recorder)
        results = run_cycles(cell, cfg=cfg, cycles=5, echo=lambda line: None)
    assert len(results) == 1 and results[0].outcome == "stopped"
    counts, _, messages = read(tmp_path / "halt.mcap")
    assert counts["/pick/cycle"] == 1 and counts["/robot/tcp_command"] == 3  # approach, descent, the halted lift
    lift, halted_at = on(messages, "/robot/tcp_command")[-1], on(messages, "/robot/tcp")[-1]
    descent = on(messages, "/robot/tcp_command")[1]
    assert np.allclose([halted_at.pose.position.z], [(descent.pose.position.z + lift.pose.position.z) / 2])
    cycle = on(messages, "/pick/cycle")[0]
    assert cycle.outcome == "stopped" and "protective stop" in cycle.reason and not cycle.success
    assert on(messages, "/log")[0].level == 3  # WARNING


def test_calibrate_collect_records_each_position_and_the_fit(tmp_path):
    proc = run_cli("calibrate", "collect", "--out", str(tmp_path / "pairs.csv"), "--settle", "0", "--poses", "8",
                   "--record", str(tmp_path / "collect.mcap"))
    assert proc.returncode == 0, proc.stderr
    counts, meta, messages = read(tmp_path / "collect.mcap")
    assert meta["edgepick"]["command"] == "calibrate collect"
    assert {t: counts[t] for t in ("/camera/color", "/camera/depth", "/robot/tcp_command", "/robot/tcp",
                                   "/calibration/position")} == dict.fromkeys(
        ("/camera/color", "/camera/depth", "/robot/tcp_command", "/robot/tcp", "/calibration/position"), 8)
    assert_in_time_order(messages)
    camera_points, robot_points = read_pairs(tmp_path / "pairs.csv")
    seen = [p for p in on(messages, "/calibration/position") if p.seen]
    recorded_camera, recorded_robot = np.array([p.camera_point for p in seen]), np.array([p.robot_point for p in seen])
    assert np.allclose(recorded_camera, camera_points, rtol=0, atol=1e-6)  # the CSV's precision
    assert np.allclose(recorded_robot, robot_points, rtol=0, atol=1e-6)
    fit = kabsch(recorded_camera, recorded_robot)
    (tf,) = [tf for m in on(messages, "/tf") for tf in m.transforms]
    assert np.allclose(rotation(tf.rotation), fit.R, atol=1e-9)
    assert np.allclose([tf.translation.x, tf.translation.y, tf.translation.z], fit.t, atol=1e-12)
    assert time.time_ns() - on(messages, "/log")[0].timestamp.ToNanoseconds() < 600e9
    proc = run_cli("replay", str(tmp_path / "collect.mcap"))
    assert proc.returncode == 2 and "a `calibrate collect` recording" in proc.stderr


def test_replay_refuses_what_is_not_a_pick_recording(tmp_path):
    (tmp_path / "log.jsonl").write_text('{"t": 1}\n')
    for path, words in ((tmp_path / "log.jsonl", "not a readable MCAP recording"), (tmp_path / "none.mcap", "no such")):
        proc = run_cli("replay", str(path))
        assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and words in proc.stderr, proc.stderr


@pytest.mark.parametrize("module", ["mcap", "mcap_protobuf", "foxglove_schemas_protobuf"])
def test_without_the_record_extra_record_and_replay_say_what_to_install(tmp_path, module):
    """A laptop's base install: `--record` and `replay` refuse in one line, before the first frame."""
    import subprocess
    import sys

    from tests.conftest import REPO

    hide = f"import sys; sys.modules[{module!r}] = None; from edgepick.cli import run; sys.exit(run(sys.argv[1:]))"
    (tmp_path / "r.mcap").write_bytes(b"")  # what replay is given; pick would write over it
    for args in (["pick", "--record", str(tmp_path / "r.mcap"), "--log", str(tmp_path / "log.jsonl")],
                 ["replay", str(tmp_path / "r.mcap")]):
        proc = subprocess.run([sys.executable, "-c", hide, *args], capture_output=True, text=True, cwd=REPO)
        assert proc.returncode == 2 and proc.stderr.count("\n") == 1, proc.stderr
        assert "pip install 'edgepick[record]'" in proc.stderr and f"({module} is not installed)" in proc.stderr
        assert "cycle" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.mcap"] and (tmp_path / "r.mcap").stat().st_size == 0
