"""`edgepick pick`: the pick-and-place loop on the command line (click only; no torch)."""

from __future__ import annotations

import json

import click

from edgepick.errors import ConfigError


def make_gripper(spec: str, robot, robot_host: str | None):
    """'digital:N' (standard output N), 'tool:N' (tool output N) or 'rg2[:HOST]'."""
    from edgepick.robot.grippers import DigitalGripper, RG2Gripper

    kind, _, arg = spec.partition(":")
    if kind in ("digital", "tool"):
        try:
            return DigitalGripper(robot, int(arg), tool=kind == "tool")
        except ValueError:
            raise ConfigError(f"--gripper {spec}: the output must be a number, e.g. digital:0") from None
    if kind == "rg2":
        host = arg or robot_host
        if not host:
            raise ConfigError("--gripper rg2 needs the robot's host (rg2:HOST, or --robot ur:HOST)")
        return RG2Gripper(host)
    raise ConfigError(f"unknown gripper {spec!r}: use digital:N, tool:N or rg2[:HOST]")


@click.command()
@click.option("--model", required=True, type=click.Path(dir_okay=False),
              help="Segmentation ONNX (docs/contracts.md#onnx-model).")
@click.option("--camera", default="synth-cell", show_default=True,
              help="synth-cell[:SEED] (synthetic camera over a calibrated cell), synth, dir:PATH or realsense[:SERIAL].")
@click.option("--robot", "robot_spec", default="sim", show_default=True, help="sim, or ur:HOST for a UR3 over ur_rtde.")
@click.option("--calib", default=None, type=click.Path(dir_okay=False),
              help="calib.json (docs/contracts.md#intrinsics-and-calibration) [default for synth-cell: the cell's "
                   "own calibration].")
@click.option("--gripper", default="digital:0", show_default=True, help="digital:N, tool:N or rg2[:HOST].")
@click.option("--execute", is_flag=True, help="Move a real arm (--robot ur:HOST). Without it the plan is only printed.")
@click.option("--cycles", default=1, show_default=True, help="Pick cycles to run.")
@click.option("--class", "classes", multiple=True, help="Only pick these classes (repeatable).")
@click.option("--choose", default="largest", show_default=True, type=click.Choice(["largest", "closest"]))
@click.option("--speed", default=0.25, show_default=True,
              help="moveL speed, m/s; the envelope refuses moves above its cap (0.25).")
@click.option("--acc", default=1.2, show_default=True,
              help="moveL acceleration, m/s^2; the envelope refuses moves above its cap (1.2).")
@click.option("--log", "log_path", default="picks.jsonl", show_default=True, type=click.Path(dir_okay=False),
              help="JSON-lines log of every command.")
@click.option("--overlay-dir", default=None, type=click.Path(file_okay=False), help="Write an overlay PNG per cycle.")
@click.option("--threads", default=2, show_default=True, help="Inference threads.")
@click.option("--engine", default="onnxruntime", show_default=True, type=click.Choice(["onnxruntime", "openvino"]),
              help="Inference engine (openvino: the [peers] extra).")
@click.option("--size", default="640x480", show_default=True, help="Camera frame size, WIDTHxHEIGHT.")
def pick(model: str, camera: str, robot_spec: str, calib: str | None, gripper: str, execute: bool, cycles: int,
         classes: tuple[str, ...], choose: str, speed: float, acc: float, log_path: str, overlay_dir: str | None,
         threads: int, engine: str, size: str) -> None:
    """Pick and place: camera -> segmentation -> grasp records -> target -> robot.

    Each cycle chooses the largest (or closest) object whose whole plan passes the safety
    envelope, then: approach above -> open -> descend -> grip -> lift -> place -> release ->
    home. --robot sim runs against the in-process SimRobot; a real UR3 (--robot ur:HOST)
    moves only with --execute, otherwise the plan is printed and nothing is sent.
    """
    from edgepick.cli.options import parse_size
    from edgepick.robot.loop import run_cycles
    from edgepick.robot.pick import CommandLog, PickConfig
    from edgepick.robot.sim import SimRobot
    from edgepick.runtime.calibration import Calibration
    from edgepick.runtime.camera import SynthCamera, open_camera
    from edgepick.runtime.pipeline import Pipeline
    from edgepick.runtime.session import Segmenter

    if cycles < 1:
        raise ConfigError("--cycles must be at least 1")
    width, height = parse_size(size)
    source = open_camera(camera, width, height)
    if calib:
        cal = Calibration.load(calib)
    elif isinstance(source, SynthCamera) and source.mount is not None:
        cal = source.calibration()
    else:
        raise ConfigError("--calib is needed to turn camera points into robot poses")
    kind, _, host = robot_spec.partition(":")
    if kind not in ("sim", "ur") or (kind == "ur" and not host):
        raise ConfigError(f"unknown robot {robot_spec!r}: use sim or ur:HOST")
    pipeline = Pipeline(Segmenter(model, threads=threads, engine=engine), cal)
    cfg = PickConfig(classes=tuple(classes), choose=choose, speed=speed, acc=acc)
    if kind == "sim":
        robot = SimRobot()
    elif execute:
        from edgepick.robot.ur import URRobot

        robot = URRobot(host)
    else:
        robot = None
        click.echo(f"plan only: nothing is sent to {host} (add --execute to move the arm)", err=True)
    grip = make_gripper(gripper, robot, host or None) if robot is not None else None
    log = CommandLog(log_path)
    echo = lambda line: click.echo(line, err=True)  # noqa: E731
    try:
        with source:
            if robot is None:
                results = run_cycles(source, pipeline, None, None, cfg, cycles, log, overlay_dir, echo)
            else:
                with robot:
                    results = run_cycles(source, pipeline, robot, grip, cfg, cycles, log, overlay_dir, echo)
    finally:
        log.close()
    done = [r for r in results if r["outcome"] == "done"]
    errors = [r["grasp_error_m"] for r in results if r.get("grasp_error_m") is not None]
    summary = {"cycles": len(results), "done": len(done), "log": log_path,
               "within_1cm": sum(1 for r in results if r.get("within_1cm")),
               "grasp_error_mm_median": round(1000 * sorted(errors)[len(errors) // 2], 2) if errors else None,
               "results": results}
    click.echo(json.dumps(summary, indent=1))
