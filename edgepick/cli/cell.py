"""The pick cell wired from `pick`'s options (click only at import; no torch): the robot and gripper
specs checked, the model (the shipped reference one by default), the camera and its calibration,
the arm, the gripper, the command log and the recorder, put together as the Cell that
edgepick.robot.loop drives."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import click

from edgepick.errors import ConfigError
from edgepick.robot.envelope import Envelope
from edgepick.robot.pick import Choose, PickConfig
from edgepick.robot.verdict import VerdictRule
from edgepick.runtime.engine import Engine

if TYPE_CHECKING:
    from edgepick.frames import Camera
    from edgepick.geometry import Size
    from edgepick.robot.base import RobotBase
    from edgepick.robot.grippers import DigitalGripper, RG2Gripper
    from edgepick.robot.loop import Cell
    from edgepick.robot.recording import Recorder
    from edgepick.runtime.calibration import Calibration
    from edgepick.sim.clutter import RoundConfig


@dataclass(frozen=True)
class PickRequest:
    """What `pick` was asked for: its options as click read them, checked before anything starts."""

    model: str | None
    camera: str
    robot_spec: str
    calib: str | None
    gripper: str
    execute: bool
    cycles: int
    rounds: int | None
    max_cycles: int | None
    classes: tuple[str, ...]
    choose: Choose
    speed: float
    acc: float
    log_path: str
    robot_log: str | None
    overlay_dir: str | None
    record_path: str | None
    verdict: VerdictRule
    threads: int
    engine: Engine
    size: str
    overlap: bool


@dataclass(frozen=True)
class CheckedPick:
    """What the checks before anything starts settle: the RoundConfig of --rounds (None without it),
    the robot's kind and host, the gripper and the camera's frame size."""

    rounds: RoundConfig | None
    robot_kind: str
    host: str
    gripper: tuple[str, int | str]
    frame_size: Size


def open_cell(request: PickRequest, checked: CheckedPick) -> tuple[Cell, PickConfig, str]:
    """The Cell `pick` drives, wired from its options: the model (the shipped reference one by default)
    and the camera with their pipeline, the calibration (the synthetic cell's own by default), the
    physics check, the arm and gripper, the command log and the recorder. Returns the cell, the pick's
    settings and the model's path."""
    from edgepick.robot.loop import Cell
    from edgepick.robot.pick import CommandLog
    from edgepick.runtime.pipeline import Pipeline
    from edgepick.runtime.session import Segmenter

    model = request.model or reference_for(request.camera)
    segmenter = Segmenter(model, threads=request.threads, engine=request.engine)
    unknown = [c for c in request.classes if c not in segmenter.info.classes]
    if unknown:
        raise ConfigError(f"--class {unknown[0]}: not a class of {model} ({', '.join(segmenter.info.classes)})")
    source, calibration, truth_cal = camera_and_calibration(request.camera, checked.frame_size, request.calib)
    pipeline = Pipeline(segmenter, calibration)
    cfg = PickConfig(classes=tuple(request.classes), choose=request.choose, speed=request.speed, acc=request.acc)
    cfg = with_gripper(cfg, checked.gripper)
    physics = None
    if request.verdict != VerdictRule.GEOMETRIC and truth_cal is not None:
        from edgepick.sim.physics import physics_judge

        physics = physics_judge(truth_cal, cfg)
    robot = open_robot(checked.robot_kind, request.execute, checked.host, request.robot_log)
    grip = make_gripper(checked.gripper, robot) if robot is not None else None
    log = CommandLog(request.log_path)
    recorder = None if checked.rounds is not None else pick_recorder(
        request.record_path, model, segmenter.info.classes, source, cfg, pipeline,
        robot.envelope if robot is not None else None)
    return Cell(source, pipeline, robot, grip, log, truth_cal, recorder, physics), cfg, model


def camera_and_calibration(camera: str, frame_size: Size, calib: str | None
                           ) -> tuple[Camera, Calibration, Calibration | None]:
    """The camera of --camera, the calibration of --calib (the synthetic cell's own without it), and the
    cell's true calibration where the camera is the synthetic cell's (its cycles judged against the truth)."""
    from edgepick.cli.cameras import open_camera
    from edgepick.runtime.calibration import Calibration
    from edgepick.sim.camera import SynthCamera

    source = open_camera(camera, frame_size)
    if calib:
        calibration = Calibration.load(calib)
    elif isinstance(source, SynthCamera) and source.mount is not None:
        calibration = source.calibration()
    else:
        raise ConfigError("--calib is needed to turn camera points into robot poses")
    truth = source.calibration() if isinstance(source, SynthCamera) and source.mount is not None else None
    return source, calibration, truth


def open_robot(kind: str, execute: bool, host: str, robot_log: str | None) -> RobotBase | None:
    """The arm of --robot: a SimRobot, a UR3 with --execute, or None (plan only, said on stderr)."""
    if kind == "sim":
        from edgepick.sim.robot import SimRobot

        return SimRobot()
    if execute:
        from edgepick.robot.ur import URRobot

        return URRobot(host, debug_log=robot_log)
    click.echo(f"plan only: nothing is sent to {host} (add --execute to move the arm)", err=True)
    return None


def pick_recorder(path: str | None, model: str, classes, source, cfg: PickConfig, pipeline, envelope: Envelope | None,
                  extra: dict | None = None) -> Recorder | None:
    """The Recorder of `pick --record PATH` (None without it), opened before the first frame; EXTRA joins
    its metadata (a round's: its table). Its `same_table` (the camera's) tells replay that a pick's place
    was remembered (robot/pick.py choose_target's TRIED)."""
    if path is None:
        return None
    from edgepick.robot.recording import Recorder, pick_metadata

    metadata = pick_metadata(model, classes, cfg, pipeline.cfg, envelope or Envelope())
    return Recorder(path, {**metadata, "same_table": source.same_table, **(extra or {})}, pipeline.calib)


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


def make_gripper(spec: tuple[str, int | str], robot: RobotBase) -> DigitalGripper | RG2Gripper:
    """The gripper of a checked spec (check_gripper): an RG2Gripper, or a DigitalGripper that
    drives ROBOT's output."""
    from edgepick.robot.grippers import DigitalGripper, RG2Gripper

    kind, arg = spec
    return RG2Gripper(str(arg)) if kind == "rg2" else DigitalGripper(robot, int(arg), tool=kind == "tool")


def check_robot(robot_spec: str) -> tuple[str, str]:
    """'sim' or 'ur:HOST' -> (kind, host)."""
    kind, _, host = robot_spec.partition(":")
    if kind not in ("sim", "ur") or (kind == "ur" and not host):
        raise ConfigError(f"unknown robot {robot_spec!r}: use sim or ur:HOST")
    return kind, host


def reference_for(camera: str) -> str:
    """The shipped reference model, for a synthetic camera only: it has seen synthetic scenes alone."""
    from edgepick.reference import reference_model

    if not camera.startswith("synth"):
        raise ConfigError(f"--model is needed with --camera {camera}: the shipped reference model knows only "
                          "synthetic scenes; train one on your own data")
    found = reference_model()
    if found is None:
        raise ConfigError("--model is needed: this install has no reference model (edgepick/reference/)")
    return str(found)
