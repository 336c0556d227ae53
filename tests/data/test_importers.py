"""Importers: tiny Cityscapes, BOP and CVAT trees made here, converted to the native layout."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from edgepick.cli import run
from edgepick.data.importers import ImportConfig, assign_splits, import_dataset
from edgepick.data.native import IGNORE, NativeDataset
from edgepick.errors import ConfigError, DatasetError
from tests.conftest import run_cli

H, W = 24, 32


def write_rgb(path, value=100):
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.zeros((H, W, 3), np.uint8)
    img[..., 0], img[..., 2] = value, 255 - value  # RGB: red channel = value
    assert cv2.imwrite(str(path), img[..., ::-1])


# ------------------------------------------------------------------------------ Cityscapes
def cityscapes_tree(root):
    ids = np.zeros((H, W), np.uint8)  # 0 = unlabeled
    ids[:, 8:16], ids[:, 16:24], ids[:, 24:] = 7, 26, 9  # road, car, parking
    for split, cities in (("train", ["aachen", "bonn"]), ("val", ["lindau"])):
        for k, city in enumerate(cities):
            stem = f"{city}_000000_{k:06d}"
            write_rgb(root / "leftImg8bit" / split / city / f"{stem}_leftImg8bit.png", 10 + k)
            label = root / "gtFine" / split / city / f"{stem}_gtFine_labelIds.png"
            label.parent.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(label), ids)
    return root


@pytest.mark.parametrize("classes, road, car, parking", [("30", 3, 22, 5), ("19", 0, 13, IGNORE)])
def test_cityscapes_class_mapping_and_ignore(tmp_path, classes, road, car, parking):
    summary = import_dataset("cityscapes", cityscapes_tree(tmp_path / "cs"), tmp_path / "out",
                             ImportConfig(cityscapes_classes=classes))
    assert summary["splits"] == {"train": 2, "val": 1, "test": 1}
    meta = json.loads((tmp_path / "out" / "meta.json").read_text())
    assert len(meta["classes"]) == int(classes) and meta["ignore_index"] == IGNORE
    assert meta["classes"][road] == "road" and meta["classes"][car] == "car"
    ds = NativeDataset.open(tmp_path / "out", "test")  # 255 is accepted as ignore
    m = ds.mask(ds.ids[0])
    assert (m[:, :8] == IGNORE).all() and (m[:, 8:16] == road).all() and (m[:, 16:24] == car).all()
    assert (m[:, 24:] == parking).all()
    assert ds.rgb(ds.ids[0]).shape == (H, W, 3)


def test_cityscapes_missing_label_file_leaves_nothing(tmp_path):
    src = cityscapes_tree(tmp_path / "cs")
    next((src / "gtFine" / "val").rglob("*.png")).unlink()
    proc = run_cli("data", "import", "cityscapes", str(src), str(tmp_path / "out"))
    assert proc.returncode == 2 and "label file missing" in proc.stderr and "Traceback" not in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cs"]  # no OUT, no partial folder


# ------------------------------------------------------------------------------------ BOP
def bop_tree(root, images=4):
    scene = root / "test" / "000002"
    gt, cams = {}, {}
    for im in range(images):
        write_rgb(scene / "rgb" / f"{im:06d}.png", 50 + im)
        (scene / "depth").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(scene / "depth" / f"{im:06d}.png"), np.full((H, W), 6000 + im, np.uint16))  # 0.1 mm units
        (scene / "mask_visib").mkdir(exist_ok=True)
        a, b = np.zeros((H, W), np.uint8), np.zeros((H, W), np.uint8)
        a[2:10, 2:10], b[12:20, 20:30] = 255, 255
        cv2.imwrite(str(scene / "mask_visib" / f"{im:06d}_000000.png"), a)
        cv2.imwrite(str(scene / "mask_visib" / f"{im:06d}_000001.png"), b)
        gt[str(im)] = [{"obj_id": 5, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 600]},
                       {"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [10, 0, 600]}]
        cams[str(im)] = {"cam_K": [572.4, 0, 15.5, 0, 573.6, 11.5, 0, 0, 1], "depth_scale": 0.1}
    (scene / "scene_gt.json").write_text(json.dumps(gt))
    (scene / "scene_camera.json").write_text(json.dumps(cams))
    return root


def test_bop_classes_depth_scale_and_intrinsics(tmp_path):
    summary = import_dataset("bop", bop_tree(tmp_path / "lm"), tmp_path / "out")
    assert sum(summary["splits"].values()) == 4 and min(summary["splits"].values()) >= 1 and summary["depth"]
    meta = json.loads((tmp_path / "out" / "meta.json").read_text())
    assert meta["classes"] == ["background", "ape", "can"]  # object ids 1 and 5, sorted
    intr = meta["intrinsics"]
    assert (intr["width"], intr["height"], intr["fx"], intr["fy"], intr["cx"], intr["cy"]) == (W, H, 572.4, 573.6,
                                                                                                 15.5, 11.5)
    assert meta["depth_scale"] == 0.001
    for split in ("train", "val", "test"):
        ds = NativeDataset.open(tmp_path / "out", split)
        for sid in ds.ids:
            m, d = ds.mask(sid), ds.depth(sid)
            assert (m[2:10, 2:10] == 2).all() and (m[12:20, 20:30] == 1).all() and m.sum() == 2 * 64 + 80
            assert d.dtype == np.uint16 and 600 <= int(d[0, 0]) <= 601  # 0.1 mm units -> mm


@pytest.mark.parametrize("damage, message", [("missing-mask", "mask file missing"), ("size", "is 16x12")])
def test_bop_malformed_tree_is_one_line_and_nothing_written(tmp_path, damage, message):
    src = bop_tree(tmp_path / "lm")
    visib = src / "test" / "000002" / "mask_visib" / "000002_000001.png"
    if damage == "missing-mask":
        visib.unlink()
    else:
        cv2.imwrite(str(visib), np.zeros((12, 16), np.uint8))
    proc = run_cli("data", "import", "bop", str(src), str(tmp_path / "out"))
    assert proc.returncode == 2 and message in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["lm"]


# ----------------------------------------------------------------------------------- CVAT
def cvat_tree(root, names=("a", "b", "c", "d")):
    (root / "SegmentationClass").mkdir(parents=True)
    (root / "labelmap.txt").write_text("# label:color_rgb:parts:actions\nbox:250,50,83::\nbackground:0,0,0::\n"
                                       "bearing:51,221,255::\n")
    depth = root.parent / "depth"
    depth.mkdir()
    for k, name in enumerate(names):
        write_rgb(root / "JPEGImages" / f"{name}.png", 20 * k)
        colour = np.zeros((H, W, 3), np.uint8)  # RGB
        colour[:12] = (250, 50, 83)
        colour[12:, 16:] = (51, 221, 255)
        cv2.imwrite(str(root / "SegmentationClass" / f"{name}.png"), colour[..., ::-1])
        cv2.imwrite(str(depth / f"{name}.png"), np.full((H, W), 2500, np.uint16))  # 0.25 mm units
    (root.parent / "intr.json").write_text(json.dumps({"width": W, "height": H, "fx": 30, "fy": 30, "cx": 15.5,
                                                       "cy": 11.5, "depth_scale": 0.00025}))
    return root


def test_cvat_colours_to_classes_with_depth(tmp_path):
    src = cvat_tree(tmp_path / "cvat")
    cfg = ImportConfig(depth=str(tmp_path / "depth"), intrinsics=str(tmp_path / "intr.json"), depth_scale_m=0.00025)
    summary = import_dataset("cvat", src, tmp_path / "out", cfg)
    assert summary["splits"] == {"train": 2, "val": 1, "test": 1}
    meta = json.loads((tmp_path / "out" / "meta.json").read_text())
    assert meta["classes"] == ["background", "box", "bearing"]  # background moved to id 0
    assert meta["intrinsics"]["fx"] == 30 and meta["depth_scale"] == 0.001
    ds = NativeDataset.open(tmp_path / "out", "train")
    m, d = ds.mask(ds.ids[0]), ds.depth(ds.ids[0])
    assert (m[:12] == 1).all() and (m[12:, 16:] == 2).all() and (m[12:, :16] == 0).all()
    assert (d == 625).all()  # 2500 * 0.25 mm


def test_cvat_unknown_colour_is_refused(tmp_path):
    src = cvat_tree(tmp_path / "cvat")
    bad = cv2.imread(str(src / "SegmentationClass" / "c.png"))
    bad[0, 0] = (1, 2, 3)  # BGR
    cv2.imwrite(str(src / "SegmentationClass" / "c.png"), bad)
    proc = run_cli("data", "import", "cvat", str(src), str(tmp_path / "out"))
    assert proc.returncode == 2 and "(3, 2, 1)" in proc.stderr and "does not list" in proc.stderr
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.partial-*"))


def test_cvat_file_names_with_glob_characters_find_their_images(tmp_path):
    src = cvat_tree(tmp_path / "cvat", names=("a[1]", "b*", "c?", "d"))
    summary = import_dataset("cvat", src, tmp_path / "out")
    assert sum(summary["splits"].values()) == 4


# ------------------------------------------------------------------------ malformed content
# Each bad tree: the CLI says one line naming the file and the field, exits 2, and leaves no OUT.
GT, CAM = "test/000002/scene_gt.json", "test/000002/scene_camera.json"
MASK, JPEG = "SegmentationClass/c.png", "JPEGImages/c.png"
DELETE = object()


def _set(path, keys, value):
    """Change one value of a JSON file (DELETE removes it)."""
    data = json.loads(path.read_text())
    node = data
    for key in keys[:-1]:
        node = node[key]
    if value is DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    path.write_text(json.dumps(data))


def _rename(path, old, new):
    data = json.loads(path.read_text())
    data[new] = data.pop(old)
    path.write_text(json.dumps(data))


def _labelmap(text):
    return lambda src: (src / "labelmap.txt").write_text(text)


def _first(src, pattern):
    return sorted(src.rglob(pattern))[0]


def _cut_jpeg(path):
    """PATH replaced by a JPEG of the same name whose second half is missing (a copy cut short)."""
    img = (np.random.default_rng(0).random((H, W, 3)) * 255).astype(np.uint8)
    ok, data = cv2.imencode(".jpg", img)
    path.unlink()
    path.with_suffix(".jpg").write_bytes(data.tobytes()[: len(data) // 2])


BAD = [
    # BOP scene_gt.json
    ("bop", lambda s: (s / GT).write_text("[]"), ["scene_gt.json", "must be a JSON object"]),
    ("bop", lambda s: _set(s / GT, ["0", 0, "obj_id"], "5"), ["scene_gt.json", "image 0[0].obj_id", "number"]),
    ("bop", lambda s: _set(s / GT, ["0", 1, "obj_id"], DELETE), ["scene_gt.json", "image 0[1]", "'obj_id'"]),
    ("bop", lambda s: _set(s / GT, ["1", 0, "obj_id"], 0), ["scene_gt.json", "image 1[0].obj_id", "1 or more"]),
    ("bop", lambda s: _set(s / GT, ["1", 0, "obj_id"], 2.5), ["scene_gt.json", "obj_id", "whole number"]),
    ("bop", lambda s: _set(s / GT, ["1", 0, "obj_id"], True), ["scene_gt.json", "obj_id", "number"]),
    ("bop", lambda s: _set(s / GT, ["2"], {"obj_id": 5}), ["scene_gt.json", "image 2", "must be a list"]),
    ("bop", lambda s: _set(s / GT, ["2"], [5]), ["scene_gt.json", "image 2[0]", "JSON object"]),
    ("bop", lambda s: _rename(s / GT, "3", "three"), ["scene_gt.json", "image id 'three'", "whole number"]),
    ("bop", lambda s: _rename(s / GT, "3", "-3"), ["scene_gt.json", "image id '-3'", "whole number"]),
    ("bop", lambda s: _rename(s / GT, "3", "01"), ["scene_gt.json", "image 1 twice"]),
    ("bop", lambda s: (s / GT).write_bytes(b"\x89PNG\r\n\x1a\n\0\0\0\rIHDR"), ["scene_gt.json", "not a text file"]),
    ("bop", lambda s: (s / GT).write_bytes('{"0": [{"obj_id": 5, "note": "café"}]}'.encode("latin-1")),
     ["scene_gt.json", "not UTF-8"]),
    ("bop", lambda s: (s / GT).write_text('{"0": [{"obj_id": 5'), ["scene_gt.json", "not valid JSON"]),
    # BOP scene_camera.json
    ("bop", lambda s: (s / CAM).write_bytes(b"\0\1\2\3"), ["scene_camera.json", "not a text file"]),
    ("bop", lambda s: (s / CAM).write_bytes(b'{"0": {"cam_K": "\xff\xfe"}}'), ["scene_camera.json", "not UTF-8"]),
    ("bop", lambda s: (s / CAM).unlink(), ["scene_camera.json", "cannot read"]),
    ("bop", lambda s: (s / CAM).write_text("[1, 2]"), ["scene_camera.json", "must be a JSON object"]),
    ("bop", lambda s: _set(s / CAM, ["2"], DELETE), ["scene_camera.json", "no entry for image 2"]),
    ("bop", lambda s: _set(s / CAM, ["2"], [572.4]), ["scene_camera.json", "image 2", "JSON object"]),
    ("bop", lambda s: _set(s / CAM, ["0", "depth_scale"], float("nan")), ["scene_camera.json", "NaN"]),
    ("bop", lambda s: _set(s / CAM, ["1", "depth_scale"], -0.1), ["scene_camera.json", "image 1.depth_scale",
                                                                  "above 0"]),
    ("bop", lambda s: _set(s / CAM, ["1", "depth_scale"], 0), ["scene_camera.json", "depth_scale", "above 0"]),
    ("bop", lambda s: _set(s / CAM, ["1", "depth_scale"], "0.1"), ["scene_camera.json", "depth_scale", "number"]),
    ("bop", lambda s: _set(s / CAM, ["0", "cam_K"], "572.4 0 15.5 0 573.6 11.5 0 0 1"),
     ["scene_camera.json", "image 0.cam_K", "must be a list"]),
    ("bop", lambda s: _set(s / CAM, ["0", "cam_K", 4], float("nan")), ["scene_camera.json", "NaN"]),
    ("bop", lambda s: _set(s / CAM, ["0", "cam_K", 4], None), ["scene_camera.json", "cam_K[4]", "number"]),
    ("bop", lambda s: _set(s / CAM, ["0", "cam_K", 8], DELETE), ["scene_camera.json", "cam_K", "list of 9"]),
    ("bop", lambda s: _set(s / CAM, ["3", "cam_K", 0], -572.4), ["scene_camera.json", "image 3.cam_K", "focal"]),
    ("bop", lambda s: _set(s / CAM, ["3", "cam_K"], [572.4, 0, 0, 0, 573.6, 0, 15.5, 11.5, 1]),
     ["scene_camera.json", "image 3.cam_K", "row by row"]),
    ("bop", lambda s: _set(s / CAM, ["3"], {"depth_scale": 0.1}), ["scene_camera.json", "image 3", "'cam_K'"]),
    # values no camera has: a depth unit of a metre, a focal length of a nanopixel, a principal point a
    # billion pixels off the image
    ("bop", lambda s: _set(s / CAM, ["1", "depth_scale"], 1000), ["scene_camera.json", "image 1.depth_scale",
                                                                  "[0.001, 10] millimetres per depth unit"]),
    ("bop", lambda s: [_set(s / CAM, [str(i), "cam_K", 0], 1e-9) for i in range(4)],
     ["scene_camera.json", "cam_K[0]", f"must be in [{W / 20:g}, {W * 100:g}] px"]),
    ("bop", lambda s: [_set(s / CAM, [str(i), "cam_K", 5], 1e9) for i in range(4)],
     ["scene_camera.json", "cam_K[5]", "must lie within one image height"]),
    # BOP images
    ("bop", lambda s: _cut_jpeg(s / "test/000002/rgb/000001.png"), ["000001.jpg", "Premature end of JPEG file"]),
    ("bop", lambda s: (s / "test/000002/mask_visib/000001_000000.png").write_bytes(b"\x89PNG\r\n"),
     ["000001_000000.png", "cannot read"]),
    ("bop", lambda s: cv2.imwrite(str(s / "test/000002/depth/000002.png"), np.zeros((H, W), np.uint8)),
     ["000002.png", "uint16"]),
    ("bop", lambda s: cv2.imwrite(str(s / "test/000002/depth/000002.png"), np.zeros((H // 2, W), np.uint16)),
     ["depth/000002.png", f"the image {W}x{H}"]),
    ("bop", lambda s: _set(s / GT, ["0"], [{"obj_id": i} for i in range(1, 256)]), ["255 object ids"]),
    # CVAT labelmap.txt
    ("cvat", _labelmap("box:256,50,83::\nbearing:51,221,255::\n"), ["labelmap.txt:1", "0..255"]),
    ("cvat", _labelmap("box:-1,50,83::\nbearing:51,221,255::\n"), ["labelmap.txt:1", "0..255"]),
    ("cvat", _labelmap("box:250,50::\n"), ["labelmap.txt:1", "name:r,g,b"]),
    ("cvat", _labelmap("box\n"), ["labelmap.txt:1", "name:r,g,b"]),
    ("cvat", _labelmap(":250,50,83::\n"), ["labelmap.txt:1", "no name"]),
    ("cvat", _labelmap("box:250,50,83::\nbox:51,221,255::\n"), ["labelmap.txt:2", "'box' twice"]),
    ("cvat", _labelmap("box:250,50,83::\nbearing:250,50,83::\n"), ["labelmap.txt", "same colour"]),
    ("cvat", _labelmap("# nothing\n"), ["labelmap.txt", "lists no labels"]),
    ("cvat", _labelmap("".join(f"l{i}:{i // 256},{i % 256},1::\n" for i in range(300))), ["labelmap.txt", "300 labels"]),
    ("cvat", lambda s: (s / "labelmap.txt").write_bytes(b"\0\0\0\0PK\3\4"), ["labelmap", "not a text file"]),
    ("cvat", lambda s: (s / "labelmap.txt").write_bytes("caf\xe9:1,2,3::\n".encode("latin-1")),
     ["labelmap", "not UTF-8"]),
    # CVAT images and masks
    ("cvat", lambda s: write_rgb(s / "JPEGImages" / "c.jpg"), ["c.png", "c.jpg", "SegmentationClass/c.png"]),
    ("cvat", lambda s: (s / JPEG).write_bytes(b"GIF89a"), ["JPEGImages/c.png", "cannot read image"]),
    ("cvat", lambda s: _cut_jpeg(s / JPEG), ["JPEGImages/c.jpg", "Premature end of JPEG file"]),
    ("cvat", lambda s: (s / MASK).write_bytes(b""), ["SegmentationClass/c.png", "cannot read mask"]),
    ("cvat", lambda s: cv2.imwrite(str(s / MASK), np.zeros((H, W, 3), np.uint16)), ["c.png", "16-bit"]),
    ("cvat", lambda s: cv2.imwrite(str(s / MASK), np.zeros((H // 2, W, 3), np.uint8)), ["c.png", "differ in size"]),
    ("cvat", lambda s: cv2.imwrite(str(s.parent / "depth" / "c.png"), np.zeros((H, W), np.uint8)),
     ["depth/c.png", "uint16"]),
    # the depth camera's intrinsics (read by edgepick.geometry.Intrinsics.load)
    ("cvat", lambda s: (s.parent / "intr.json").write_text('{"width": 32, "height": 24, "fx": inf, "fy": 30, '
                                                             '"cx": 15.5, "cy": 11.5}'), ["intr.json"]),
    ("cvat", lambda s: _set(s.parent / "intr.json", ["fx"], float("inf")), ["intr.json"]),
    ("cvat", lambda s: (s.parent / "intr.json").write_bytes(b'{"width": "\xff"}'), ["intr.json"]),
    ("cvat", lambda s: _set(s.parent / "intr.json", ["fx"], 1e-9), ["intr.json", "fx must be in [1.6, 3200] px"]),
    ("cvat", lambda s: _set(s.parent / "intr.json", ["cy"], -1e9), ["intr.json", "cy must lie within one image"]),
    ("cvat", lambda s: _set(s.parent / "intr.json", ["depth_scale"], 1000), ["intr.json", "depth_scale must be in"]),
    # Cityscapes
    ("cityscapes", lambda s: cv2.imwrite(str(_first(s / "gtFine", "*.png")), np.zeros((H, W), np.uint16)),
     ["_gtFine_labelIds.png", "16-bit"]),
    ("cityscapes", lambda s: cv2.imwrite(str(_first(s / "gtFine", "*.png")), np.zeros((H, W, 3), np.uint8)),
     ["_gtFine_labelIds.png", "single-channel"]),
    ("cityscapes", lambda s: cv2.imwrite(str(_first(s / "gtFine", "*.png")), np.full((H, W), 40, np.uint8)),
     ["_gtFine_labelIds.png", "label id 40"]),
    ("cityscapes", lambda s: _first(s / "gtFine", "*.png").write_bytes(b"\x89PNG\r\n\x1a\n"),
     ["_gtFine_labelIds.png", "cannot read label image"]),
    ("cityscapes", lambda s: _first(s / "leftImg8bit", "*.png").write_bytes(b"\xff\xd8\xff\xe0"),
     ["_leftImg8bit.png", "cannot read image"]),
    ("cityscapes", lambda s: cv2.imwrite(str(_first(s / "gtFine", "*.png")), np.zeros((H, W // 2), np.uint8)),
     ["_leftImg8bit.png", "differ in size"]),
]
TREES = {"bop": lambda t: bop_tree(t / "lm"), "cvat": lambda t: cvat_tree(t / "cvat"),
         "cityscapes": lambda t: cityscapes_tree(t / "cs")}


@pytest.mark.parametrize("fmt, damage, needles", BAD, ids=[f"{f}-{i}-{n[-1][:24]}" for i, (f, _, n) in enumerate(BAD)])
def test_malformed_content_is_one_line_exit_2_and_nothing_left(tmp_path, capfd, fmt, damage, needles):
    src = TREES[fmt](tmp_path)
    damage(src)
    extra = (["--depth", str(tmp_path / "depth"), "--intrinsics", str(tmp_path / "intr.json"), "--depth-scale",
              "0.00025"] if fmt == "cvat" else [])
    capfd.readouterr()
    code = run(["data", "import", fmt, str(src), str(tmp_path / "out"), *extra])
    out, err = capfd.readouterr()
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("edgepick: error: "), err
    for needle in needles:
        assert needle in lines[0], lines[0]
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.partial-*"))


@pytest.mark.parametrize("scale, needle", [("1000", "--depth-scale 1000.0: must be in [1e-06, 0.01] metres per depth"),
                                           ("0.002", "depth/c.png holds 40000 units, 80 m at this scale")])
def test_a_cvat_depth_scale_no_camera_has_is_one_line_and_nothing_left(tmp_path, capfd, scale, needle):
    """A depth scale that would clip every depth pixel at the 65.535 m a millimetre PNG holds: refused
    by its range, or by the depth it makes of an image, never written clipped."""
    src = cvat_tree(tmp_path / "cvat")
    cv2.imwrite(str(tmp_path / "depth" / "c.png"), np.full((H, W), 40000, np.uint16))
    capfd.readouterr()
    code = run(["data", "import", "cvat", str(src), str(tmp_path / "out"), "--depth", str(tmp_path / "depth"),
                "--intrinsics", str(tmp_path / "intr.json"), "--depth-scale", scale])
    lines = [line for line in capfd.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and needle in lines[0], lines
    assert not (tmp_path / "out").exists() and not list(tmp_path.glob(".out.partial-*"))


def test_there_are_at_least_20_bad_trees():
    assert len(BAD) >= 20 and {f for f, _, _ in BAD} == set(TREES)


def test_import_refuses_unknown_format_missing_source_and_bad_splits(tmp_path):
    with pytest.raises(ConfigError, match="fmt='.*': must be one of cityscapes, bop, cvat"):
        import_dataset("voc", tmp_path, tmp_path / "o")
    with pytest.raises(DatasetError, match="does not exist"):
        import_dataset("bop", tmp_path / "nope", tmp_path / "o")
    with pytest.raises(ConfigError, match="split_fractions=.*sum to 1"):
        import_dataset("bop", tmp_path, tmp_path / "o", ImportConfig(split_fractions=(0.5, 0.1, 0.1)))
    with pytest.raises(DatasetError, match="too few"):
        assign_splits(["a", "b"], (0.8, 0.1, 0.1))


def test_assign_splits_is_deterministic_and_fills_every_split():
    names = [f"img{i}" for i in range(50)]
    a, b = assign_splits(names, (0.8, 0.1, 0.1)), assign_splits(list(reversed(names)), (0.8, 0.1, 0.1))
    assert a == b
    assert [list(a.values()).count(s) for s in ("train", "val", "test")] == [40, 5, 5]


@pytest.mark.slow
def test_imported_cityscapes_trains_and_evaluates_with_ignored_pixels(tmp_path):
    pytest.importorskip("torch")
    import_dataset("cityscapes", cityscapes_tree(tmp_path / "cs"), tmp_path / "data",
                   ImportConfig(cityscapes_classes="19"))
    run_cli("train", str(tmp_path / "data"), "--out", str(tmp_path / "run"), "--epochs", "1", "--size", "64x32",
            "--batch-size", "2", "--device", "cpu", check=True)
    proc = run_cli("eval", str(tmp_path / "run"), str(tmp_path / "data"), "--split", "test", check=True)
    result = json.loads(proc.stdout)
    assert len(result["classes"]) == 19 and len(result["confusion_matrix"]) == 19
    assert result["pixels"] == H * 16  # road + car columns; unlabeled and parking (255) are not scored
