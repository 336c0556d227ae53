import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np

from edgepick.data.render import CLASSES, LIGHTINGS
from edgepick.data.synth import SynthConfig, synthesize
from tests.conftest import run_cli


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_same_seed_gives_identical_files_whatever_the_worker_count(tmp_path):
    synthesize(tmp_path / "a", SynthConfig(scenes=6, width=160, height=120, seed=3, splits=(3, 2, 1), workers=1),
               progress=False)
    synthesize(tmp_path / "b", SynthConfig(scenes=6, width=160, height=120, seed=3, splits=(3, 2, 1), workers=2),
               progress=False)
    synthesize(tmp_path / "c", SynthConfig(scenes=6, width=160, height=120, seed=4, splits=(3, 2, 1), workers=1),
               progress=False)
    a, b, c = _files(tmp_path / "a"), _files(tmp_path / "b"), _files(tmp_path / "c")
    assert a == b
    assert a["train/rgb/000000.png"] != c["train/rgb/000000.png"]


def test_layout_follows_contract_3_1(small_data):
    meta = json.loads((small_data / "meta.json").read_text())
    assert meta["classes"] == ["background", "bearing", "disk", "adapter", "box"]
    assert meta["depth_scale"] == 0.001
    for key in ("width", "height", "fx", "fy", "cx", "cy"):
        assert key in meta["intrinsics"]
    assert meta["generator"]["seed"] == 7
    for split, n in (("train", 36), ("val", 8), ("test", 4)):
        for kind in ("rgb", "depth", "mask"):
            assert len(list((small_data / split / kind).glob("*.png"))) == n
        rgb = cv2.imread(str(small_data / split / "rgb" / "000000.png"), cv2.IMREAD_UNCHANGED)
        depth = cv2.imread(str(small_data / split / "depth" / "000000.png"), cv2.IMREAD_UNCHANGED)
        mask = cv2.imread(str(small_data / split / "mask" / "000000.png"), cv2.IMREAD_UNCHANGED)
        assert rgb.shape == (240, 320, 3) and rgb.dtype == np.uint8
        assert depth.shape == (240, 320) and depth.dtype == np.uint16
        assert mask.shape == (240, 320) and mask.dtype == np.uint8 and mask.max() < len(CLASSES)
        grasps = json.loads((small_data / split / "grasps.json").read_text())
        assert len(grasps) == n
        for records in grasps.values():
            for g in records:
                assert g["class"] in CLASSES[1:]
                assert len(g["pixel"]) == 2 and len(g["point_camera_m"]) == 3
                assert -90 < g["angle_deg"] <= 90
                assert 0.3 < g["point_camera_m"][2] < 1.0


def test_all_classes_and_lighting_conditions_over_a_set(small_data):
    classes, lightings = set(), set()
    for split in ("train", "val", "test"):
        scenes = json.loads((small_data / split / "scenes.json").read_text())
        lightings |= {s["lighting"] for s in scenes.values()}
        for sid in scenes:
            mask = cv2.imread(str(small_data / split / "mask" / f"{sid}.png"), cv2.IMREAD_UNCHANGED)
            classes |= set(np.unique(mask).tolist())
    assert classes == set(range(len(CLASSES)))
    assert lightings == set(LIGHTINGS)


def test_depth_is_realistic(small_data):
    """Valid depth near the camera height, holes present (metal, edges, the left band), grasp depth matches."""
    grasps = json.loads((small_data / "train" / "grasps.json").read_text())
    holes = []
    for sid, records in list(grasps.items())[:12]:
        depth = cv2.imread(str(small_data / "train" / "depth" / f"{sid}.png"), cv2.IMREAD_UNCHANGED)
        holes.append((depth == 0).mean())
        assert (depth[:, :3] == 0).all()  # the D415's left invalid band
        valid = depth[depth > 0] / 1000.0
        assert 0.4 < np.median(valid) < 1.0
        for g in records:
            u, v = (int(round(c)) for c in g["pixel"])
            patch = depth[max(v - 3, 0):v + 4, max(u - 3, 0):u + 4]
            if g["class"] in ("box", "adapter") and g["visible_fraction"] > 0.9 and (patch > 0).sum() > 10:
                assert abs(np.median(patch[patch > 0]) / 1000.0 - g["point_camera_m"][2]) < 0.02
    assert 0.01 < np.mean(holes) < 0.3


def test_grasp_truth_lies_on_its_object(small_data):
    grasps = json.loads((small_data / "train" / "grasps.json").read_text())
    hits = total = 0
    for sid, records in grasps.items():
        mask = cv2.imread(str(small_data / "train" / "mask" / f"{sid}.png"), cv2.IMREAD_UNCHANGED)
        for g in records:
            if g["class"] in ("box", "adapter") and g["visible_fraction"] > 0.95:
                u, v = (int(round(c)) for c in g["pixel"])
                total += 1
                hits += CLASSES[mask[min(v, mask.shape[0] - 1), min(u, mask.shape[1] - 1)]] == g["class"]
    assert total > 5 and hits / total > 0.9


def test_refuses_non_empty_output_and_bad_size(tmp_path):
    out = tmp_path / "busy"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    proc = run_cli("data", "synth", str(out), "--scenes", "3")
    assert proc.returncode == 2 and "not empty" in proc.stderr and "Traceback" not in proc.stderr
    assert sorted(p.name for p in out.iterdir()) == ["keep.txt"]
    proc = run_cli("data", "synth", str(tmp_path / "new"), "--size", "640by480")
    assert proc.returncode == 2 and "WIDTHxHEIGHT" in proc.stderr
    assert not (tmp_path / "new").exists()


def test_interrupted_run_leaves_nothing(tmp_path):
    """Ctrl-C in the middle: no OUT, no hidden partial folder."""
    import signal
    import time

    out = tmp_path / "data"
    proc = subprocess.Popen([sys.executable, "-m", "edgepick", "data", "synth", str(out), "--scenes", "3000",
                             "--workers", "1"], cwd=Path(__file__).resolve().parents[2],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            # a shell that runs the suite in the background ignores SIGINT, and children inherit
                            # that: give the child the default disposition, as a terminal would
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))

    def scenes_written() -> int:
        return sum(len(list(p.glob("*/rgb/*.png"))) for p in tmp_path.glob(".data.partial-*"))

    deadline = time.time() + 180  # a loaded 2-core CI machine starts Python slowly
    while time.time() < deadline and scenes_written() < 3 and proc.poll() is None:
        time.sleep(0.05)
    assert proc.poll() is None, "synth ended before it could be interrupted"
    assert scenes_written() >= 3
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode != 0
    assert list(tmp_path.iterdir()) == []


def test_preview_writes_a_contact_sheet(small_data, tmp_path):
    proc = run_cli("data", "preview", str(small_data), "--out", str(tmp_path / "sheet.png"), "--count", "4",
                   check=True)
    sheet = cv2.imread(str(tmp_path / "sheet.png"))
    assert sheet is not None and sheet.shape[1] == 3 * 640
    assert json.loads(proc.stdout)["scenes"] == 4


def test_workers_keep_freed_memory_on_glibc():
    """The pool workers' allocator setting (frame-sized temporaries from the heap, not fresh mmaps)
    takes effect on glibc and is a no-op elsewhere; run in a child so this process keeps its defaults."""
    import platform

    code = "from edgepick.data.synth import _keep_freed_memory; print(_keep_freed_memory())"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[2]).stdout.strip()
    assert out == str(platform.libc_ver()[0] == "glibc")
