"""`edgepick calibrate`: collect camera-to-robot pairs with the arm and a marker, and fit them.

`edgepick calibrate PAIRS.csv --out calib.json` is `calibrate fit` (the group's default command).
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict
from typing import TYPE_CHECKING, cast

import click

from edgepick.cli.options import emit, parse_size
from edgepick.errors import ConfigError
from edgepick.files import check_output

if TYPE_CHECKING:
    from edgepick.frames import Camera
    from edgepick.robot.base import RobotBase
    from edgepick.robot.envelope import Envelope
    from edgepick.robot.handeye import CollectConfig, Collected
    from edgepick.robot.recording import Recorder
    from edgepick.runtime.calibration import Calibration
    from edgepick.runtime.marker import MarkerSpec


class _FitByDefault(click.Group):
    """A group whose first argument, when it names no subcommand, is fit's PAIRS."""

    def resolve_command(self, ctx: click.Context, args: list[str]):
        if args and args[0] not in self.commands and not args[0].startswith("-"):
            args = ["fit", *args]
        return super().resolve_command(ctx, args)


@click.group(cls=_FitByDefault)
def calibrate() -> None:
    """Camera-to-robot calibration: `collect` pairs with the arm, then fit them (Kabsch).

    \b
      edgepick calibrate collect --robot ur:HOST --camera realsense --marker aruco:4X4_50:7:40 \\
          --region 0.15,0.40,-0.20,0.20,0.08,0.25 --poses 16 --out pairs.csv --execute
      edgepick calibrate pairs.csv --out calib.json          (the same as: calibrate fit ...)
      edgepick calibrate pairs.csv --out calib.json --subsets 4,14,24
    """


def _floats(text: str, count: int, option: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{option} {text}: give {count} comma-separated numbers")
    return values


def _mm(metres: float) -> str:
    """A leave-one-out error in millimetres, or '-' where there is none (the other pairs are collinear)."""
    return "-" if math.isnan(metres) else f"{metres * 1000:.2f}"


@calibrate.command("fit")
@click.argument("pairs", type=click.Path(dir_okay=False))
@click.option("--out", required=True, type=click.Path(dir_okay=False),
              help="calib.json to write (docs/contracts.md#intrinsics-and-calibration).")
@click.option("--max-rmse", default=20.0, show_default=True, metavar="MM",
              help="Refuse a fit whose RMSE is above this many millimetres (and say what is likely wrong).")
@click.option("--drop-outliers", is_flag=True,
              help="Fit without the pairs flagged as outliers (leave-one-out error > 4x the median and > 10 mm).")
@click.option("--subsets", default="", metavar="K,K,...",
              help="Also report the error against the number of pairs (thesis Table 5.2): fits of 200 random "
                   "K-pair subsets, each measured on the pairs it left out.")
def fit(pairs: str, out: str, max_rmse: float, drop_outliers: bool, subsets: str) -> None:
    """Fit the camera-to-robot transform (Kabsch, det = +1) from PAIRS.csv.

    PAIRS.csv has the header cam_x,cam_y,cam_z,robot_x,robot_y,robot_z (metres) and at
    least 4 rows of the same physical points seen by the camera and touched by the robot
    (`calibrate collect` writes it). Prints each pair's residual and leave-one-out error (its
    error under the fit of the others: a mis-detection stands out there), flags outliers;
    refuses coincident or collinear points, and a fit too poor to be a measurement (mixed
    units, a mirrored axis, pairs of different points).
    """
    from edgepick.runtime.calibration import (
        check_subset_sizes,
        diagnose,
        kabsch,
        leave_one_out,
        outliers,
        read_pairs,
        residuals,
        subset_errors,
    )

    if not (math.isfinite(max_rmse) and max_rmse > 0):
        raise ConfigError(f"--max-rmse {max_rmse}: must be a positive number of millimetres")
    try:
        sizes = sorted({int(v) for v in subsets.split(",") if v.strip()})
    except ValueError:
        raise ConfigError(f"--subsets {subsets}: give comma-separated pair counts, e.g. 4,14,24") from None
    check_output(out, "--out", inputs=(pairs,))
    camera, robot = read_pairs(pairs)
    check_subset_sizes(sizes, len(camera))
    cal = kabsch(camera, robot)
    loo = leave_one_out(camera, robot) if len(camera) > 4 else None
    flagged = outliers(loo) if loo is not None else []
    flagged_set = set(flagged)
    if drop_outliers and flagged:
        keep = [i for i in range(len(camera)) if i not in flagged_set]
        cal = kabsch(camera[keep], robot[keep])
        camera_fit, robot_fit = camera[keep], robot[keep]
    else:
        camera_fit, robot_fit = camera, robot
    diagnose(cal, camera_fit, robot_fit, max_rmse / 1000)  # a refusal comes before the first line below
    if drop_outliers and flagged:
        click.echo(f"dropped {len(flagged)} outlier pair(s): {', '.join(str(i + 1) for i in flagged)}", err=True)
    for i, err in enumerate(residuals(cal, camera, robot)):
        held = f"   leave-one-out {_mm(loo[i]):>7} mm" if loo is not None else ""
        flag = "   outlier" + (" (dropped)" if drop_outliers else "") if i in flagged_set else ""
        click.echo(f"pair {i + 1:3d}: residual {err * 1000:7.2f} mm{held}{flag}", err=True)
    click.echo(f"RMSE {cal.rmse_m * 1000:.2f} mm over {cal.n_pairs} pairs", err=True)
    table = subset_errors(camera_fit, robot_fit, sizes) if sizes else {}
    for k, row in table.items():
        click.echo(f"{k:3d} pairs: error at the other pairs {row['mean_mm']:.2f} mm mean, {row['p95_mm']:.2f} mm p95 "
                   f"({row['fits']} fits)", err=True)
    cal.save(out)
    result = {"out": out, **cal.to_dict(), "outliers": [i + 1 for i in flagged],
              "leave_one_out_mm": [None if math.isnan(e) else round(e * 1000, 2) for e in loo] if loo is not None
              else None}
    if table:
        result["subsets"] = {str(k): v for k, v in table.items()}
    emit(result)


@calibrate.command("collect")
@click.option("--robot", "robot_spec", default="sim", show_default=True, help="sim or ur:HOST.")
@click.option("--camera", default="synth-cell", show_default=True,
              help="realsense[:SERIAL], synth-cell[:SEED] (a simulated camera over the cell, which sees the marker "
                   "where the arm puts it) or dir:PATH.")
@click.option("--marker", "marker_spec", default="aruco:4X4_50:7:40", show_default=True,
              help="aruco:DICT:ID[:SIZE_MM]: the printed marker on the tool (with its size, a sighting of the wrong "
                   "size is refused).")
@click.option("--marker-offset", default="0,0,0", show_default=True, metavar="X,Y,Z",
              help="Marker centre from the TCP, tool frame, metres (e.g. 0,0,-0.01 for a plate 1 cm above the TCP "
                   "of a tool pointing down).")
@click.option("--poses", default=16, show_default=True, help="Positions to visit (at least 4).")
@click.option("--region", default=None, metavar="X0,X1,Y0,Y1,Z0,Z1",
              help="Box of TCP positions the camera sees, robot frame, metres [synth-cell: 0.18,0.38,-0.16,0.16,"
                   "0.08,0.24; required otherwise].")
@click.option("--settle", default=0.5, show_default=True, help="Seconds to wait after each move before the frame.")
@click.option("--speed", default=0.1, show_default=True, help="moveL speed, m/s.")
@click.option("--size", default="640x480", show_default=True, help="Camera frame size, WIDTHxHEIGHT.")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="pairs.csv to write.")
@click.option("--execute", is_flag=True, help="Move a real arm (ur:HOST); without it the plan is printed only.")
@click.option("--robot-log", default=None, type=click.Path(dir_okay=False),
              help="File for the ur_rtde client's own messages [default: discarded].")
@click.option("--record", "record_path", default=None, type=click.Path(dir_okay=False),
              help="Record each position's frame, commanded and reported TCP and sighting, then the fitted "
                   "transform, to this MCAP file for Foxglove or Rerun (the [record] extra; "
                   "docs/contracts.md#recordings).")
def collect(robot_spec: str, camera: str, marker_spec: str, marker_offset: str, poses: int, region: str | None,
            settle: float, speed: float, size: str, out: str, execute: bool, robot_log: str | None,
            record_path: str | None) -> None:
    """Move a marker on the tool through a grid of positions and write camera/robot point pairs.

    Plans POSES positions on a grid over REGION at two or three heights, checks every position
    and the straight path to it against the safety envelope before the first move, then at each:
    moves (moveL, tool pointing down), waits --settle, detects the ArUco marker (OpenCV), takes its
    centre's 3D point from the aligned depth and the TCP from the robot. Positions where the marker
    is not seen or has no depth are skipped and listed. Fewer than 4 usable pairs, or pairs on one
    line, end with an error and no file. Then: edgepick calibrate PAIRS --out calib.json.
    """
    from edgepick.cli.cameras import open_camera
    from edgepick.cli.cell import check_robot
    from edgepick.robot.envelope import Envelope
    from edgepick.robot.handeye import plan_positions
    from edgepick.runtime.calibration import write_pairs
    from edgepick.runtime.camera import FolderCamera
    from edgepick.runtime.marker import MarkerSpec

    spec = MarkerSpec.parse(marker_spec)
    kind, host = check_robot(robot_spec)
    envelope = Envelope()
    cfg = _collect_config(camera, marker_offset, poses, region, settle, speed, envelope)
    folder = camera.partition(":")[2] if camera.startswith("dir:") else None  # the frames it reads
    check_output(out, "--out", inputs=(folder,))
    if robot_log is not None:
        check_output(robot_log, "--robot-log", inputs=(folder, out))
    if record_path is not None:
        check_output(record_path, "--record", inputs=(folder, out, robot_log))
    frame_size = parse_size(size)
    plan = plan_positions(cfg)
    if kind == "ur" and not execute:
        _print_plan(plan, host, envelope)
        return
    robot = _open_arm(kind, host, envelope, robot_log)
    source = open_camera(camera, frame_size)
    if isinstance(source, FolderCamera) and not source.loop and len(source.names) < len(plan):
        raise ConfigError(f"--camera {camera}: {len(source.names)} frames for {len(plan)} positions; give one frame "
                          "per position (or fewer --poses)")
    recorder = _collect_recorder(record_path, marker_spec, cfg)
    got, cal = _collect_and_fit(robot, source, spec, plan, cfg, envelope, recorder)
    write_pairs(out, got.camera, got.robot)
    click.echo(f"{len(got.camera)} pairs written to {out}; their fit: RMSE {cal.rmse_m * 1000:.2f} mm", err=True)
    emit({"out": out, "pairs": len(got.camera), "planned": len(plan), "skipped": [i for i, _ in got.skipped],
          "rmse_mm": round(cal.rmse_m * 1000, 3)})


def _collect_config(camera: str, marker_offset: str, poses: int, region: str | None, settle: float, speed: float,
                    envelope: Envelope) -> CollectConfig:
    """The CollectConfig of collect's options, checked: a speed within the envelope's cap, and a --region
    wherever the camera is not the synthetic cell's (whose region is the default)."""
    from edgepick.robot.handeye import CollectConfig

    if not (math.isfinite(speed) and 0 < speed <= envelope.max_speed):
        raise ConfigError(f"--speed {speed}: must be in (0, {envelope.max_speed}] m/s")
    cell = camera.split(":")[0] == "synth-cell"
    if region is None and not cell:
        raise ConfigError("--region is needed: the box of TCP positions your camera sees (robot frame, metres)")
    offset = cast("tuple[float, float, float]", _floats(marker_offset, 3, "--marker-offset"))
    if region is None:
        return CollectConfig(poses=poses, offset_m=offset, settle_s=settle, speed=speed)
    box = cast("tuple[float, float, float, float, float, float]", _floats(region, 6, "--region"))
    return CollectConfig(poses=poses, offset_m=offset, settle_s=settle, speed=speed, region=box)


def _print_plan(plan: list[list[float]], host: str, envelope: Envelope) -> None:
    """collect on a real arm without --execute: the plan checked from the home pose and printed, nothing sent."""
    from edgepick.robot.handeye import check_plan
    from edgepick.robot.motion import HOME_POSE

    check_plan(plan, HOME_POSE, envelope)  # the arm's own pose is not known without a connection
    for i, pose in enumerate(plan, start=1):
        click.echo(f"position {i:3d}: x {pose[0]:.3f}  y {pose[1]:.3f}  z {pose[2]:.3f}", err=True)
    click.echo(f"plan only: nothing is sent to {host} (add --execute to move the arm)", err=True)
    emit({"out": None, "planned": len(plan), "moved": False})


def _open_arm(kind: str, host: str, envelope: Envelope, robot_log: str | None) -> RobotBase:
    """The arm collect moves: a SimRobot, or a UR3 at HOST (its client's messages to ROBOT_LOG)."""
    if kind == "sim":
        from edgepick.sim.robot import SimRobot

        return SimRobot(envelope)
    from edgepick.robot.ur import URRobot

    return URRobot(host, envelope=envelope, debug_log=robot_log)


def _collect_recorder(record_path: str | None, marker_spec: str, cfg: CollectConfig) -> Recorder | None:
    """The Recorder of `collect --record PATH` (None without it)."""
    if record_path is None:
        return None
    from edgepick.robot.recording import Recorder

    return Recorder(record_path, {"command": "calibrate collect", "marker": marker_spec, **asdict(cfg)})


def _collect_and_fit(robot: RobotBase, source: Camera, spec: MarkerSpec, plan: list[list[float]], cfg: CollectConfig,
                     envelope: Envelope, recorder: Recorder | None) -> tuple[Collected, Calibration]:
    """Visit PLAN with ROBOT, pair the marker's sightings and fit them: the pairs and their fit, refused in one
    line when fewer than 4 are usable or they lie on one line. The recording (if any) is closed whatever happens."""
    from edgepick.robot.handeye import check_plan, collect_pairs
    from edgepick.runtime.calibration import kabsch
    from edgepick.sim.camera import SynthCamera, ToolMarker

    echo = lambda line: click.echo(line, err=True)  # noqa: E731
    try:
        with source, robot:
            check_plan(plan, robot.tcp_pose(), envelope)
            if isinstance(source, SynthCamera):
                source.show_tool_marker(ToolMarker(spec, robot.tcp_pose, cfg.offset_m))
            got = collect_pairs(robot, source, spec, plan, cfg, echo, recorder)
        if got.skipped:
            click.echo(f"{len(got.skipped)} of {len(plan)} positions gave no pair: "
                       + "; ".join(f"{i}: {why}" for i, why in got.skipped), err=True)
        if len(got.camera) < 4:
            raise ConfigError(f"only {len(got.camera)} usable pairs of {len(plan)} positions (4 needed); is the "
                              "marker in view over --region, and is --marker the printed one?")
        cal = kabsch(got.camera, got.robot)  # refuses pairs on one line before anything is written
        if recorder is not None:
            recorder.fitted(cal, got.camera, got.robot, time.time_ns())
    finally:
        if recorder is not None:  # also on Ctrl-C or a halt: what was recorded becomes a readable file
            recorder.close()
    return got, cal
