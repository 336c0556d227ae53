"""`edgepick pick`: the pick-and-place loop on the command line (click only; no torch)."""

from __future__ import annotations

import contextlib
import json
import math
import signal
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import click

from edgepick.cli.cell import CheckedPick, PickRequest, check_gripper, check_robot, open_cell, pick_recorder
from edgepick.cli.options import choice, default_of, parse_size, round_config
from edgepick.errors import ConfigError
from edgepick.files import check_output, output_dir
from edgepick.robot.envelope import Envelope
from edgepick.robot.pick import Choose, PickConfig
from edgepick.robot.verdict import VerdictRule
from edgepick.runtime.engine import Engine

if TYPE_CHECKING:
    from edgepick.robot.cycle import CycleResult
    from edgepick.robot.loop import Cell
    from edgepick.sim.clutter import RoundConfig


@click.command()
@click.option("--model", default=None, type=click.Path(dir_okay=False),
              help="Segmentation ONNX (docs/contracts.md#onnx-model) [default with a synthetic camera: the shipped "
                   "reference model, edgepick/reference/MODEL_CARD.md; a real camera needs a model of its own].")
@click.option("--camera", default="synth-cell", show_default=True,
              help="synth-cell[:SEED] (synthetic camera over a calibrated cell), synth, dir:PATH or realsense[:SERIAL].")
@click.option("--robot", "robot_spec", default="sim", show_default=True, help="sim, or ur:HOST for a UR3 over ur_rtde.")
@click.option("--calib", default=None, type=click.Path(dir_okay=False),
              help="calib.json (docs/contracts.md#intrinsics-and-calibration) [default for synth-cell: the cell's "
                   "own calibration].")
@click.option("--gripper", default="digital:0", show_default=True, help="digital:N, tool:N or rg2[:HOST].")
@click.option("--execute", is_flag=True, help="Move a real arm (--robot ur:HOST). Without it the plan is only printed.")
@click.option("--cycles", default=1, show_default=True, help="Pick cycles to run, each on a fresh scene.")
@click.option("--rounds", default=None, type=int,
              help="Instead: clutter removal in the synthetic cell (the [sim] extra), N rounds. A round lays out 4-10 "
                   "parts (piles allowed) once and picks from that table until it is empty, two cycles in a row "
                   "fail, or --max-cycles: a part leaves the table when its grasp succeeded (the physics check's "
                   "verdict with --verdict physics|both), the rest settle in MuJoCo and the next frame shows where "
                   "they came to rest. The summary gains \"rounds\": grasp success, clearance, picks per part, "
                   "failures and time per pick, per round and per light condition, with 95% intervals "
                   "(docs/contracts.md#clutter-removal-rounds). --record writes one file per round.")
@click.option("--max-cycles", default=None, type=int,
              help="--rounds: cycles per round at most [default: none; the two-failures rule ends a round].")
@click.option("--class", "classes", multiple=True, help="Only pick these classes (repeatable).")
@click.option("--choose", default=default_of(PickConfig, "choose"), show_default=True, type=choice(Choose))
@click.option("--speed", default=default_of(PickConfig, "speed"), show_default=True,
              help=f"moveL speed, m/s, in (0, {default_of(Envelope, 'max_speed')}]: the envelope's cap; anything else "
                   "is refused up front.")
@click.option("--acc", default=default_of(PickConfig, "acc"), show_default=True,
              help=f"moveL acceleration, m/s^2, in (0, {default_of(Envelope, 'max_acc')}]: the envelope's cap; "
                   "anything else is refused up front.")
@click.option("--log", "log_path", default="picks.jsonl", show_default=True, type=click.Path(dir_okay=False),
              help="JSON-lines log of every command (appended; created at the first entry).")
@click.option("--robot-log", default=None, type=click.Path(dir_okay=False),
              help="--robot ur:HOST: write ur_rtde's own messages (reconnects, socket errors) here [default: "
                   "discarded; edgepick reports a failure itself].")
@click.option("--overlay-dir", default=None, type=click.Path(file_okay=False), help="Write an overlay PNG per cycle.")
@click.option("--record", "record_path", default=None, type=click.Path(dir_okay=False),
              help="Record every cycle to this MCAP file for Foxglove or Rerun (the [record] extra): colour, depth, "
                   "labels, intrinsics, the camera -> base transform, grasp markers, commanded and reported TCP "
                   "poses, gripper, verdict and timings (docs/contracts.md#recordings); `edgepick replay` reruns "
                   "the grasp step on it. Written after each cycle's commands, on a worker thread.")
@click.option("--verdict", default=VerdictRule.GEOMETRIC.value, show_default=True, type=choice(VerdictRule),
              help="Synthetic cell: the verdict on each cycle: the geometric rule (docs/contracts.md#grasp-success), or "
                   "also the physics check (the grasp carried out in MuJoCo after the cycle's commands: the [sim] "
                   "extra; physics and both print both).")
@click.option("--threads", default=2, show_default=True, help="Inference threads.")
@click.option("--engine", default=Engine.ONNXRUNTIME.value, show_default=True, type=choice(Engine),
              help="Inference engine (openvino: the [peers] extra; auto: the faster one here, measured once per "
                   "model and cached in ~/.cache/edgepick).")
@click.option("--size", default="640x480", show_default=True, help="Camera frame size, WIDTHxHEIGHT.")
@click.option("--overlap", is_flag=True,
              help="Read and segment the next frame while the arm places the object and returns home, so the arm "
                   "waits only for the plan (each cycle reports frame_to_frame_ms and arm_wait_ms). Only where the "
                   "camera sees neither the arm nor the part it holds once the arm is above the place pose.")
def pick(**options: Any) -> None:
    """Pick and place: camera -> segmentation -> grasp records -> target -> robot.

    Each cycle chooses the largest (or closest) object whose whole plan passes the safety
    envelope, then: approach above -> open -> descend -> grip -> lift -> place -> release ->
    home. --robot sim runs against the in-process SimRobot; a real UR3 (--robot ur:HOST)
    moves only with --execute, otherwise the plan is printed and nothing is sent. Every
    target and the straight path to it are checked against the envelope before the first
    command. The JSON summary goes to stdout; if the robot halts (protective or emergency
    stop, lost link) or cannot be reached, it says so and the exit status is 3.
    """
    from edgepick.robot.base import RobotHalted, RobotUnreachable

    request = PickRequest(**options)
    given = click.get_current_context().get_parameter_source("cycles") == click.core.ParameterSource.COMMANDLINE
    checked = _check_request(request, cycles_given=given)
    cell, cfg, model = open_cell(request, checked)
    results: list[CycleResult] = []  # filled cycle by cycle: still there when an interrupt ends the loop
    described: list[dict] = []  # --rounds: each round as it ends
    halted, unreachable, interrupt = _drive(cell, request, checked.rounds, cfg, model, results, described)
    summary = _summary(model, results, described, request.rounds, halted, interrupt, cell.log, request.log_path,
                       request.record_path)
    _print_summary(summary, interrupted=interrupt is not None)
    if interrupt is not None:  # the command line says so in one line and exits 128 + the signal
        raise interrupt
    if halted:  # the command line prints the one error line and exits 3
        if unreachable:
            raise RobotUnreachable(halted)
        done_of = summary["cycles"] if request.rounds else request.cycles
        raise RobotHalted(f"robot halted: {halted} ({summary['done']} of {done_of} cycles done)")


def _check_request(request: PickRequest, cycles_given: bool) -> CheckedPick:
    """Every option checked before anything starts (a camera opened, a robot reached): the counts,
    the motion and robot, the gripper, the output paths, and the extras the run will need."""
    paths = (request.model, request.calib)
    cycles = request.cycles if cycles_given else None
    rounds = _check_rounds(request.rounds, request.max_cycles, cycles, request.camera, request.robot_spec, request.overlap)
    kind, host = _check_motion(request.cycles, request.speed, request.acc, request.robot_spec)
    gripper_spec = check_gripper(request.gripper, host or None)
    check_output(request.log_path, "--log", inputs=paths)
    if request.overlay_dir is not None:
        check_output(request.overlay_dir, "--overlay-dir", kind="dir", inputs=paths, reuse="pick")
    if request.robot_log is not None:
        check_output(request.robot_log, "--robot-log", inputs=(*paths, request.log_path))
    if request.record_path is not None:
        for path in round_records(request.record_path, request.rounds):
            check_output(path, "--record", inputs=(*paths, request.log_path, request.robot_log))
        from edgepick.robot.messages import schemas

        schemas()  # the [record] extra, before anything starts
    if rounds is not None:
        from edgepick.sim.physics import require_mujoco

        require_mujoco()  # the [sim] extra settles the rounds' parts, before anything starts
    if request.verdict != VerdictRule.GEOMETRIC:
        if not request.camera.startswith("synth-cell"):
            raise ConfigError(f"--verdict {request.verdict}: needs the synthetic cell (--camera synth-cell), whose "
                              "scenes know their objects")
        from edgepick.sim.physics import require_mujoco

        require_mujoco()  # the [sim] extra, before anything starts
    return CheckedPick(rounds, kind, host, gripper_spec, parse_size(request.size))


def _drive(cell: Cell, request: PickRequest, rounds: RoundConfig | None, cfg: PickConfig, model: str,
           results: list[CycleResult], described: list[dict]) -> tuple[str | None, bool, KeyboardInterrupt | None]:
    """Run the cycles (or with --rounds the rounds) in CELL, the gripper probed before the arm is sent
    anything; RESULTS and DESCRIBED fill as they finish. The log and the recording are closed however it
    ends. Returns why the robot halted (None: it did not), whether it could not be reached, and the
    interrupt (Ctrl-C, SIGTERM or SIGHUP) that ended the run."""
    from edgepick.robot.base import RobotError, RobotUnreachable
    from edgepick.robot.loop import run_cycles

    echo = lambda line: click.echo(line, err=True)  # noqa: E731
    halted, unreachable, interrupt = None, False, None
    overlays = output_dir(request.overlay_dir, "pick") if request.overlay_dir is not None else contextlib.nullcontext()

    def run() -> None:
        if rounds is None or request.rounds is None:
            run_cycles(cell, cfg=cfg, cycles=request.cycles, overlay_dir=request.overlay_dir, echo=echo,
                       overlap=request.overlap, done=results)
        else:
            _run_rounds(cell, request, request.rounds, rounds, cfg, model, echo, results, described)

    try:
        with overlays, cell.camera:
            if cell.robot is None or cell.gripper is None:
                run()
            else:
                try:
                    cell.gripper.probe()  # a gripper that cannot be reached is found before the arm is sent anything
                    with cell.robot:
                        run()
                except RobotError as exc:
                    if getattr(exc, "exit_code", 2) != 3:
                        raise
                    halted, unreachable = str(exc), isinstance(exc, RobotUnreachable)
                halted = halted or cell.robot.halted
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM or SIGHUP (Terminated): the summary of what was done
        interrupt = exc
    finally:
        cell.log.close()
        if cell.recorder is not None:  # also on Ctrl-C or a halt: what was recorded becomes a readable file
            cell.recorder.close()
    return halted, unreachable, interrupt


def _run_rounds(cell: Cell, request: PickRequest, count: int, rounds: RoundConfig, cfg: PickConfig, model: str,
                echo: Callable[[str], object], results: list[CycleResult], described: list[dict]) -> None:
    """`pick --rounds COUNT`: sim/clutter.py's run_rounds on the synthetic cell's seed and frame size, a
    recording per round."""
    from edgepick.sim.camera import SynthCamera
    from edgepick.sim.clutter import run_rounds

    source, record_path = cell.camera, request.record_path
    assert isinstance(source, SynthCamera)  # --rounds needs --camera synth-cell (_check_rounds)
    envelope = cell.robot.envelope if cell.robot is not None else None

    def round_recorder(round_cell):
        files = round_records(record_path, count) if record_path is not None else []
        return pick_recorder(files[round_cell.round - 1], model, cell.pipeline.classes, source, cfg, cell.pipeline,
                         envelope, {"round": round_cell.describe(), "same_table": round_cell.same_table})

    run_rounds(cell.pipeline, cell.robot, cell.gripper, rounds=count, pick=cfg,
               log=cell.log, seed=source.seed, cfg=rounds, judge=cell.physics is not None, echo=echo,
               overlay_dir=request.overlay_dir, recorder=round_recorder if record_path else None, done=results,
               described=described, size=(source.intrinsics.width, source.intrinsics.height))


def _summary(model: str, results: list[CycleResult], described: list[dict], rounds: int | None, halted, interrupt,
             log, log_path: str, record_path: str | None) -> dict:
    """`pick`'s JSON summary: the cycles summed (robot/loop.py), how the run ended, its files, with --rounds
    the rounds summed ("rounds", sim/clutter.py), and every cycle's result."""
    from edgepick.robot.loop import cycles_summary

    records = [f for f in round_records(record_path, rounds) if Path(f).exists()] if record_path else []
    summary = {"model": model, **cycles_summary(results), "halted": halted, "interrupted": _signal_name(interrupt),
               "log": log_path if log.path and log.path.exists() else None,
               "record": records if rounds is not None else records[0] if records else None}
    if rounds is not None:
        from edgepick.sim.clutter import round_summary

        summary["rounds"] = round_summary(described, results)
    return {**summary, "results": [r.to_dict() for r in results]}


def _signal_name(interrupt: KeyboardInterrupt | None) -> str | None:
    """The signal that ended the run: SIGINT for Ctrl-C, SIGTERM or SIGHUP (edgepick.errors.Terminated)."""
    if interrupt is None:
        return None
    return signal.Signals(getattr(interrupt, "signum", signal.SIGINT)).name


def _print_summary(summary: dict, interrupted: bool) -> None:
    """The run's JSON summary on stdout: first, even when the run ends in a halt or an interrupt. A
    hung-up terminal may have taken stdout with it; an interrupted run then ends without it."""
    try:
        click.echo(json.dumps(summary, indent=1))
    except OSError:
        if not interrupted:
            raise


def round_records(path: str, rounds: int | None) -> list[str]:
    """The files `--record PATH` writes: PATH itself, or with --rounds N one per round, PATH's stem
    then -round001 ... -roundNNN (a round is one recording)."""
    if rounds is None:
        return [path]
    p = Path(path)
    return [str(p.with_name(f"{p.stem}-round{k:03d}{p.suffix}")) for k in range(1, rounds + 1)]


def _check_rounds(rounds: int | None, max_cycles: int | None, cycles: int | None, camera: str, robot_spec: str,
                  overlap: bool):
    """--rounds and --max-cycles checked before anything starts: the RoundConfig of --rounds (None without it)."""
    config = round_config(rounds, max_cycles)
    if config is None:
        return None
    if cycles is not None:
        raise ConfigError(f"--cycles {cycles} with --rounds {rounds}: a round runs until its table is empty or its "
                          "picks fail; cap it with --max-cycles")
    if not camera.partition(":")[0] == "synth-cell":
        raise ConfigError(f"--rounds {rounds}: needs the synthetic cell (--camera synth-cell[:SEED]), whose table "
                          f"edgepick lays out and settles; --camera {camera} cannot be cleared")
    if robot_spec != "sim":
        raise ConfigError(f"--rounds {rounds}: needs --robot sim (the round's parts are simulated, and so is the arm)")
    if overlap:
        raise ConfigError("--overlap with --rounds: the next frame shows the table a cycle leaves behind, so it cannot "
                          "be read while the cycle goes on")
    return config


def _check_motion(cycles: int, speed: float, acc: float, robot_spec: str) -> tuple[str, str]:
    """Refuse a cycle count, speed or acceleration outside the envelope's caps, or an unknown
    robot; returns the robot's kind and host."""
    if cycles < 1:
        raise ConfigError("--cycles must be at least 1")
    envelope = Envelope()
    if not (math.isfinite(speed) and 0 < speed <= envelope.max_speed):
        raise ConfigError(f"--speed {speed}: must be in (0, {envelope.max_speed}] m/s")
    if not (math.isfinite(acc) and 0 < acc <= envelope.max_acc):
        raise ConfigError(f"--acc {acc}: must be in (0, {envelope.max_acc}] m/s^2")
    return check_robot(robot_spec)


