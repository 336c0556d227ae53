"""The real ur_rtde client (through URRobot) against the loopback UR controller peer."""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

pytest.importorskip("rtde_control")

from edgepick.errors import ConfigError  # noqa: E402
from edgepick.robot.base import RobotError, RobotHalted, RobotUnreachable  # noqa: E402
from edgepick.robot.envelope import SafetyError  # noqa: E402
from edgepick.robot.grippers import DigitalGripper  # noqa: E402
from edgepick.robot.pick import CommandLog, PickConfig, choose_target, execute, plan_pick  # noqa: E402
from edgepick.robot.ur import URRobot  # noqa: E402
from tests.conftest import REPO, make_grasp, worker_index  # noqa: E402

DOWN = [math.pi, 0.0, 0.0]
RECORD = make_grasp("box", [0.3, -0.05, 0.06, *DOWN])
_next = [20 + os.getpid() % 200]


@pytest.fixture()
def peer(tmp_path):
    """Start a controller peer on a fresh loopback address; yields (host, log reader, options setter)."""
    procs = []

    def start(*options: str) -> tuple[str, callable]:
        _next[0] = 20 + (_next[0] - 19) % 230
        host = f"127.{1 + worker_index()}.0.{_next[0]}"  # a block of addresses per xdist worker
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
    # the safety-limit query, moveL, moveJ ... stop script
    assert commands(log())[:3] == [36, 3, 1] and commands(log())[-1] == 255


@pytest.mark.slow
def test_a_full_pick_cycle_on_the_controller(peer, tmp_path):
    host, log = peer()
    plan = plan_pick(RECORD, PickConfig())
    with URRobot(host) as robot:
        assert execute(plan, robot, DigitalGripper(robot, 0), CommandLog(tmp_path / "c.jsonl"), 1, PickConfig()) is None
        assert math.dist(robot.tcp_pose()[:3], PickConfig().home_pose[:3]) < 0.01
    assert commands(log()).count(3) == 7  # the seven moveL steps of the plan


@pytest.mark.slow
@pytest.mark.parametrize("fault, word", [("--protective-stop-on-move", "protective stop"), ("--drop-on-move", "lost")])
def test_a_stop_mid_move_ends_the_cycle_and_nothing_more_is_sent(peer, fault, word):
    host, log = peer(fault, "2")  # the descent (second motion) stops halfway
    plan = plan_pick(RECORD, PickConfig())
    t0 = time.monotonic()
    with URRobot(host, command_margin_s=3.0) as robot:
        reason = execute(plan, robot, DigitalGripper(robot, 0), CommandLog(None), 1, PickConfig())
        assert reason and word in reason
        if word == "protective stop":  # in the controller's own words too
            assert "protective stop (controller safety mode PROTECTIVE_STOP)" in reason
        assert robot.sent == ["moveL", "setDigitalOut", "moveL"]
        with pytest.raises(RobotHalted):
            robot.move_l([0.3, 0.0, 0.2, *DOWN])
    assert time.monotonic() - t0 < 30
    entries = log()
    event = next(i for i, e in enumerate(entries) if e.get("event") in ("protective_stop", "link_dropped"))
    assert [e for e in entries[event:] if "cmd" in e] == []  # nothing reached the controller after the stop
    assert commands(entries) == [36, 3, 36, 3]  # each moveL after its safety-limit query


def test_out_of_envelope_target_is_refused_before_anything_is_sent(peer):
    host, log = peer()
    with URRobot(host) as robot:
        with pytest.raises(SafetyError, match="below the table"):
            robot.move_l([0.3, 0.0, -0.02, *DOWN])
        with pytest.raises(SafetyError, match="reach"):
            robot.move_l([0.45, 0.2, 0.05, *DOWN])
        assert robot.sent == []
    assert commands(log()) == [33, 255]  # only the exit: stopL, then stop the control script


def test_a_pose_outside_the_controllers_safety_limits_is_refused_before_the_move(peer):
    """ur_rtde's isPoseWithinSafetyLimits, asked before each moveL and for a pick's whole plan:
    a target the controller refuses is not sent, and a plan with one is not started."""
    host, log = peer("--refuse-poses-beyond-x", "0.28")
    with URRobot(host) as robot:
        with pytest.raises(SafetyError, match=r"refused moveL: \(0.300, 0.000, 0.200\) is outside the controller's "
                                              "safety limits"):
            robot.move_l([0.3, 0.0, 0.2, *DOWN])
        assert robot.sent == [] and not robot.halted
        record, plan, note = choose_target([RECORD], robot.envelope, PickConfig(), robot.tcp_pose(),
                                           robot.limits_reason)
        assert record is None and "approach above the object: (0.300, -0.050, 0.140) is outside the controller's " \
            "safety limits" in note
        robot.move_l([0.25, 0.0, 0.2, *DOWN])  # within the limits: carried out
    assert 3 in commands(log()) and commands(log())[:2] == [36, 36]  # refused target: no moveL after its query
    assert [e["values"][0] for e in log() if e.get("cmd") == 3] == [0.25]


def test_refused_connection_is_a_clear_error():
    t0 = time.monotonic()
    with pytest.raises(RobotUnreachable, match="cannot reach the robot at 127.0.0.254: .*Could not connect"):
        URRobot("127.0.0.254").connect()
    assert time.monotonic() - t0 < 20


def test_a_worker_that_dies_while_connecting_is_noticed_at_once():
    """The ur_rtde worker killed while it waits on a controller that accepts and never answers: an
    end of the pipe, not the 15 s connect timeout."""
    host = f"127.{1 + worker_index()}.1.{20 + (os.getpid() + 7) % 230}"
    silent = socket.socket()
    silent.bind((host, 30004))
    silent.listen(4)  # accepts the RTDE connection, never replies
    robot, failed = URRobot(host, connect_timeout_s=15.0), []

    def connect() -> None:
        try:
            robot.connect()
        except RobotError as exc:
            failed.append(exc)

    thread = threading.Thread(target=connect)
    thread.start()
    try:
        deadline = time.monotonic() + 10
        while (robot.proc is None or robot.proc.pid is None) and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(1.0)  # the worker is waiting on the silent controller
        t0 = time.monotonic()
        os.kill(robot.proc.pid, signal.SIGKILL)
        thread.join(20)
        assert time.monotonic() - t0 < 3
    finally:
        silent.close()
    (exc,) = failed
    assert isinstance(exc, RobotUnreachable)
    assert str(exc).startswith(f"cannot reach the robot at {host}: the ur_rtde worker stopped")


def test_an_unwritable_robot_log_is_one_line_about_the_file(tmp_path, capfd):
    """ur_rtde's output file cannot be opened (here: it is a folder): said at once, in one line that
    names debug_log (the command line's --robot-log), with no traceback from the worker and no attempt to
    reach the robot."""
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=f"debug_log='{tmp_path}' cannot be written: Is a directory"):
        URRobot("127.0.0.254", debug_log=str(tmp_path)).connect()
    assert time.monotonic() - t0 < 5
    assert "Traceback" not in capfd.readouterr().err


def test_the_robot_log_folder_is_made_when_missing(peer, tmp_path):
    host, _ = peer()
    debug_log = tmp_path / "logs" / "today" / "rtde.log"
    with URRobot(host, debug_log=str(debug_log)) as robot:
        robot.move_l([0.25, 0.0, 0.2, *DOWN])
    assert debug_log.is_file()


@pytest.mark.slow
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


@pytest.mark.slow
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
    assert json.loads(out)["cycles"] == 0 and "cannot reach the robot at 127.0.0.254" in json.loads(out)["halted"]
    _only_edgepick_lines(err)
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "picks.jsonl").exists()
    assert err.startswith("edgepick: error: cannot reach the robot at 127.0.0.254: ")  # it never connected


def test_an_rg2_that_cannot_be_reached_stops_pick_before_the_arm_is_sent_anything(peer, tmp_path, capfd):
    pytest.importorskip("onnx")
    from edgepick.cli import run
    from tests.robot.test_loop import CALIB, capture
    from tests.runtime.test_pipeline import red_model

    host, log = peer()
    cam = capture(tmp_path / "cap", [(160, 120)])
    (tmp_path / "calib.json").write_text(json.dumps(CALIB))
    code = run(["pick", "--model", str(red_model(tmp_path / "m.onnx")), "--camera", f"dir:{cam}", "--calib",
                str(tmp_path / "calib.json"), "--robot", f"ur:{host}", "--execute", "--gripper", "rg2:rg2.invalid",
                "--log", str(tmp_path / "picks.jsonl")])
    out, err = capfd.readouterr()
    assert code == 3, err
    assert err.splitlines() == [err.strip()] and err.startswith("edgepick: error: cannot reach the RG2 gripper at "
                                                                "rg2.invalid:41414: ")
    assert json.loads(out)["halted"].startswith("cannot reach the RG2 gripper") and json.loads(out)["cycles"] == 0
    assert [e for e in log() if "cmd" in e or e.get("event") == "script"] == []  # the arm was sent nothing


@pytest.mark.slow
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
