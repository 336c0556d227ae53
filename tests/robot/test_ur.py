"""The real ur_rtde client (through URRobot) against the loopback UR controller peer."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import pytest

pytest.importorskip("rtde_control")

from edgepick.robot.base import RobotError, RobotHalted  # noqa: E402
from edgepick.robot.envelope import SafetyError  # noqa: E402
from edgepick.robot.grippers import DigitalGripper  # noqa: E402
from edgepick.robot.pick import CommandLog, PickConfig, execute, plan_pick  # noqa: E402
from edgepick.robot.ur import URRobot  # noqa: E402
from tests.conftest import REPO  # noqa: E402

DOWN = [math.pi, 0.0, 0.0]
RECORD = {"class": "box", "area_px": 900, "depth_m": 0.62, "pose_robot": [0.3, -0.05, 0.06, *DOWN]}
_next = [20 + os.getpid() % 200]


@pytest.fixture()
def peer(tmp_path):
    """Start a controller peer on a fresh 127.0.0.N; yields (host, log reader, options setter)."""
    procs = []

    def start(*options: str) -> tuple[str, callable]:
        _next[0] = 20 + (_next[0] - 19) % 230
        host = f"127.0.0.{_next[0]}"
        log = tmp_path / f"peer-{host}.jsonl"
        proc = subprocess.Popen([sys.executable, "-m", "edgepick.sim.ur_peer", "--host", host, "--lifetime", "90",
                                 "--time-scale", "0.2", "--log", str(log), *options], cwd=REPO,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        procs.append(proc)
        assert "ready" in proc.stdout.readline()

        def read_log() -> list[dict]:
            return [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
        return host, read_log

    start.procs = procs
    yield start
    for p in procs:
        p.kill()
        p.wait(10)


def commands(log: list[dict]) -> list[int]:
    return [e["cmd"] for e in log if "cmd" in e]


def test_connect_move_and_digital_output(peer):
    host, log = peer()
    with URRobot(host) as robot:
        robot.move_l([0.3, 0.0, 0.2, *DOWN], 0.25, 1.2)
        assert math.dist(robot.tcp_pose()[:3], [0.3, 0.0, 0.2]) < 0.01
        robot.move_j([0.0, -1.2, 1.2, -1.57, -1.57, 0.0], 1.0, 1.4)
        gripper = DigitalGripper(robot, 1, tool=True)
        gripper.grip()
        assert any(e.get("event") == "digital_out" and e["bits"] == 1 << 17 for e in log())
        gripper.release()
    assert commands(log())[:2] == [3, 1] and commands(log())[-1] == 255  # moveL, moveJ ... stop script


def test_a_full_pick_cycle_on_the_controller(peer, tmp_path):
    host, log = peer()
    plan = plan_pick(RECORD, PickConfig())
    with URRobot(host) as robot:
        assert execute(plan, robot, DigitalGripper(robot, 0), CommandLog(tmp_path / "c.jsonl"), 1, PickConfig()) is None
        assert math.dist(robot.tcp_pose()[:3], PickConfig().home_pose[:3]) < 0.01
    assert commands(log()).count(3) == 7  # the seven moveL steps of the plan


@pytest.mark.parametrize("fault, word", [("--protective-stop-on-move", "protective stop"), ("--drop-on-move", "lost")])
def test_a_stop_mid_move_ends_the_cycle_and_nothing_more_is_sent(peer, fault, word):
    host, log = peer(fault, "2")  # the descent (second motion) stops halfway
    plan = plan_pick(RECORD, PickConfig())
    t0 = time.monotonic()
    with URRobot(host, command_margin_s=3.0) as robot:
        reason = execute(plan, robot, DigitalGripper(robot, 0), CommandLog(None), 1, PickConfig())
        assert reason and word in reason
        assert robot.sent == ["moveL", "setDigitalOut", "moveL"]
        with pytest.raises(RobotHalted):
            robot.move_l([0.3, 0.0, 0.2, *DOWN])
    assert time.monotonic() - t0 < 30
    entries = log()
    event = next(i for i, e in enumerate(entries) if e.get("event") in ("protective_stop", "link_dropped"))
    assert [e for e in entries[event:] if "cmd" in e] == []  # nothing reached the controller after the stop
    assert commands(entries) == [3, 3]


def test_out_of_envelope_target_is_refused_before_anything_is_sent(peer):
    host, log = peer()
    with URRobot(host) as robot:
        with pytest.raises(SafetyError, match="below the table"):
            robot.move_l([0.3, 0.0, -0.02, *DOWN])
        with pytest.raises(SafetyError, match="reach"):
            robot.move_l([0.45, 0.2, 0.05, *DOWN])
        assert robot.sent == []
    assert commands(log()) == [33, 255]  # only the exit: stopL, then stop the control script


def test_refused_connection_is_a_clear_error():
    t0 = time.monotonic()
    with pytest.raises(RobotError, match="cannot connect to the UR controller at 127.0.0.254"):
        URRobot("127.0.0.254").connect()
    assert time.monotonic() - t0 < 20


def test_pick_command_executes_on_the_controller(peer, tmp_path):
    pytest.importorskip("onnx")
    from tests.conftest import run_cli
    from tests.robot.test_loop import CALIB, capture
    from tests.runtime.test_pipeline import red_model

    host, log = peer()
    cam = capture(tmp_path / "cap", [(160, 120)])
    (tmp_path / "calib.json").write_text(json.dumps(CALIB))
    proc = run_cli("pick", "--model", str(red_model(tmp_path / "m.onnx")), "--camera", f"dir:{cam}", "--calib",
                   str(tmp_path / "calib.json"), "--robot", f"ur:{host}", "--execute", "--log", str(tmp_path / "l.jsonl"))
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["done"] == 1
    assert commands(log()).count(3) == 7


def _pick_cli(tmp_path, host: str, *extra: str) -> subprocess.Popen:
    from tests.robot.test_loop import CALIB, capture
    from tests.runtime.test_pipeline import red_model

    cam = capture(tmp_path / "cap", [(160, 120)])
    (tmp_path / "calib.json").write_text(json.dumps(CALIB))
    return subprocess.Popen([sys.executable, "-m", "edgepick", "pick", "--model", str(red_model(tmp_path / "m.onnx")),
                             "--camera", f"dir:{cam}", "--calib", str(tmp_path / "calib.json"), "--robot", f"ur:{host}",
                             "--execute", "--log", str(tmp_path / "picks.jsonl"), *extra],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _only_edgepick_lines(stderr: str) -> None:
    lines = stderr.strip().splitlines()
    assert lines and lines[-1].startswith("edgepick: error:"), stderr
    assert all(line.startswith(("cycle ", "edgepick: ")) for line in lines), stderr  # nothing from ur_rtde


@pytest.mark.parametrize("signal_name", ["SIGKILL", "SIGSTOP"])
def test_a_controller_killed_or_frozen_mid_move_ends_pick_with_exit_3(peer, tmp_path, signal_name):
    pytest.importorskip("onnx")
    import signal

    host, log = peer("--time-scale", "1.0")  # moves at real speed: ~1 s for the approach
    proc = _pick_cli(tmp_path, host, "--robot-log", str(tmp_path / "rtde.log"))
    deadline = time.monotonic() + 30
    while 3 not in commands(log()) and time.monotonic() < deadline:
        time.sleep(0.01)
    peer_proc = peer.procs[-1]
    os.kill(peer_proc.pid, getattr(signal, signal_name))  # the controller dies or freezes mid-moveL
    t0 = time.monotonic()
    try:
        out, err = proc.communicate(timeout=30)
    finally:
        os.kill(peer_proc.pid, signal.SIGKILL)
    assert time.monotonic() - t0 < 30
    assert proc.returncode == 3, err
    summary = json.loads(out)  # stdout is the JSON summary alone
    assert summary["halted"] and summary["results"][0]["outcome"] == "stopped"
    _only_edgepick_lines(err)
    assert "robot halted" in err.splitlines()[-1]


def test_nothing_listening_is_exit_3_with_no_log_left(tmp_path):
    pytest.importorskip("onnx")
    proc = _pick_cli(tmp_path, "127.0.0.254")
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 3, err
    assert json.loads(out)["cycles"] == 0 and "cannot connect" in json.loads(out)["halted"]
    _only_edgepick_lines(err)
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "picks.jsonl").exists()


def test_calibrate_collect_through_ur_rtde_on_the_controller(peer, tmp_path):
    """The same collection against the loopback controller: real ur_rtde client, the synthetic
    camera seeing the marker where the controller reports the TCP."""
    from tests.conftest import run_cli

    host, log = peer()
    proc = run_cli("calibrate", "collect", "--robot", f"ur:{host}", "--camera", "synth-cell", "--poses", "6",
                   "--speed", "0.25", "--settle", "0", "--out", str(tmp_path / "pairs.csv"), "--execute")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["pairs"] == 6 and (tmp_path / "pairs.csv").is_file()
    assert commands(log()).count(3) == 7  # six positions and the way back, all moveL
