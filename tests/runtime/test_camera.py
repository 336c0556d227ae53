"""Frame sources: a folder of PNGs (plain or a native data set), the synthetic stream, RealSense errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from edgepick.cli.cameras import open_camera
from edgepick.data.synth import SynthConfig, synthesize
from edgepick.frames import CameraError
from edgepick.geometry import Intrinsics, Size
from edgepick.runtime.camera import FolderCamera, RealSenseCamera
from edgepick.sim.camera import SynthCamera


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    out = tmp_path_factory.mktemp("cam") / "data"
    synthesize(out, SynthConfig(scenes=5, width=160, height=120, seed=1, splits=(2, 1, 2)), progress=False)
    return out


def plain_folder(root, n=3, size=(120, 160), depth_size=None):
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    for i in range(n):
        rgb = np.full(size + (3,), 10 * i, np.uint8)
        rgb[..., 0] = 200  # red in RGB order
        cv2.imwrite(str(root / "rgb" / f"f{i}.png"), rgb[..., ::-1])
        cv2.imwrite(str(root / "depth" / f"f{i}.png"), np.full(depth_size or size, 500 + i, np.uint16))
    (root / "intrinsics.json").write_text(json.dumps(Intrinsics.d415(size[1], size[0]).to_dict()))
    return root


def test_folder_of_a_native_data_set_gives_frames_with_truth(dataset):
    with FolderCamera(dataset) as cam:  # DATA -> its test split
        frames = list(cam)
    assert [f.name for f in frames] == ["000000", "000001"]
    meta = json.loads((dataset / "meta.json").read_text())
    for f in frames:
        assert f.rgb.shape == (120, 160, 3) and f.rgb.dtype == np.uint8
        assert f.depth.shape == (120, 160) and f.depth.dtype == np.uint16
        assert f.intrinsics.to_dict() == meta["intrinsics"]
        assert f.truth == json.loads((dataset / "test" / "grasps.json").read_text())[f.name]
    with FolderCamera(dataset / "train") as cam:
        assert len(list(cam)) == 2


def test_plain_folder_reads_rgb_in_rgb_order_and_loops(tmp_path):
    cam = FolderCamera(plain_folder(tmp_path / "cap"), loop=True)
    names = [cam.read().name for _ in range(5)]
    assert names == ["f0", "f1", "f2", "f0", "f1"]
    f = FolderCamera(tmp_path / "cap").read()
    assert f.rgb[0, 0, 0] == 200 and f.depth[0, 0] == 500 and f.truth is None


@pytest.mark.parametrize("case, message", [
    ("no-intrinsics", "intrinsics"), ("no-depth", "lacks"), ("no-frames", "no rgb"), ("size", "must agree")])
def test_folder_refuses_broken_captures(tmp_path, case, message):
    root = tmp_path / "cap"
    if case == "no-frames":
        (root / "rgb").mkdir(parents=True)
        (root / "intrinsics.json").write_text(json.dumps(Intrinsics.d415(160, 120).to_dict()))
    else:
        plain_folder(root, depth_size=(60, 80) if case == "size" else None)
    if case == "no-intrinsics":
        (root / "intrinsics.json").unlink()
    if case == "no-depth":
        (root / "depth" / "f1.png").unlink()
    with pytest.raises(CameraError, match=message):
        FolderCamera(root).read()


def test_synth_stream_is_deterministic_and_carries_truth():
    a, b = SynthCamera(160, 120, seed=3, frames=2), SynthCamera(160, 120, seed=3)
    fa, fb = a.read(), b.read()
    assert np.array_equal(fa.rgb, fb.rgb) and np.array_equal(fa.depth, fb.depth)
    assert fa.truth and {"class", "pixel", "point_camera_m"} <= set(fa.truth[0])
    assert not np.array_equal(a.read().rgb, fa.rgb)  # a new scene per frame
    with pytest.raises(StopIteration):
        a.read()


def test_open_camera_specs(tmp_path):
    assert isinstance(open_camera("synth:5", Size(160, 120)), SynthCamera)
    assert isinstance(open_camera(f"dir:{plain_folder(tmp_path / 'c')}"), FolderCamera)
    assert isinstance(open_camera("realsense:123"), RealSenseCamera)  # not opened: touches no device
    with pytest.raises(CameraError, match="unknown camera"):
        open_camera("webcam")


def test_realsense_without_a_device_is_a_clear_error():
    # With the [camera] extra this is pyrealsense2 finding no device; without it, the install hint.
    with pytest.raises(CameraError, match="no RealSense device|camera extra"):
        with RealSenseCamera():
            pass
