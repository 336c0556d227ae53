"""`edgepick replay`: a `pick --record` recording, read back, and each cycle's choice made again.

Without a model, the grasp step runs on the recorded label maps, depth and calibration and the
target is chosen as the run chose it (the same envelope, pick settings and arm pose), so the
same code gives the same choice: a check that a recording explains its run, and the place to
try grasp settings on a failed session's frames. With a model, the recorded colour frames are
segmented again first, so a new model is tried against the frames of a session without the
robot. The colour frames are stored as JPEG (docs/contracts.md#recordings), which a model sees
as a camera's frame plus compression noise; labels and depth are lossless.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from edgepick.errors import EdgepickError
from edgepick.geometry import Intrinsics
from edgepick.robot.clearance import hand_clearance
from edgepick.robot.envelope import Envelope
from edgepick.robot.messages import rotation, schemas
from edgepick.robot.pick import PickConfig, choose_target
from edgepick.runtime.calibration import Calibration
from edgepick.runtime.grasp import grasp_records
from edgepick.runtime.grasp_config import GraspConfig
from edgepick.runtime.session import Segmenter

SAME_OBJECT_PX = 2.0  # two choices of one class this close are the same object (another model moves a centroid)
FRAME_TOPICS = ("/camera/color", "/camera/depth", "/segmentation/labels")


class RecordingError(EdgepickError):
    """A file that is not a readable edgepick pick recording."""


@dataclass
class RecordedCycle:
    cycle: int
    frame: str
    rgb: np.ndarray  # HxWx3 RGB, decoded from the recorded JPEG
    depth: np.ndarray  # HxW uint16, as recorded
    labels: np.ndarray  # HxW class ids, as the run's model gave them
    start_pose: list[float] | None  # the arm's pose the run planned from (None: from home)
    result: dict  # the cycle's result as `pick` printed it
    # a clutter-removal round's table (/round/scene): round, pick, the parts before the pick and once the rest
    # settled ("before", "settled": each id, class, pose, size), the part removed and why the round ended there
    scene: dict | None = None


@dataclass
class Recording:
    path: Path
    metadata: dict  # the "edgepick" metadata record, values decoded from JSON
    intrinsics: Intrinsics
    calibration: Calibration | None  # base -> camera, from /tf


def _reader(file):
    schemas()  # the [record] extra, or one line saying how to install it
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    return make_reader(file, decoder_factories=[DecoderFactory()])


def _decoded(value: str):
    try:
        return json.loads(value)
    except ValueError:
        return value


def open_recording(path: str | Path) -> Recording:
    """The recording's settings, camera and calibration; RecordingError (one line) for a file that
    is not an MCAP file, has no summary, or was not written by `pick --record`."""
    path = Path(path)
    if not path.is_file():
        raise RecordingError(f"{path}: no such recording")
    try:
        with open(path, "rb") as file:
            reader = _reader(file)
            meta = {m.name: {k: _decoded(v) for k, v in m.metadata.items()} for m in reader.iter_metadata()}
            calibration = None
            for _, _, _, message in reader.iter_decoded_messages(topics=["/tf"]):
                for tf in message.transforms:
                    if tf.child_frame_id == "camera":
                        t = np.array([tf.translation.x, tf.translation.y, tf.translation.z])
                        calibration = Calibration(rotation(tf.rotation), t, float("nan"), 0)
                        break
                if calibration is not None:
                    break
    except EdgepickError:
        raise
    except Exception as exc:  # noqa: BLE001 - the mcap reader's many errors for a file that is not one
        raise RecordingError(f"{path} is not a readable MCAP recording ({type(exc).__name__}: {exc})") from None
    settings = meta.get("edgepick", {})
    if settings.get("command") != "pick":
        what = f"a `{settings['command']}` recording" if settings.get("command") else "not an edgepick recording"
        raise RecordingError(f"{path} is {what}; replay takes the recordings of `edgepick pick --record`")
    if "camera" not in meta:
        raise RecordingError(f"{path} holds no frame (the run stopped before its first cycle)")
    return Recording(path, settings, Intrinsics.from_dict(meta["camera"]), calibration)


def round_scenes(recording: Recording) -> dict[int, dict]:
    """A round's recording (`pick --rounds --record`): per cycle, its round and pick, the parts as its frame
    showed them ("before") and where the rest settled after the pick ("settled"), the part removed
    (None: none) and why the round ended there ("": it went on). Empty for a run of single scenes."""
    scenes: dict[int, dict] = {}
    with open(recording.path, "rb") as file:
        for _, _, _, m in _reader(file).iter_decoded_messages(topics=["/round/scene"], log_time_order=True):
            scene = scenes.setdefault(m.cycle, {"round": m.round, "pick": m.pick})
            scene[m.stage] = json.loads(m.objects_json)
            if m.stage == "settled":
                scene.update(removed=None if m.removed < 0 else m.removed, ended=m.ended or None)
    return scenes


def recorded_cycles(recording: Recording) -> Iterator[RecordedCycle]:
    """Each recorded cycle with its frame, in the order of the run (and, in a round, its table)."""
    frames: dict[int, dict] = {}
    scenes = round_scenes(recording)
    with open(recording.path, "rb") as file:
        for _, channel, mcap_message, message in _reader(file).iter_decoded_messages(
                topics=[*FRAME_TOPICS, "/pick/cycle"], log_time_order=True):
            if channel.topic != "/pick/cycle":
                frames.setdefault(mcap_message.log_time, {})[channel.topic] = message
                continue
            shown = frames.pop(message.frame_time.ToNanoseconds(), {})
            if set(shown) != set(FRAME_TOPICS):
                raise RecordingError(f"{recording.path}: cycle {message.cycle} lacks {sorted(set(FRAME_TOPICS) - set(shown))}")
            yield RecordedCycle(message.cycle, message.frame, _colour(shown["/camera/color"]),
                                _raw(shown["/camera/depth"], np.uint16), _raw(shown["/segmentation/labels"], np.uint8),
                                list(message.start_pose) or None, json.loads(message.result_json),
                                scenes.get(message.cycle))


def _colour(message) -> np.ndarray:
    bgr = cv2.imdecode(np.frombuffer(message.data, np.uint8), cv2.IMREAD_COLOR)
    if bgr is None:
        raise RecordingError("a colour frame of the recording is not a JPEG image")
    return np.ascontiguousarray(bgr[..., ::-1])


def _raw(message, dtype) -> np.ndarray:
    return np.frombuffer(message.data, dtype).reshape(message.height, message.width).copy()


def _config(cls, values: dict):
    """A frozen config from its recorded fields (JSON lists back to tuples)."""
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items() if k in names})


def replay(recording: Recording, segmenter: Segmenter | None = None) -> Iterator[dict]:
    """Per recorded cycle: what it chose, what the grasp step (after SEGMENTER, when given) and
    the choice choose now, how far apart the two grasp pixels are, and whether they are the same
    object (the same class, within SAME_OBJECT_PX)."""
    meta = recording.metadata
    classes = segmenter.info.classes if segmenter is not None else meta["classes"]
    pick_cfg = _config(PickConfig, meta["pick_config"])
    grasp_cfg = _config(GraspConfig, meta["grasp_config"])
    envelope = _config(Envelope, meta["envelope"])
    same_table = bool(meta.get("same_table", False))
    tried: list[list[float]] = []  # where the recorded picks went, on one table (choose_target's TRIED)
    for rc in recorded_cycles(recording):
        labels = rc.labels
        if segmenter is not None:
            labels = segmenter.restore(segmenter.infer(segmenter.prepare(rc.rgb)), rc.rgb.shape[:2])
        records = grasp_records(labels, rc.depth, recording.intrinsics, classes, recording.calibration, grasp_cfg)
        clear = hand_clearance(rc.depth, recording.intrinsics, recording.calibration, pick_cfg.hand) \
            if pick_cfg.hand is not None and recording.calibration is not None else None
        chosen, _, note = choose_target(records, envelope, pick_cfg, rc.start_pose, clear=clear, tried=tried)
        if same_table and rc.result.get("pose_robot") and rc.result.get("outcome") in ("done", "stopped"):
            tried.append(rc.result["pose_robot"][:3])
        recorded = {"target": rc.result.get("target"), "pixel": rc.result.get("pixel")}
        now = {"target": None, "pixel": None, "reason": note} if chosen is None else \
            {"target": chosen.cls, "pixel": list(chosen.pixel), "pose_robot": list(chosen.chosen_pose())}
        was = rc.result.get("pixel")
        shift = math.dist(was, chosen.pixel) if was and chosen is not None else None
        same = recorded["target"] == now["target"] and (shift is None or shift <= SAME_OBJECT_PX)
        out = {"cycle": rc.cycle, "frame": rc.frame, "objects": len(records), "recorded": recorded, "replayed": now,
               "same": same, "shift_px": None if shift is None else round(shift, 3)}
        if rc.scene is not None:
            out["round"] = {"round": rc.scene["round"], "pick": rc.scene["pick"],
                            "parts_before": len(rc.scene.get("before", [])), "parts_after": len(rc.scene.get("settled", [])),
                            "removed": rc.scene.get("removed"), "ended": rc.scene.get("ended")}
        yield out
