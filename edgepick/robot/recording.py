"""`pick --record` and `calibrate collect --record`: what the cell saw and did, as one MCAP file that
Foxglove and Rerun open (docs/contracts.md#recordings has the topics and frames).

Recording must not cost the arm time: the loop hands each cycle's arrays and values over once
its commands are sent, and a worker thread encodes the images (JPEG colour, lossless depth and
labels) and writes them, Zstandard-compressed, while the loop goes on. The file is written under
a temporary sibling name and takes its final name once its summary (the index a reader seeks
with) is written: at the end, and also when the run stops on Ctrl-C, SIGTERM, a robot halt or an
error, so that what was recorded up to then is a valid, readable file.
"""

from __future__ import annotations

import contextlib
import json
import os
import queue
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import cv2
import numpy as np

from edgepick.errors import ConfigError
from edgepick.files import public_mode
from edgepick.frames import Frame
from edgepick.robot.cycle import CycleResult
from edgepick.robot.markers import (
    BASE,
    BLUE,
    CAMERA,
    GREEN,
    GREY,
    camera_calibration,
    grasp_markers,
    image_annotations,
    point_cloud,
    scene_objects,
)
from edgepick.robot.messages import quaternion, schemas, set_pose
from edgepick.robot.pick import Step
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import draw_overlay
from edgepick.runtime.grasp_record import Grasp

JPEG_QUALITY = 90
WORKER_NICE = 10  # the writer thread yields the CPU to the loop's inference when both want it
TCP = "tcp"  # the tool's frame, beside markers.py's base and camera (docs/contracts.md#recordings)


@dataclass
class StepDone:
    """One step of a plan as it was carried out: when (wall ns), what, and the TCP the robot
    reported after it (None when it could not be read)."""

    time_ns: int
    step: Step
    reported: list[float] | None
    result: str  # "ok" or "error: ..."


@dataclass
class SceneChange:
    """How a clutter-removal round's table changed over one cycle (sim/clutter.py): its parts as the
    frame showed them and once the rest had settled after the pick, each {"id", "class", "pose"
    [x, y, z, qx, qy, qz, qw] in the base frame, "size"}; the id of the part the pick took off
    (None: none), when the rest had settled (wall ns), why the round ends here (None: it goes on),
    and the ids of the parts that left the tray otherwise."""

    round: int
    pick: int
    before: list[dict]
    after: list[dict]
    removed: int | None
    settled_ns: int
    ended: str | None
    fell: list[int] = field(default_factory=list)

    def summary(self) -> dict:
        """The cycle's "round" as `pick` prints it: the round, the pick, what left the table, what is left."""
        return {"round": self.round, "pick": self.pick, "removed": self.removed, "fell": self.fell,
                "left": len(self.after), "ended": self.ended}


@dataclass
class PickCycle:
    """What `pick` hands the recorder per cycle (docs/contracts.md#recordings, "/pick/cycle")."""

    cycle: int
    frame: Frame
    frame_ns: int  # wall time the frame was read
    labels: np.ndarray
    records: list[Grasp]
    chosen: Grasp | None
    plan: list[Step]
    start_pose: list[float] | None  # the arm's pose the plan starts from (None: plan only, from home)
    result: CycleResult
    steps: list[StepDone]
    line: str  # the line `pick` printed for it
    scene: SceneChange | None = None  # a clutter-removal round's table before the pick and after it settled


@dataclass
class CalibrationSighting:
    """What `calibrate collect` hands the recorder per position."""

    position: int
    frame: Frame
    frame_ns: int
    commanded: list[float]
    reported: list[float]
    camera_point: list[float] | None  # the marker centre seen (None: not seen)
    robot_point: list[float]
    reason: str  # why no pair came from it ("" when one did)


class Recorder:
    """An MCAP file being written: `with Recorder(path, metadata) as rec: rec.add(cycle)`.
    Opening it checks that PATH can be written (a ConfigError names OPTION); `add` queues work
    for the writer thread and returns at once."""

    def __init__(self, path: str | Path, metadata: dict, calibration: Calibration | None = None,
                 option: str = "--record"):
        self.path, self.calibration = Path(path), calibration
        self._error: ConfigError | None = None
        self.msgs = schemas()  # the [record] extra, or one line saying how to install it
        from mcap_protobuf.writer import Writer

        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".partial", dir=self.path.parent)
        except OSError as exc:
            raise ConfigError(f"{option} {path}: cannot write there ({exc.strerror})") from None
        self.tmp = Path(tmp)
        self._file = os.fdopen(fd, "wb")
        self.writer = Writer(self._file)
        self.writer.add_metadata("edgepick", {k: v if isinstance(v, str) else json.dumps(v) for k, v in metadata.items()})
        self.busy_s = 0.0  # the writer thread's time on encoding and writing (benchmarks/recording.py)
        self._camera_known = False
        self.first_ns: int | None = None  # the first frame's time
        self._queue: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._work, name="edgepick-recorder", daemon=True)
        self._thread.start()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def add(self, item: PickCycle | CalibrationSighting | Callable[[], None]) -> None:
        """Queue a cycle, a sighting, or any writing (a callable) for the writer thread."""
        if self.first_ns is None and isinstance(item, PickCycle | CalibrationSighting):
            self.first_ns = item.frame_ns
        self._queue.put(item)

    def close(self) -> None:
        """Write what is queued, the summary, and give the file its name; a run that recorded no
        frame (it failed before its first) leaves no file. Idempotent."""
        if self._thread.is_alive():
            self._queue.put(None)
            self._thread.join()
        if self._file.closed:
            return
        try:
            self.writer.finish()
        finally:
            self._file.close()
        if self.first_ns is None:
            self.tmp.unlink()
            return
        public_mode(self.tmp)
        os.replace(self.tmp, self.path)
        if self._error is not None:
            raise self._error

    def _work(self) -> None:
        with contextlib.suppress(AttributeError, OSError):  # Linux: a thread has its own nice value
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), WORKER_NICE)
        while True:
            item = self._queue.get()
            if item is None:
                return
            if self._error is not None:
                continue  # a failed write: what follows is dropped, close() raises it
            start = time.perf_counter()
            try:
                if isinstance(item, PickCycle):
                    self._pick_cycle(item)
                elif isinstance(item, CalibrationSighting):
                    self._sighting(item)
                else:
                    item()
            except Exception as exc:  # noqa: BLE001 - e.g. a full disk: reported by close(), the run goes on
                self._error = ConfigError(f"recording {self.path} failed: {exc}")
            self.busy_s += time.perf_counter() - start

    # -- messages -------------------------------------------------------------------------
    def write(self, topic: str, message, time_ns: int) -> None:
        if message.DESCRIPTOR.fields_by_name.get("timestamp") is not None:
            message.timestamp.FromNanoseconds(time_ns)
        self.writer.write_message(topic, message, log_time=time_ns, publish_time=time_ns)

    def camera(self, frame: Frame, time_ns: int) -> None:
        """The frame's colour (JPEG), depth (16UC1, lossless) and intrinsics; the first frame's
        intrinsics, with the depth scale, also as the "camera" metadata record."""
        m = self.msgs
        if not self._camera_known:
            self.writer.add_metadata("camera", {k: json.dumps(v) for k, v in frame.intrinsics.to_dict().items()})
            self._camera_known = True
        ok, jpeg = cv2.imencode(".jpg", frame.rgb[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        self.write("/camera/color", m.CompressedImage(frame_id=CAMERA, format="jpeg", data=jpeg.tobytes()), time_ns)
        depth = np.ascontiguousarray(frame.depth, np.uint16)
        self.write("/camera/depth", m.RawImage(frame_id=CAMERA, width=depth.shape[1], height=depth.shape[0],
                                               encoding="16UC1", step=2 * depth.shape[1], data=depth.tobytes()), time_ns)
        self.write("/camera/calibration", camera_calibration(m, frame.intrinsics), time_ns)

    def transform(self, cal: Calibration, time_ns: int, tcp: list[float] | None = None) -> None:
        """/tf: base -> camera (robot = R camera + t), and base -> tcp when given."""
        m = self.msgs.FrameTransforms()
        _add_transform(m, CAMERA, cal.t, cal.R, time_ns)
        if tcp is not None:
            _add_transform(m, TCP, tcp[:3], cv2.Rodrigues(np.asarray(tcp[3:6], np.float64))[0], time_ns)
        self.write("/tf", m, time_ns)

    def pose(self, topic: str, pose: list[float], time_ns: int) -> None:
        message = self.msgs.PoseInFrame(frame_id=BASE)
        set_pose(message.pose, pose)
        self.write(topic, message, time_ns)

    def log(self, text: str, time_ns: int, level: int = 2) -> None:
        self.write("/log", self.msgs.Log(level=level, message=text, name="edgepick"), time_ns)

    # -- pick -----------------------------------------------------------------------------
    def _pick_cycle(self, c: PickCycle) -> None:
        m, t = self.msgs, c.frame_ns
        self.camera(c.frame, t)
        labels = np.ascontiguousarray(c.labels, np.uint8)
        self.write("/segmentation/labels", m.RawImage(frame_id=CAMERA, width=labels.shape[1], height=labels.shape[0],
                                                      encoding="mono8", step=labels.shape[1], data=labels.tobytes()), t)
        ok, overlay = cv2.imencode(".jpg", draw_overlay(labels, c.records), [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        self.write("/segmentation/overlay", m.CompressedImage(frame_id=CAMERA, format="jpeg", data=overlay.tobytes()), t)
        self.write("/camera/annotations", image_annotations(m, c.records, c.chosen, t), t)
        plan_ns = t + int(1e6 * c.result.plan_ms)
        if self.calibration is not None:
            self.transform(self.calibration, t, c.start_pose)
        self.write("/grasp/markers", grasp_markers(m, c.records, c.chosen, c.plan, plan_ns), plan_ns)
        posed = [r for r in c.records if r.pose_robot is not None]
        self.write("/grasp/points", point_cloud(m, [r.pose_robot for r in posed],
                                                [GREEN if r is c.chosen else GREY for r in posed]), plan_ns)
        targets = [s.target for s in c.plan if s.target is not None]
        self.write("/plan/targets", point_cloud(m, targets, [BLUE] * len(targets)), plan_ns)
        for done in c.steps:
            if done.step.target is not None:  # a moveL
                self.pose("/robot/tcp_command", done.step.target, done.time_ns)
            else:
                self.write("/robot/gripper", m.GripperState(cycle=c.cycle, command=done.step.command,
                                                            closed=done.step.command == "grip", result=done.result),
                           done.time_ns)
            if done.reported is not None:
                self.pose("/robot/tcp", done.reported, done.time_ns)
                tf = m.FrameTransforms()
                rotation = cv2.Rodrigues(np.asarray(done.reported[3:6], np.float64))[0]
                _add_transform(tf, TCP, done.reported[:3], rotation, done.time_ns)
                self.write("/tf", tf, done.time_ns)
        end_ns = max([plan_ns, *(d.time_ns for d in c.steps)])
        self.write("/pick/cycle", pick_cycle_message(m, c), end_ns)
        self.log(c.line, end_ns, level=2 if c.result.outcome in ("done", "planned") else 3)
        if c.scene is not None:
            self._round_scene(c.scene, c.cycle, t)

    def _round_scene(self, change: SceneChange, cycle: int, frame_ns: int) -> None:
        """A round's table: as the frame showed it (at the frame's time) and where the rest settled after
        the pick (at the time they came to rest), as /round/scene and as solids on /scene/objects."""
        for stage, objects, time_ns in (("before", change.before, frame_ns),
                                        ("settled", change.after, max(change.settled_ns, frame_ns + 1))):
            settled = stage == "settled"
            self.write("/round/scene", self.msgs.RoundScene(
                round=change.round, cycle=cycle, pick=change.pick, stage=stage,
                removed=-1 if change.removed is None or not settled else change.removed,
                ended=str(change.ended or "") if settled else "", objects_json=json.dumps(objects)), time_ns)
            self.write("/scene/objects", scene_objects(self.msgs, objects, time_ns), time_ns)

    # -- calibrate collect ----------------------------------------------------------------
    def _sighting(self, s: CalibrationSighting) -> None:
        m, t = self.msgs, s.frame_ns
        self.camera(s.frame, t)
        self.pose("/robot/tcp_command", s.commanded, t)
        self.pose("/robot/tcp", s.reported, t)
        self.write("/calibration/position", m.CalibrationPosition(
            position=s.position, seen=s.camera_point is not None, reason=s.reason,
            camera_point=s.camera_point or [], robot_point=s.robot_point), t)

    def fitted(self, cal: Calibration, camera: np.ndarray, robot: np.ndarray, time_ns: int) -> None:
        """After collecting: the fitted transform on /tf, stamped with the first position's time (a
        viewer places each frame by the transforms logged up to it), and the pairs as markers at
        TIME_NS (queued)."""
        first_ns = self.first_ns if self.first_ns is not None else time_ns

        def write() -> None:
            self.transform(cal, first_ns)
            update = self.msgs.SceneUpdate()
            entity = update.entities.add(id="pairs", frame_id=BASE)
            entity.timestamp.FromNanoseconds(time_ns)
            for point, colour in [(p, GREEN) for p in robot] + [(p, BLUE) for p in cal.apply(camera)]:
                sphere = entity.spheres.add()
                sphere.pose.position.x, sphere.pose.position.y, sphere.pose.position.z = (float(v) for v in point)
                sphere.pose.orientation.w = 1.0
                sphere.size.x = sphere.size.y = sphere.size.z = 0.01
                sphere.color.r, sphere.color.g, sphere.color.b, sphere.color.a = colour
            self.write("/calibration/pairs", update, time_ns)
            self.log(f"fit: RMSE {cal.rmse_m * 1000:.2f} mm over {cal.n_pairs} pairs", time_ns)

        self.add(write)


def _add_transform(m, child: str, translation, rotation: np.ndarray, time_ns: int) -> None:
    """Append base -> CHILD (a translation and a 3x3 rotation) to a FrameTransforms message."""
    entry = m.transforms.add(parent_frame_id=BASE, child_frame_id=child)
    entry.timestamp.FromNanoseconds(time_ns)
    entry.translation.x, entry.translation.y, entry.translation.z = (float(v) for v in translation)
    entry.rotation.x, entry.rotation.y, entry.rotation.z, entry.rotation.w = quaternion(rotation)


def pick_cycle_message(m, c: PickCycle):
    r, v = c.result, c.result.verdict
    nan = float("nan")
    message = m.PickCycle(
        cycle=c.cycle, frame=str(c.frame.name), objects=len(c.records), outcome=r.outcome,
        reason=str(r.reason or ""), target=str(r.target or ""), pixel=list(r.chosen.pixel) if r.chosen else [],
        start_pose=c.start_pose or [], **{f"{k}_ms": float(r.stage_ms.get(k, nan))
                                          for k in ("pre", "inference", "post", "grasp")},
        plan_ms=float(r.plan_ms), frame_to_command_ms=float(nan if r.frame_to_command_ms is None else r.frame_to_command_ms),
        judged=v is not None, success=v is not None and v.success, failure=str(v.failure or "") if v is not None else "",
        result_json=json.dumps(r.to_dict()), records_json=json.dumps([g.to_dict() for g in c.records]))
    message.frame_time.FromNanoseconds(c.frame_ns)
    return message


def pick_metadata(model: str, classes: list[str] | tuple[str, ...], pick_config, grasp_config, envelope) -> dict:
    """The recording's "edgepick" metadata record: what `replay` needs to redo a cycle's choice."""
    return {"command": "pick", "model": model, "classes": list(classes),
            "pick_config": asdict(pick_config), "grasp_config": asdict(grasp_config), "envelope": asdict(envelope),
            "recorded_at": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
