"""Collecting camera-to-robot pairs with the arm (`edgepick calibrate collect`): a marker on the
tool is moved to N positions on a grid inside the envelope, and at each one the camera's 3D point
of the marker and the arm's TCP make a pair (thesis 5.1.3, done by hand there).

The plan is checked whole before the first move, as `pick` checks its plan: every position and
the straight path to it against the safety envelope. The tool keeps one orientation (pointing
down, the marker facing the camera above); the robot point of a pair is the TCP plus the marker's
offset in the tool frame.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from edgepick.errors import ParameterError
from edgepick.frames import Camera, CameraError
from edgepick.robot.base import RobotBase
from edgepick.robot.envelope import Envelope, SafetyError
from edgepick.robot.recording import CalibrationSighting, Recorder
from edgepick.runtime.marker import MarkerSpec, detect_marker

TOOL_DOWN = (math.pi, 0.0, 0.0)  # rotation vector of a tool pointing straight down
MAX_POSES = 1000  # a quarter of an hour of arm time at the default settle_s and speed; a fit needs tens


@dataclass(frozen=True)
class CollectConfig:
    """How `calibrate collect` visits its positions, checked on creation."""

    poses: int = 12
    region: tuple[float, float, float, float, float, float] = (0.18, 0.38, -0.16, 0.16, 0.08, 0.24)  # x0,x1,y0,y1,z0,z1
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # marker centre from the TCP, tool frame
    orientation: tuple[float, float, float] = TOOL_DOWN
    speed: float = 0.1
    acc: float = 0.5
    settle_s: float = 0.5  # wait after each move before the frame is taken

    def __post_init__(self) -> None:
        for name in ("region", "offset_m", "orientation"):
            object.__setattr__(self, name, tuple(float(v) for v in getattr(self, name)))
        if self.poses < 4:
            raise ParameterError("{poses}: a fit needs at least 4 positions", poses=self.poses)
        x0, x1, y0, y1, z0, z1 = self.region
        if not (x0 < x1 and y0 < y1 and z0 < z1) or not all(math.isfinite(v) for v in self.region):
            raise ParameterError("{region}: XMIN,XMAX,YMIN,YMAX,ZMIN,ZMAX (metres, robot frame) needs each min below "
                                 "its max", region=self.region)
        if len(self.offset_m) != 3 or not all(math.isfinite(v) and abs(v) < 0.5 for v in self.offset_m):
            raise ParameterError("{offset_m}: X,Y,Z is the marker centre from the TCP in metres (tool frame)",
                                 offset_m=self.offset_m)
        if not (math.isfinite(self.settle_s) and 0 <= self.settle_s <= 30):
            raise ParameterError("{settle_s}: seconds in [0, 30]", settle_s=self.settle_s)
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ParameterError("{speed}: must be a positive number of m/s", speed=self.speed)
        if not (math.isfinite(self.acc) and self.acc > 0):
            raise ParameterError("{acc}: must be a positive number of m/s^2", acc=self.acc)
        if self.poses > MAX_POSES:
            each = self.seconds_per_position()
            raise ParameterError(f"{{poses}}: at most {MAX_POSES} (each position takes about {each:.1f} s, its move "
                                 f"at {{speed}} plus {{settle_s}}: {_duration(self.poses * each)} in all)",
                                 poses=self.poses, speed=self.speed, settle_s=self.settle_s)

    def seconds_per_position(self) -> float:
        """A rough time per position: the moveL over one grid step (accelerating at acc to speed and
        back) and the settle wait; the frame and the marker detection are not counted."""
        x0, x1, y0, y1, _, _ = self.region
        layers = 2 if self.poses < 12 else 3
        step = math.sqrt((x1 - x0) * (y1 - y0) / math.ceil(self.poses / layers))  # the grid's spacing
        ramp = self.speed ** 2 / self.acc  # the distance spent speeding up and slowing down
        move = step / self.speed + self.speed / self.acc if step >= ramp else 2 * math.sqrt(step / self.acc)
        return move + self.settle_s


def _duration(seconds: float) -> str:
    """'12 min' or '1,234 h'."""
    return f"{seconds / 60:.0f} min" if seconds < 5400 else f"{seconds / 3600:,.0f} h"


def plan_positions(cfg: CollectConfig) -> list[list[float]]:
    """cfg.poses TCP poses on a grid over cfg.region: two or three heights (a fit needs the points
    off one line; heights keep them off one plane as well), each layer in serpentine order so
    that each move is short."""
    x0, x1, y0, y1, z0, z1 = cfg.region
    layers = 2 if cfg.poses < 12 else 3
    per_layer = math.ceil(cfg.poses / layers)
    nx = max(2, round(math.sqrt(per_layer * (x1 - x0) / (y1 - y0))))
    ny = max(2, math.ceil(per_layer / nx))
    cells = [(i, j) for i in range(nx) for j in range(ny)]
    poses = []
    for k, z in enumerate(np.linspace(z1, z0, layers)):
        # the layer's share spread over its grid; odd layers mirrored, so that layers do not stack
        picked = [cells[c] for c in np.unique(np.round(np.linspace(0, len(cells) - 1, min(per_layer, len(cells))))
                                              .astype(int))]
        picked = [(i, ny - 1 - j) if k % 2 else (i, j) for i, j in picked]
        picked.sort(key=lambda c: (c[0], c[1] if c[0] % 2 == 0 else -c[1]))  # serpentine
        if k % 2:
            picked.reverse()
        for i, j in picked:
            x, y = x0 + (x1 - x0) * i / (nx - 1), y0 + (y1 - y0) * j / (ny - 1)
            poses.append([float(x), float(y), float(z), *cfg.orientation])
    return poses[:cfg.poses]


def check_plan(poses: list[list[float]], start: list[float], envelope: Envelope) -> None:
    """Refuse the whole plan if any pose, or the straight path to it (from START, then pose to
    pose, and back to START), leaves the envelope; nothing has moved then."""
    for i, pose in enumerate(poses, start=1):
        reason = envelope.pose_reason(pose) or envelope.path_reason(start if i == 1 else poses[i - 2], pose)
        if reason:
            raise SafetyError(f"calibration position {i} {[round(v, 3) for v in pose[:3]]} refused: {reason}")
    reason = envelope.path_reason(poses[-1], start)
    if reason:
        raise SafetyError(f"the way back to the start pose is refused: {reason}")


def marker_point(tcp_pose: list[float], offset_m) -> np.ndarray:
    """Robot-frame position of the marker centre: the TCP plus the offset turned by the tool's rotation."""
    rot = cv2.Rodrigues(np.asarray(tcp_pose[3:], np.float64))[0]
    return np.asarray(tcp_pose[:3], np.float64) + rot @ np.asarray(offset_m, np.float64)


@dataclass
class Collected:
    camera: np.ndarray  # [N, 3] marker centres, camera frame
    robot: np.ndarray  # [N, 3] marker centres, robot frame
    positions: list[int]  # plan position (1-based) of each pair
    skipped: list[tuple[int, str]]  # plan position and why no pair came from it


def collect_pairs(robot: RobotBase, camera: Camera, spec: MarkerSpec, poses: list[list[float]], cfg: CollectConfig,
                  echo: Callable[[str], None] = lambda line: None, recorder: Recorder | None = None) -> Collected:
    """Move to each pose, wait cfg.settle_s, read a frame and the TCP, and pair the marker's camera
    point with its robot point; positions without a usable sighting are skipped. Returns to the
    start pose at the end, also when the camera runs out of frames (then a CameraError). RECORDER
    gets each position's frame, poses and sighting."""
    start = robot.tcp_pose()
    cam_pts, rob_pts, used, skipped = [], [], [], []
    for i, pose in enumerate(poses, start=1):
        robot.move_l(pose, cfg.speed, cfg.acc)
        if cfg.settle_s:
            time.sleep(cfg.settle_s)
        try:
            frame = camera.read()
        except StopIteration:  # a folder of frames used up
            robot.move_l(start, cfg.speed, cfg.acc)
            raise CameraError(f"the camera has no frame left for position {i} of {len(poses)}; give one frame per "
                              "position") from None
        frame_ns = time.time_ns()
        tcp = robot.tcp_pose()
        sighting, why = detect_marker(frame, spec)
        if recorder is not None:
            recorder.add(CalibrationSighting(i, frame, frame_ns, pose, tcp, None if sighting is None else
                                             [float(v) for v in sighting.point_camera_m],
                                             [float(v) for v in marker_point(tcp, cfg.offset_m)], why or ""))
        if sighting is None:
            skipped.append((i, why))
            echo(f"position {i}/{len(poses)}: skipped, {why}")
            continue
        cam_pts.append(sighting.point_camera_m)
        rob_pts.append(marker_point(tcp, cfg.offset_m))
        used.append(i)
        echo(f"position {i}/{len(poses)}: marker at {np.round(sighting.point_camera_m, 4).tolist()} m (camera), "
             f"{sighting.depth_pixels} depth pixels")
    robot.move_l(start, cfg.speed, cfg.acc)
    return Collected(np.array(cam_pts).reshape(-1, 3), np.array(rob_pts).reshape(-1, 3), used, skipped)
