"""The messages of a recording (docs/contracts.md#recordings): Foxglove's Protobuf schemas where one
fits, so that Foxglove and Rerun both show them, and edgepick's own messages for what no schema
covers (a pick cycle's outcome and timings, the gripper's state, a clutter-removal round's table).

Foxglove's schemas come from `foxglove-schemas-protobuf`; edgepick's own are built here from a
descriptor, so that no generated code or `protoc` is needed. A reader decodes every message
from the schema stored in the file (Protobuf's FileDescriptorSet), as both viewers do.
Everything here imports `mcap`/Protobuf on first use: they are the optional `[record]` extra.
"""

from __future__ import annotations

import functools
import importlib
import math
from collections.abc import Sequence
from types import SimpleNamespace

import cv2
import numpy as np

from edgepick.errors import ConfigError

RECORD_EXTRA = "recording needs the record extra: pip install 'edgepick[record]'"
RECORD_MODULES = ("google.protobuf", "mcap", "mcap_protobuf", "foxglove_schemas_protobuf")

FOXGLOVE_MESSAGES = ("CompressedImage", "RawImage", "CameraCalibration", "FrameTransforms", "PoseInFrame",
                     "PointCloud", "SceneUpdate", "ImageAnnotations", "Log")
# edgepick's own messages: name -> fields (name, type); "double*" is a repeated double
EDGEPICK_MESSAGES = {
    "PickCycle": [("timestamp", "Timestamp"), ("cycle", "uint32"), ("frame", "string"), ("frame_time", "Timestamp"),
                  ("objects", "uint32"),
                  ("outcome", "string"), ("reason", "string"), ("target", "string"), ("pixel", "double*"),
                  ("start_pose", "double*"), ("pre_ms", "double"), ("inference_ms", "double"), ("post_ms", "double"),
                  ("grasp_ms", "double"), ("plan_ms", "double"), ("frame_to_command_ms", "double"),
                  ("judged", "bool"), ("success", "bool"), ("failure", "string"), ("result_json", "string"),
                  ("records_json", "string")],
    "GripperState": [("timestamp", "Timestamp"), ("cycle", "uint32"), ("command", "string"), ("closed", "bool"),
                     ("result", "string")],
    "CalibrationPosition": [("timestamp", "Timestamp"), ("position", "uint32"), ("seen", "bool"),
                            ("reason", "string"), ("camera_point", "double*"), ("robot_point", "double*")],
    "RoundScene": [("timestamp", "Timestamp"), ("round", "uint32"), ("cycle", "uint32"), ("pick", "uint32"),
                   ("stage", "string"), ("removed", "int32"), ("ended", "string"), ("objects_json", "string")],
}


def _field_type(kind: str):
    from google.protobuf import descriptor_pb2

    fdp = descriptor_pb2.FieldDescriptorProto
    return {"uint32": fdp.TYPE_UINT32, "int32": fdp.TYPE_INT32, "double": fdp.TYPE_DOUBLE, "bool": fdp.TYPE_BOOL, "string": fdp.TYPE_STRING,
            "Timestamp": fdp.TYPE_MESSAGE}[kind.rstrip("*")]


@functools.cache
def schemas() -> SimpleNamespace:
    """The message classes by name: Foxglove's (FOXGLOVE_MESSAGES) and edgepick's (EDGEPICK_MESSAGES).
    ConfigError when the [record] extra is missing."""
    try:
        for module in RECORD_MODULES:
            importlib.import_module(module)
    except ModuleNotFoundError as exc:
        raise ConfigError(f"{RECORD_EXTRA} ({exc.name} is not installed)") from None
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory, timestamp_pb2

    foxglove = {name: getattr(importlib.import_module(f"foxglove_schemas_protobuf.{name}_pb2"), name)
                for name in FOXGLOVE_MESSAGES}

    proto = descriptor_pb2.FileDescriptorProto(name="edgepick/recording.proto", package="edgepick", syntax="proto3",
                                               dependency=[timestamp_pb2.DESCRIPTOR.name])
    for name, fields in EDGEPICK_MESSAGES.items():
        message = proto.message_type.add(name=name)
        for number, (field_name, kind) in enumerate(fields, start=1):
            label = descriptor_pb2.FieldDescriptorProto.LABEL_REPEATED if kind.endswith("*") else \
                descriptor_pb2.FieldDescriptorProto.LABEL_OPTIONAL
            entry = message.field.add(name=field_name, number=number, type=_field_type(kind), label=label)
            if kind == "Timestamp":  # "timestamp": when the message's event was; "frame_time": its frame's
                entry.type_name = ".google.protobuf.Timestamp"
    pool = descriptor_pool.Default()
    try:
        pool.FindFileByName(proto.name)
    except KeyError:
        pool.Add(proto)
    own = {name: message_factory.GetMessageClass(pool.FindMessageTypeByName(f"edgepick.{name}"))
           for name in EDGEPICK_MESSAGES}
    return SimpleNamespace(**foxglove, **own)


def quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a 3x3 rotation matrix (Shepperd's method: stable for every rotation)."""
    m = np.asarray(rotation, np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2 * math.sqrt(1 + trace)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * math.sqrt(1 + m[i, i] - m[j, j] - m[k, k])
        v = [0.0, 0.0, 0.0]
        v[i], v[j], v[k] = s / 4, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
        q = (v[0], v[1], v[2], (m[k, j] - m[j, k]) / s)
    return tuple(float(c) for c in q)  # type: ignore[return-value]


def rotation(q) -> np.ndarray:
    """The 3x3 rotation matrix of a quaternion (x, y, z, w) (a message's orientation)."""
    x, y, z, w = (q.x, q.y, q.z, q.w) if hasattr(q, "w") else q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def set_pose(message, pose: Sequence[float]) -> None:
    """Fill a foxglove Pose from a robot pose [x, y, z, rx, ry, rz] (a rotation vector, as the UR takes it)."""
    message.position.x, message.position.y, message.position.z = (float(v) for v in pose[:3])
    q = quaternion(cv2.Rodrigues(np.asarray(pose[3:6], np.float64))[0])
    message.orientation.x, message.orientation.y, message.orientation.z, message.orientation.w = q


def robot_pose(message) -> list[float]:
    """A robot pose [x, y, z, rx, ry, rz] from a foxglove Pose (set_pose's inverse)."""
    rvec = cv2.Rodrigues(rotation(message.orientation))[0].ravel()
    return [message.position.x, message.position.y, message.position.z, *(float(v) for v in rvec)]
