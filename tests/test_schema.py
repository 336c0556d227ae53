"""edgepick/schema.py and every reader built on it (data set meta, intrinsics, grasp truth,
calibration, pairs, BOP scene files; checkpoints in tests/train/test_checkpoint.py): fed mutated
files (random bytes, cut short, a field replaced by any JSON value, NaN and infinities, a field
removed), each reader gives a valid result or edgepick's one-line error, never another exception."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from edgepick.data.bop import read_scene
from edgepick.data.native import read_meta
from edgepick.errors import EdgepickError
from edgepick.frames import read_grasps
from edgepick.geometry import Intrinsics
from edgepick.runtime.calibration import Calibration, read_pairs
from edgepick.schema import FileContentError, Where, as_names, as_number, read_json

INTRINSICS = {"width": 640, "height": 480, "fx": 615.0, "fy": 615.0, "cx": 319.5, "cy": 239.5, "depth_scale": 0.001}
META = {"classes": ["background", "bearing", "disk", "adapter", "box"], "intrinsics": INTRINSICS,
        "depth_scale": 0.001, "generator": {"name": "edgepick.synth"}}
GRASPS = {"000000": [{"class": "box", "pixel": [100.5, 80.0], "angle_deg": 12.0, "orientation_defined": True,
                      "point_camera_m": [0.01, -0.02, 0.7], "visible_fraction": 1.0}],
          "000001": []}
CALIB = {"R": [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "t": [0.3, 0.0, 0.7], "rmse_m": 0.001, "n_pairs": 8}
PAIRS = ("cam_x,cam_y,cam_z,robot_x,robot_y,robot_z\n" + "\n".join(
    ",".join(f"{v:.3f}" for v in (x, y, 0.6 + z, 0.3 + y, x, 0.1 - z)) for x, y, z in
    ((0, 0, 0), (0.1, 0, 0.02), (0, 0.1, 0.04), (0.1, 0.1, 0), (0.05, 0.02, 0.05), (0.02, 0.08, 0.01))) + "\n")

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-10**20, 10**20) | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=8)


def _paths(doc, prefix=()):
    """Every place in a JSON document, as a key path."""
    yield prefix
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc):
            yield from _paths(v, prefix + (i,))


@st.composite
def mutated(draw, doc):
    """DOC with one place replaced by any JSON value or removed, as text; or DOC's text cut short;
    or random bytes."""
    kind = draw(st.sampled_from(["replace", "remove", "cut", "bytes"]))
    text = json.dumps(doc)
    if kind == "bytes":
        return draw(st.binary(max_size=200))
    if kind == "cut":
        return text[:draw(st.integers(0, max(0, len(text) - 1)))].encode()
    doc = copy.deepcopy(doc)
    path = draw(st.sampled_from([p for p in _paths(doc) if p]))
    parent = doc
    for key in path[:-1]:
        parent = parent[key]
    if kind == "remove":
        del parent[path[-1]]
    else:
        parent[path[-1]] = draw(json_values)
    return json.dumps(doc, allow_nan=True).encode()


def _one_line_or_value(reader, path: Path) -> None:
    try:
        reader(path)
    except EdgepickError as exc:
        assert "\n" not in str(exc) and str(exc).strip(), repr(str(exc))


SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


@SETTINGS
@given(content=mutated(META))
def test_data_set_meta(tmp_path, content):
    (tmp_path / "meta.json").write_bytes(content)
    _one_line_or_value(lambda p: read_meta(p.parent), tmp_path / "meta.json")


@SETTINGS
@given(content=mutated(INTRINSICS) | mutated(META))
def test_intrinsics_file_or_a_data_sets_meta(tmp_path, content):
    (tmp_path / "intrinsics.json").write_bytes(content)
    _one_line_or_value(Intrinsics.load, tmp_path / "intrinsics.json")


@SETTINGS
@given(content=mutated(GRASPS))
def test_grasp_truth(tmp_path, content):
    (tmp_path / "grasps.json").write_bytes(content)
    _one_line_or_value(read_grasps, tmp_path / "grasps.json")


@SETTINGS
@given(content=mutated(CALIB))
def test_calibration(tmp_path, content):
    (tmp_path / "calib.json").write_bytes(content)
    _one_line_or_value(Calibration.load, tmp_path / "calib.json")


SCENE_GT = {"0": [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 600]}],
            "1": [{"obj_id": 2}, {"obj_id": 1}]}
SCENE_CAMERA = {"0": {"cam_K": [572.4, 0, 325.3, 0, 573.6, 242.0, 0, 0, 1], "depth_scale": 1.0},
                "1": {"cam_K": [572.4, 0, 325.3, 0, 573.6, 242.0, 0, 0, 1], "depth_scale": 0.1}}


@SETTINGS
@given(gt=mutated(SCENE_GT), camera=mutated(SCENE_CAMERA), which=st.sampled_from(["gt", "camera", "both"]))
def test_bop_scene_files(tmp_path, gt, camera, which):
    (tmp_path / "scene_gt.json").write_bytes(gt if which != "camera" else json.dumps(SCENE_GT).encode())
    (tmp_path / "scene_camera.json").write_bytes(camera if which != "gt" else json.dumps(SCENE_CAMERA).encode())
    _one_line_or_value(lambda p: read_scene(p.parent), tmp_path / "scene_gt.json")


@SETTINGS
@given(cut=st.integers(0, len(PAIRS)), junk=st.binary(max_size=40), at=st.integers(0, len(PAIRS)),
       encoding=st.sampled_from(["utf-8", "latin-1", "utf-16"]))
def test_pairs_file(tmp_path, cut, junk, at, encoding):
    text = PAIRS[:cut] if cut % 2 else PAIRS
    data = text.encode(encoding)
    (tmp_path / "pairs.csv").write_bytes(data[:at] + junk + data[at:])
    _one_line_or_value(read_pairs, tmp_path / "pairs.csv")


def test_pairs_file_in_latin1_is_a_one_line_error(tmp_path):
    (tmp_path / "pairs.csv").write_bytes("cam_x,cam_y,cam_z,robot_x,robot_y,robot_z\n0,0,0.6,0.3,0,0.1 # caf\xe9\n"
                                         .encode("latin-1"))
    with pytest.raises(EdgepickError, match="not UTF-8"):
        read_pairs(tmp_path / "pairs.csv")


@pytest.mark.parametrize("text, message", [
    (b"{\"a\": NaN}", "not a number JSON allows"),
    (b"{\"a\": -Infinity}", "not a number JSON allows"),
    (b"\x00\x01", "not a text file"),
    (b"{\"a\": 1", "not valid JSON"),
    (b"[" * 100_000, "nested too deeply"),
])
def test_read_json_is_strict(tmp_path, text, message):
    (tmp_path / "f.json").write_bytes(text)
    with pytest.raises(FileContentError, match=message):
        read_json(tmp_path / "f.json", "test file")


def test_a_missing_file_and_a_folder_are_one_line(tmp_path):
    with pytest.raises(FileContentError, match="cannot read test file"):
        read_json(tmp_path / "none.json", "test file")
    with pytest.raises(FileContentError, match="is a folder"):
        read_json(tmp_path, "test file")


@pytest.mark.parametrize("value, limits, message", [
    (True, {}, "must be a number, got true"),
    ("3", {}, "must be a number, got the string '3'"),
    (math.inf, {}, "must be a finite number"),
    (2.5, {"integer": True}, "must be a whole number"),
    (0, {"above": 0}, "must be above 0"),
    (-1, {"minimum": 0}, "must be 0 or more"),
    (9, {"maximum": 8}, "must be 8 or less"),
])
def test_numbers_are_checked_and_the_field_named(value, limits, message):
    with pytest.raises(FileContentError, match=f"f.json: size.width {message}"):
        as_number(value, Where("f.json").at("size").at("width"), **limits)


def test_names_must_be_distinct_strings():
    assert as_names(["a", "b"], Where("m")) == ["a", "b"]
    for value, message in ((["a", "a"], "names 'a' twice"), ("ab", "must be a list"), ([1], "non-empty string"),
                           ([""], "non-empty string")):
        with pytest.raises(FileContentError, match=message):
            as_names(value, Where("m").at("classes"))
