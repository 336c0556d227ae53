"""`edgepick pick`: the pick-and-place loop on the command line (click only; no torch)."""

from __future__ import annotations

import contextlib
import json
import math
import signal
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import click

from edgepick.cli.options import choice, default_of, parse_size, round_config
from edgepick.errors import ConfigError
from edgepick.files import check_output, output_dir
from edgepick.robot.envelope import Envelope
from edgepick.robot.pick import Choose, PickConfig
from edgepick.robot.verdict import VerdictRule
from edgepick.runtime.engine import Engine

if TYPE_CHECKING:
    from edgepick.robot.cycle import CycleResult


def check_gripper(spec: str, robot_host: str | None) -> tuple[str, int | str]:
    """Parse --gripper before anything starts: ('digital' or 'tool', N) for an output the arm has
    (the limits of RobotBase.set_digital_out), or ('rg2', HOST)."""
    from edgepick.robot.base import output_reason

    kind, _, arg = spec.partition(":")
    if kind in ("digital", "tool"):
        try:
            index = int(arg)
        except ValueError:
            raise ConfigError(f"--gripper {spec}: the output must be a number, e.g. {kind}:0") from None
        reason = output_reason(index, tool=kind == "tool")
        if reason:
            raise ConfigError(f"--gripper {spec}: the {reason}")
        return kind, index
    if kind == "rg2":
        host = arg or robot_host
        if not host:
            raise ConfigError("--gripper rg2 needs the robot's host (rg2:HOST, or --robot ur:HOST)")
        return kind, host
    raise ConfigError(f"--gripper {spec}: unknown gripper; use digital:N, tool:N or rg2[:HOST]")


def with_gripper(cfg: PickConfig, spec: tuple[str, int | str]) -> PickConfig:
    """CFG with the hand the planner checks (robot/clearance.py) matching a checked gripper spec:
    an RG2's jaw opens only as far as RG2Gripper opens it."""
    if spec[0] != "rg2" or cfg.hand is None:
        return cfg
    from edgepick.robot.grippers import RG2Gripper

    return replace(cfg, hand=replace(cfg.hand, jaw_opening_m=RG2Gripper.OPEN_WIDTH_M))


def make_gripper(spec: tuple[str, int | str], robot):
    """The gripper of a checked spec (check_gripper): an RG2Gripper, or a DigitalGripper that
    drives ROBOT's output."""
    from edgepick.robot.grippers import DigitalGripper, RG2Gripper

    kind, arg = spec
    return RG2Gripper(arg) if kind == "rg2" else DigitalGripper(robot, arg, tool=kind == "tool")


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
def pick(model: str, camera: str, robot_spec: str, calib: str | None, gripper: str, execute: bool, cycles: int,
         rounds: int | None, max_cycles: int | None, classes: tuple[str, ...], choose: str, speed: float, acc: float,
         log_path: str, robot_log: str | None, overlay_dir: str | None, record_path: str | None, verdict: str,
         threads: int, engine: str, size: str, overlap: bool) -> None:
    """Pick and place: camera -> segmentation -> grasp records -> target -> robot.

    Each cycle chooses the largest (or closest) object whose whole plan passes the safety
    envelope, then: approach above -> open -> descend -> grip -> lift -> place -> release ->
    home. --robot sim runs against the in-process SimRobot; a real UR3 (--robot ur:HOST)
    moves only with --execute, otherwise the plan is printed and nothing is sent. Every
    target and the straight path to it are checked against the envelope before the first
    command. The JSON summary goes to stdout; if the robot halts (protective or emergency
    stop, lost link) or cannot be reached, it says so and the exit status is 3.
    """
    from edgepick.cli.cameras import open_camera
    from edgepick.robot.base import RobotError, RobotHalted, RobotUnreachable
    from edgepick.robot.loop import Cell, run_cycles
    from edgepick.robot.pick import CommandLog
    from edgepick.runtime.calibration import Calibration
    from edgepick.runtime.pipeline import Pipeline
    from edgepick.runtime.session import Segmenter
    from edgepick.sim.camera import SynthCamera

    given = click.get_current_context().get_parameter_source("cycles") == click.core.ParameterSource.COMMANDLINE
    round_cfg = _check_rounds(rounds, max_cycles, cycles if given else None, camera, robot_spec, overlap)
    kind, host = _check_motion(cycles, speed, acc, robot_spec)
    gripper_spec = check_gripper(gripper, host or None)
    check_output(log_path, "--log", inputs=(model, calib))
    if overlay_dir is not None:
        check_output(overlay_dir, "--overlay-dir", kind="dir", inputs=(model, calib), reuse="pick")
    if robot_log is not None:
        check_output(robot_log, "--robot-log", inputs=(model, calib, log_path))
    if record_path is not None:
        for path in round_records(record_path, rounds):
            check_output(path, "--record", inputs=(model, calib, log_path, robot_log))
        from edgepick.robot.messages import schemas

        schemas()  # the [record] extra, before anything starts
    if round_cfg is not None:
        from edgepick.sim.physics import require_mujoco

        require_mujoco()  # the [sim] extra settles the rounds' parts, before anything starts
    if verdict != VerdictRule.GEOMETRIC:
        if not camera.startswith("synth-cell"):
            raise ConfigError(f"--verdict {verdict}: needs the synthetic cell (--camera synth-cell), whose scenes "
                              "know their objects")
        from edgepick.sim.physics import require_mujoco

        require_mujoco()  # the [sim] extra, before anything starts
    frame_size = parse_size(size)
    model = model or _reference_for(camera)
    segmenter = Segmenter(model, threads=threads, engine=engine)
    unknown = [c for c in classes if c not in segmenter.info.classes]
    if unknown:
        raise ConfigError(f"--class {unknown[0]}: not a class of {model} ({', '.join(segmenter.info.classes)})")
    source = open_camera(camera, frame_size)
    if calib:
        cal = Calibration.load(calib)
    elif isinstance(source, SynthCamera) and source.mount is not None:
        cal = source.calibration()
    else:
        raise ConfigError("--calib is needed to turn camera points into robot poses")
    pipeline = Pipeline(segmenter, cal)
    truth_cal = source.calibration() if isinstance(source, SynthCamera) and source.mount is not None else None
    cfg = PickConfig(classes=tuple(classes), choose=choose, speed=speed, acc=acc)
    cfg = with_gripper(cfg, gripper_spec)
    physics = None
    if verdict != VerdictRule.GEOMETRIC and truth_cal is not None:
        from edgepick.sim.physics import physics_judge

        physics = physics_judge(truth_cal, cfg)
    robot = _open_robot(kind, execute, host, robot_log)
    grip = make_gripper(gripper_spec, robot) if robot is not None else None
    log = CommandLog(log_path)
    echo = lambda line: click.echo(line, err=True)  # noqa: E731
    results: list[CycleResult] = []  # filled cycle by cycle: still there when an interrupt ends the loop
    described: list[dict] = []  # --rounds: each round as it ends
    halted, unreachable, interrupt = None, False, None
    overlays = output_dir(overlay_dir, "pick") if overlay_dir is not None else contextlib.nullcontext()
    recorder = None if round_cfg is not None else _recorder(
        record_path, model, segmenter.info.classes, source, cfg, pipeline, robot.envelope if robot is not None else None)

    def run(arm, hand) -> None:
        if round_cfg is None:
            run_cycles(Cell(source, pipeline, arm, hand, log, truth_cal, recorder, physics), cfg=cfg, cycles=cycles,
                       overlay_dir=overlay_dir, echo=echo, overlap=overlap, done=results)
        else:
            _run_rounds(arm, hand, rounds, round_cfg, cfg, log, source, pipeline, physics is not None, echo, overlay_dir,
                        record_path, model, segmenter.info.classes, results, described)

    try:
        with overlays, source:
            if robot is None:
                run(None, None)
            else:
                try:
                    grip.probe()  # a gripper that cannot be reached is found before the arm is sent anything
                    with robot:
                        run(robot, grip)
                except RobotError as exc:
                    if getattr(exc, "exit_code", 2) != 3:
                        raise
                    halted, unreachable = str(exc), isinstance(exc, RobotUnreachable)
                halted = halted or robot.halted
    except KeyboardInterrupt as exc:  # Ctrl-C, SIGTERM or SIGHUP (Terminated): the summary of what was done
        interrupt = exc
    finally:
        log.close()
        if recorder is not None:  # also on Ctrl-C or a halt: what was recorded becomes a readable file
            recorder.close()
    summary = _summary(model, results, described, rounds, halted, interrupt, log, log_path, record_path)
    _print_summary(summary, interrupted=interrupt is not None)
    if interrupt is not None:  # the command line says so in one line and exits 128 + the signal
        raise interrupt
    if halted:  # the command line prints the one error line and exits 3
        if unreachable:
            raise RobotUnreachable(halted)
        raise RobotHalted(f"robot halted: {halted} ({summary['done']} of {summary['cycles'] if rounds else cycles} "
                          "cycles done)")


def _open_robot(kind: str, execute: bool, host: str, robot_log: str | None):
    """The arm of --robot: a SimRobot, a UR3 with --execute, or None (plan only, said on stderr)."""
    if kind == "sim":
        from edgepick.sim.robot import SimRobot

        return SimRobot()
    if execute:
        from edgepick.robot.ur import URRobot

        return URRobot(host, debug_log=robot_log)
    click.echo(f"plan only: nothing is sent to {host} (add --execute to move the arm)", err=True)
    return None


def _run_rounds(arm, hand, rounds: int, round_cfg, cfg: PickConfig, log, source, pipeline, judge: bool, echo,
                overlay_dir: str | None, record_path: str | None, model: str, classes, results: list[CycleResult],
                described: list[dict]) -> None:
    """`pick --rounds`: sim/clutter.py's run_rounds on SOURCE's seed and frame size, a recording per round."""
    from edgepick.sim.clutter import run_rounds

    def round_recorder(cell):
        return _recorder(round_records(record_path, rounds)[cell.round - 1], model, classes, source, cfg, pipeline,
                         arm.envelope, {"round": cell.describe()})

    run_rounds(pipeline, arm, hand, rounds=rounds, pick=cfg, log=log, seed=source.seed, cfg=round_cfg, judge=judge,
               echo=echo, overlay_dir=overlay_dir, recorder=round_recorder if record_path else None, done=results,
               described=described, size=(source.intrinsics.width, source.intrinsics.height))


def _summary(model: str, results: list[CycleResult], described: list[dict], rounds: int | None, halted, interrupt,
             log, log_path: str, record_path: str | None) -> dict:
    """`pick`'s JSON summary: the cycles summed (robot/loop.py), how the run ended, its files, with --rounds
    the rounds summed ("rounds", sim/clutter.py), and every cycle's result."""
    from edgepick.robot.loop import cycles_summary

    records = [f for f in round_records(record_path, rounds) if Path(f).exists()] if record_path else []
    summary = {"model": model, **cycles_summary(results), "halted": halted, "interrupted": _signal_name(interrupt),
               "log": log_path if log.path and log.path.exists() else None,
               "record": records if rounds is not None else (records or [None])[0]}
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


def _recorder(path: str | None, model: str, classes, source, cfg: PickConfig, pipeline, envelope: Envelope | None,
              extra: dict | None = None):
    """The Recorder of `pick --record PATH` (None without it), opened before the first frame; EXTRA joins
    its metadata (a round's: its table)."""
    if path is None:
        return None
    from edgepick.robot.recording import Recorder, pick_metadata

    metadata = pick_metadata(model, classes, cfg, pipeline.cfg, envelope or Envelope())
    return Recorder(path, {**metadata, **(extra or {})}, pipeline.calib)


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


def check_robot(robot_spec: str) -> tuple[str, str]:
    """'sim' or 'ur:HOST' -> (kind, host)."""
    kind, _, host = robot_spec.partition(":")
    if kind not in ("sim", "ur") or (kind == "ur" and not host):
        raise ConfigError(f"unknown robot {robot_spec!r}: use sim or ur:HOST")
    return kind, host


def _reference_for(camera: str) -> str:
    """The shipped reference model, for a synthetic camera only: it has seen synthetic scenes alone."""
    from edgepick.reference import reference_model

    if not camera.startswith("synth"):
        raise ConfigError(f"--model is needed with --camera {camera}: the shipped reference model knows only "
                          "synthetic scenes; train one on your own data")
    found = reference_model()
    if found is None:
        raise ConfigError("--model is needed: this install has no reference model (edgepick/reference/)")
    return str(found)
