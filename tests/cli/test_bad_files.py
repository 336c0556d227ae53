"""What a user's FILES and PATHS say, command by command: malformed data sets, intrinsics, grasp
truth, checkpoints and model metadata; outputs that are links, FIFOs, devices, system folders, the
working folder or over-long names; counts, seeds and environment variables out of range. Each ends
with edgepick's one line on stderr, exit status 2, nothing on stdout, no traceback and nothing
written, before any work.

The workspace is built once (a broken copy of each file kind beside a good one) and every case
runs in-process through `edgepick.cli.run`, as tests/cli/test_bad_input.py does for the flags.
"""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnx")
torch = pytest.importorskip("torch")

from edgepick.cli import run  # noqa: E402
from edgepick.files import mark  # noqa: E402
from edgepick.runtime.calibration import kabsch  # noqa: E402
from tests.cli.test_bad_input import _pairs, _tree, assert_refused  # noqa: E402
from tests.runtime.test_pipeline import red_model  # noqa: E402

ROOT = os.geteuid() == 0  # a device node can be made in a test folder only as root
LONG = "n" * 240  # with edgepick's temporary-name room, over the usual 255-byte name limit


def _dataset(root: Path, source: Path, meta: bytes | None = None, grasps: bytes | None = None) -> Path:
    """A data set whose splits are the images of SOURCE (linked) with its own meta.json and test grasps.json."""
    root.mkdir()
    (root / "meta.json").write_bytes(meta if meta is not None else (source / "meta.json").read_bytes())
    for split in ("train", "val", "test"):
        (root / split).mkdir()
        for sub in ("rgb", "depth", "mask"):
            os.symlink(source / split / sub, root / split / sub)
        original = (source / split / "grasps.json").read_bytes()
        (root / split / "grasps.json").write_bytes(grasps if grasps is not None and split == "test" else original)
    return root


def _meta(source: Path, **change) -> bytes:
    meta = json.loads((source / "meta.json").read_text())
    for key, value in change.items():
        if value is None:
            meta.pop(key, None)
        else:
            meta[key] = value
    return json.dumps(meta).encode()


def _intrinsics(source: Path, **change) -> bytes:
    meta = json.loads((source / "meta.json").read_text())
    meta["intrinsics"] = {**meta["intrinsics"], **change}
    return json.dumps(meta).encode()


def _grasps(source: Path, change) -> bytes:
    grasps = json.loads((source / "test" / "grasps.json").read_text())
    first = next(iter(grasps))
    change(grasps[first][0])
    return json.dumps(grasps).encode()


META = {  # data set meta.json variants -> a word the error must hold
    "meta-binary": (lambda s: bytes(range(256)), "not a text file"),
    "meta-latin1": (lambda s: '{"classes": ["caf\xe9", "b"]}'.encode("latin-1"), "not UTF-8"),
    "meta-notjson": (lambda s: b"classes: [a, b]", "not valid JSON"),
    "meta-list": (lambda s: b"[1, 2]", "must be a JSON object"),
    "meta-str-classes": (lambda s: _meta(s, classes="abcdef"), "classes must be a list"),
    "meta-one-class": (lambda s: _meta(s, classes=["background"]), "classes must list at least 2"),
    "meta-dup-classes": (lambda s: _meta(s, classes=["a", "a", "b", "c", "d"]), "names 'a' twice"),
    "meta-int-classes": (lambda s: _meta(s, classes=[0, 1, 2, 3, 4]), "classes[0] must be a non-empty string"),
    "meta-no-classes": (lambda s: _meta(s, classes=None), "has no field 'classes'"),
    "meta-inf-fx": (lambda s: _intrinsics(s, fx=1e400), "not a number JSON allows"),
    "meta-nan-cx": (lambda s: _intrinsics(s, cx=float("nan")), "not a number JSON allows"),
    "meta-frac-width": (lambda s: _intrinsics(s, width=320.5), "intrinsics.width must be a whole number"),
    "meta-str-height": (lambda s: _intrinsics(s, height="240"), "intrinsics.height must be a number"),
    "meta-neg-fy": (lambda s: _intrinsics(s, fy=-615.0), "intrinsics.fy must be above 0"),
    "meta-zero-scale": (lambda s: _intrinsics(s, depth_scale=0), "intrinsics.depth_scale must be above 0"),
    # values no camera has (docs/contracts.md#intrinsics-and-calibration; the set's images are 320x240)
    "meta-tiny-fx": (lambda s: _intrinsics(s, fx=1e-9), "intrinsics.fx must be in [16, 32000] px"),
    "meta-far-cy": (lambda s: _intrinsics(s, cy=1e9), "intrinsics.cy must lie within one image height"),
    "meta-metre-scale": (lambda s: _intrinsics(s, depth_scale=1000),
                         "intrinsics.depth_scale must be in [1e-06, 0.01] metres per depth unit"),
    "meta-top-scale": (lambda s: _meta(s, depth_scale=1000), "depth_scale must be in [1e-06, 0.01] metres per"),
}
GRASPS = {  # a test split's grasps.json variants
    "grasps-corrupt": (lambda s: b'{"000000": [{"class": "box", "pix', "not valid JSON"),
    "grasps-list": (lambda s: b"[]", "must be a JSON object"),
    "grasps-no-pixel": (lambda s: _grasps(s, lambda g: g.pop("pixel")), "has no 'pixel'"),
    "grasps-str-point": (lambda s: _grasps(s, lambda g: g.update(point_camera_m="0,0,1")), "point_camera_m must be"),
    "grasps-short-pixel": (lambda s: _grasps(s, lambda g: g.update(pixel=[1])), "pixel must be a list of 2"),
    "grasps-class-null": (lambda s: _grasps(s, lambda g: g.update({"class": None})), "class must be a non-empty"),
}


def _checkpoint_variants(best: dict) -> dict[str, tuple[object, str]]:
    def changed(**change):
        ckpt = {k: v for k, v in best.items() if k not in ("optimizer", "scheduler")}
        for key, value in change.items():
            if value is None:
                ckpt.pop(key, None)
            else:
                ckpt[key] = value
        return ckpt

    mc = best["model_config"]
    return {
        "ck-list": ([1, 2, 3], "is not an edgepick checkpoint"),
        "ck-no-model-config": (changed(model_config=None), "is not an edgepick checkpoint"),
        "ck-arch": (changed(model_config={**mc, "arch": "vgg16"}), "model_config.arch must be one of"),
        "ck-num-classes": (changed(model_config={**mc, "num_classes": "five"}), "num_classes must be a number"),
        "ck-model-config-str": (changed(model_config="mobilenetv3"), "model_config must be a JSON object"),
        "ck-unknown-config-field": (changed(model_config={**mc, "depth": 3}), "unknown fields depth"),
        "ck-stride": (changed(model_config={**mc, "output_stride": 4}), "output stride must be 8 or 16"),
        "ck-no-classes": (changed(classes=None), "has no field 'classes'"),
        "ck-classes-count": (changed(classes=["background", "a", "b"]), "names 3 classes but the model has 5"),
        "ck-no-size": (changed(input_size=None), "has no field 'input_size'"),
        "ck-zero-size": (changed(input_size=[0, 0]), "input_size[0] must be 32 or more"),
        "ck-odd-size": (changed(input_size=[36, 44]), "44x36 (WIDTHxHEIGHT) must have sides that are multiples of 8"),
        "ck-33x31": (changed(input_size=[31, 33]), "input_size[0] must be 32 or more, got 31"),
        "ck-unknown-field": (changed(colorspace="hsv"), "has unknown fields colorspace"),
        "ck-model-list": (changed(model=[1, 2]), "model must be a state dict"),
        "ck-epoch": (changed(epoch=-1), "epoch must be 0 or more"),
        "ck-train-config": (changed(train_config="fast"), "train_config must be a JSON object"),
    }


TRAIN_CONFIGS = {  # a run's last.pt whose recorded train_config is bogus (resume, hybrid-QaT)
    "tc-str": ("fast", "train_config must be a JSON object"),
    "tc-no-data": ({"out": "r"}, "has no 'data'"),
    "tc-size": ({"size": "96x128"}, "train_config.size must be a list"),
    "tc-lr": ({"lr": "fast"}, "train_config.lr must be a number"),
    "tc-keep": ({"keep_epochs": [2.5]}, "keep_epochs[0] must be a whole number"),
}


def _onnx_meta(source: Path, out: Path, **change) -> Path:
    import onnx

    model = onnx.load(source)
    for entry in model.metadata_props:
        if entry.key in change:
            entry.value = change[entry.key]
    onnx.save(model, out)
    return out


@pytest.fixture(scope="module")
def bw(tmp_path_factory, small_data, trained_run):
    """The workspace: broken data sets, checkpoints, runs and models, and odd output paths."""
    w = tmp_path_factory.mktemp("bad-files")
    ws = {"W": w, "D": small_data, "RUN": trained_run, "MODEL": red_model(w / "model.onnx")}
    sets = w / "sets"
    sets.mkdir()
    for name, (make, _) in {**META, **GRASPS}.items():
        content = make(small_data)
        ws[name] = _dataset(sets / name, small_data, **({"grasps": content} if name in GRASPS else {"meta": content}))
    cks = w / "ck"
    cks.mkdir()
    best = torch.load(trained_run / "best.pt", map_location="cpu", weights_only=False)
    for name, (ckpt, _) in _checkpoint_variants(best).items():
        torch.save(ckpt, cks / f"{name}.pt")
        ws[name] = cks / f"{name}.pt"
    (cks / "garbage.pt").write_bytes(b"\x80\x04not a pickle at all")
    ws["ck-garbage"] = cks / "garbage.pt"
    last = torch.load(trained_run / "last.pt", map_location="cpu", weights_only=False)
    for name, (value, _) in TRAIN_CONFIGS.items():
        run_dir = w / "runs" / name
        run_dir.mkdir(parents=True)
        config = value if not isinstance(value, dict) or name == "tc-no-data" else {**last["train_config"], **value}
        torch.save({**{k: v for k, v in last.items() if k not in ("optimizer", "scheduler")}, "train_config": config},
                   run_dir / "last.pt")
        (run_dir / "metrics.json").write_text("{}")
        mark(run_dir, "train")
        ws[name] = run_dir
    torch.save([torch.zeros(3)], w / "bb-list.pt")
    torch.save({"backbone.0.0.weight": "not a tensor"}, w / "bb-str.pt")
    (w / "bb-text.pt").write_text("weights")
    for name, change in {"m-frac": {"edgepick.input_size": "[240.5, 320]"},
                         "m-str-classes": {"edgepick.classes": '"abc"'},
                         "m-int-classes": {"edgepick.classes": "[1, 2, 3]"},
                         "m-str-size": {"edgepick.input_size": '"big"'},
                         "m-one-class": {"edgepick.classes": '["background"]'}}.items():
        ws[name] = _onnx_meta(ws["MODEL"], w / f"{name}.onnx", **change)
    _pairs(w / "pairs.csv", *_good_pairs())
    kabsch(*_good_pairs()).save(w / "calib.json")
    (w / "intr.json").write_text(json.dumps({"width": 320, "height": 240, "fx": 300.0, "fy": 300.0, "cx": 160.0,
                                             "cy": 120.0}))
    import cv2

    labels = np.zeros((240, 320), np.uint8)
    cv2.rectangle(labels, (100, 80), (160, 120), 4, -1)
    cv2.imwrite(str(w / "mask.png"), labels)
    cv2.imwrite(str(w / "rgb.png"), np.dstack([labels] * 3))
    cv2.imwrite(str(w / "depth.png"), np.full((240, 320), 600, np.uint16))
    _odd_outputs(w / "o")
    ws["O"] = w / "o"
    return ws


def _good_pairs():
    rng = np.random.default_rng(0)
    cam = rng.uniform(-0.2, 0.2, (8, 3)) + [0, 0, 0.6]
    rot = np.array([[0, -1, 0], [-1, 0, 0], [0, 0, -1]], float)
    return cam, cam @ rot.T + [0.3, 0.1, 0.7]


def _odd_outputs(o: Path) -> None:
    """Per suffix: a link to a file, a dangling link, a link loop, a FIFO (and a device as root);
    a link to a folder, a dangling one and a loop for folder outputs."""
    o.mkdir()
    (o / "target.txt").write_text("the user's")
    (o / "folder").mkdir()
    for ext in (".onnx", ".png", ".json", ".jsonl", ".csv", ""):
        os.symlink(o / "target.txt", o / f"lnk{ext}")
        os.symlink(o / "missing", o / f"dang{ext}")
        os.symlink(o / f"loop{ext}", o / f"loop{ext}")
        os.mkfifo(o / f"fifo{ext}")
        if ROOT:
            os.mknod(o / f"full{ext}", 0o600 | stat.S_IFCHR, os.makedev(1, 7))
    os.symlink(o / "folder", o / "lnkdir")


# command -> (args with {OUT}, the output's suffix, its kind)
WRITERS = {
    "data synth": (["data", "synth", "{OUT}", "--scenes", "3"], "", "dir"),
    "data preview": (["data", "preview", "{D}", "--out", "{OUT}"], ".png", "file"),
    "data import": (["data", "import", "cvat", "{W}/sets", "{OUT}"], "", "dir"),
    "data capture": (["data", "capture", "{OUT}", "--camera", "synth", "--count", "1"], "", "dir"),
    "train": (["train", "{D}", "--out", "{OUT}", "--size", "64x48", "--epochs", "1"], "", "dir"),
    "eval": (["eval", "{MODEL}", "{D}", "--out", "{OUT}"], ".json", "file"),
    "export": (["export", "{RUN}", "--out", "{OUT}"], ".onnx", "file"),
    "quantize static": (["quantize", "static", "{RUN}", "--data", "{D}", "--out", "{OUT}"], ".onnx", "file"),
    "quantize qat --run": (["quantize", "qat", "--data", "{D}", "--out", "{W}/qat.onnx", "--run", "{OUT}"], "",
                           "dir"),
    "quantize hybrid --run": (["quantize", "hybrid", "{RUN}", "--data", "{D}", "--qat-fraction", "0.04", "--out",
                               "{W}/h.onnx", "--run", "{OUT}"], "", "dir"),
    "calibrate": (["calibrate", "{W}/pairs.csv", "--out", "{OUT}"], ".json", "file"),
    "grasp --overlay": (["grasp", "--mask", "{W}/mask.png", "--depth", "{W}/depth.png", "--intrinsics",
                         "{W}/intr.json", "--overlay", "{OUT}"], ".png", "file"),
    "pick --log": (["pick", "--model", "{MODEL}", "--log", "{OUT}"], ".jsonl", "file"),
    "pick --overlay-dir": (["pick", "--model", "{MODEL}", "--log", "{W}/p.jsonl", "--overlay-dir", "{OUT}"], "",
                           "dir"),
    "pick --robot-log": (["pick", "--model", "{MODEL}", "--robot", "ur:127.0.0.1", "--log", "{W}/p.jsonl",
                          "--robot-log", "{OUT}"], ".jsonl", "file"),
    "bench": (["bench", "{MODEL}", "--data", "{D}", "--out", "{OUT}"], "", "dir"),
    "demo": (["demo", "--workdir", "{OUT}"], "", "dir"),
}
OUTPUT_VARIANTS = [("/proc/edgepick/out{ext}", "inside /proc"), ("/sys/edgepick{ext}", "inside /sys"),
                   ("{O}/dang{ext}", "broken symbolic link"), ("{O}/loop{ext}", "broken symbolic link"),
                   ("{O}/fifo{ext}", "FIFO"), ("{O}/" + LONG + "{ext}", "bytes; this file system takes")]
OUTPUT_CASES = []
for _command, (args, ext, kind) in WRITERS.items():
    variants = OUTPUT_VARIANTS + ([("{O}/full{ext}", "character device")] if ROOT else [])
    variants += [("{O}/lnk{ext}", "symbolic link")] if kind == "file" else \
        [("{O}/lnkdir", "symbolic link"), (".", "working folder"), ("{O}/target.txt", "is a file")]
    for path, message in variants:
        OUTPUT_CASES.append(([a.replace("{OUT}", path.replace("{ext}", ext)) for a in args], message))
OUTPUT_CASES += [
    (["calibrate", "{W}/pairs.csv", "--out", "{W}/pairs.csv"], "same path as"),
    (["eval", "{MODEL}", "{D}", "--out", "{MODEL}"], "same path as"),
    (["data", "preview", "{D}", "--out", "{D}/train/rgb/000000.png"], "would overwrite a file of the input"),
    (["grasp", "--mask", "{W}/mask.png", "--depth", "{W}/depth.png", "--intrinsics", "{W}/intr.json", "--overlay",
      "{W}/mask.png"], "same path as"),
    (["pick", "--model", "{MODEL}", "--log", "{W}/same.jsonl", "--robot", "ur:127.0.0.1", "--robot-log",
      "{W}/same.jsonl"], "same path as"),
    (["data", "synth", ""], "OUT is empty"),
    (["eval", "{MODEL}", "{D}", "--out", ""], "--out is empty"),
    (["bench", "{MODEL}", "--data", "{D}", "--out", "{W}/sets"], "not made by edgepick bench"),
    (["demo", "--workdir", "{W}/sets"], "not made by edgepick demo"),
    (["train", "{D}", "--out", "{W}/sets", "--size", "64x48"], "is not empty"),
]

DATA_READERS = {  # commands that read a data set's meta.json (and so its classes and intrinsics)
    "preview": ["data", "preview", "{SET}", "--out", "{W}/p.png"],
    "train": ["train", "{SET}", "--out", "{W}/r", "--size", "64x48", "--epochs", "1"],
    "eval": ["eval", "{MODEL}", "{SET}"],
    "static": ["quantize", "static", "{RUN}", "--data", "{SET}", "--out", "{W}/q.onnx"],
    "bench": ["bench", "{MODEL}", "--data", "{SET}", "--out", "{W}/b"],
}
FRAME_READERS = {  # commands that read a folder camera's intrinsics and grasp truth
    "capture": ["data", "capture", "{W}/cap", "--camera", "dir:{SET}", "--count", "1"],
    "pick": ["pick", "--model", "{MODEL}", "--camera", "dir:{SET}", "--calib", "{W}/calib.json", "--log",
             "{W}/p.jsonl"],
}
CONTENT_CASES = []
for name, (_, message) in META.items():
    readers = {**DATA_READERS, **(FRAME_READERS if "intrinsics" in message or name in ("meta-inf-fx", "meta-nan-cx")
                                  else {})}
    for command in readers.values():
        CONTENT_CASES.append(([a.replace("{SET}", "{" + name + "}") for a in command], message))
for name, (_, message) in GRASPS.items():
    for command in (["data", "preview", "{SET}", "--out", "{W}/p.png", "--split", "test"], *FRAME_READERS.values()):
        CONTENT_CASES.append(([a.replace("{SET}", "{" + name + "}") for a in command], message))
CHECKPOINT_NAMES = [*_checkpoint_variants({"model_config": {}}).items(), ("ck-garbage", (None, "cannot read checkpoint"))]
for name, (_, message) in CHECKPOINT_NAMES:
    for command in (["eval", "{CK}", "{D}"], ["export", "{CK}", "--out", "{W}/e.onnx"],
                    ["quantize", "static", "{CK}", "--data", "{D}", "--out", "{W}/q.onnx"]):
        CONTENT_CASES.append(([a.replace("{CK}", "{" + name + "}") for a in command], message))
for name, (_, message) in TRAIN_CONFIGS.items():
    CONTENT_CASES.append((["train", "{D}", "--out", "{" + name + "}", "--resume"], message))
    CONTENT_CASES.append((["quantize", "hybrid", "{" + name + "}", "--data", "{D}", "--qat-fraction", "0.04", "--out",
                           "{W}/h.onnx"], message))
CONTENT_CASES += [
    (["train", "{D}", "--out", "{W}/r", "--size", "64x48", "--backbone-weights", "{W}/bb-list.pt"], "not a state dict"),
    (["train", "{D}", "--out", "{W}/r", "--size", "64x48", "--backbone-weights", "{W}/bb-str.pt"], "backbone weights"),
    (["train", "{D}", "--out", "{W}/r", "--size", "64x48", "--backbone-weights", "{W}/bb-text.pt"], "backbone weights"),
]
for name, message in {"m-frac": "input_size[0] must be a whole number", "m-str-classes": "classes must be a list",
                      "m-int-classes": "classes[0] must be a non-empty string", "m-str-size": "input_size must be a list",
                      "m-one-class": "classes must list at least 2"}.items():
    for command in (["eval", "{M}", "{D}"], ["pick", "--model", "{M}", "--log", "{W}/p.jsonl"],
                    ["grasp", "--model", "{M}", "--rgb", "{W}/rgb.png", "--depth", "{W}/depth.png", "--intrinsics",
                     "{W}/intr.json"], ["bench", "{M}", "--data", "{D}", "--out", "{W}/b"],
                    ["bench", "{MODEL}", "{M}", "--cell", "1", "--out", "{W}/b"]):
        CONTENT_CASES.append(([a.replace("{M}", "{" + name + "}") for a in command], message))

NUMBER_CASES = [
    (["data", "synth", "{W}/s", "--scenes", "1000000000000"], "beyond the 1000000"),
    (["data", "synth", "{W}/s", "--splits", "1,1,999999999999"], "beyond the 1000000"),
    (["data", "synth", "{W}/s", "--scenes", "900000", "--size", "4096x4096"], "GB free"),
    (["data", "capture", "{W}/cap", "--camera", "synth", "--count", "10000000"], "--count 10000000"),
    (["train", "{D}", "--out", "{W}/r", "--size", "64x48", "--seed", "-1"], "--seed -1"),
    (["train", "{D}", "--out", "{W}/r", "--size", "64x48", "--epochs", "2", "--keep-epochs", "0"], "--keep-epochs 0"),
    (["train", "{D}", "--out", "{W}/r", "--size", "64x48", "--epochs", "2", "--keep-epochs", "5"], "--keep-epochs 5"),
    (["train", "{D}", "--out", "{W}/r", "--size", "64x48", "--epochs", "2", "--keep-epochs", "-1"], "--keep-epochs -1"),
    (["quantize", "static", "{RUN}", "--data", "{D}", "--out", "{W}/q.onnx", "--seed", "-1"], "--seed -1"),
    (["quantize", "static", "{RUN}", "--data", "{D}", "--out", "{W}/q.onnx", "--max-miou-drop", "nan"],
     "--max-miou-drop nan"),
    (["quantize", "static", "{RUN}", "--data", "{D}", "--out", "{W}/q.onnx", "--max-miou-drop", "1",
      "--max-float-layers", "0"], "--max-float-layers 0"),
    (["quantize", "qat", "--data", "{D}", "--out", "{W}/q.onnx", "--size", "64x48", "--seed", "-1"], "--seed -1"),
    (["quantize", "inspect", "{RUN}", "--data", "{D}", "--top", "-1"], "--top -1"),
    (["quantize", "inspect", "{RUN}", "--data", "{D}", "--images", "999"], "val images to compare (--images)"),
    (["quantize", "inspect", "{RUN}", "--data", "{D}", "--images", "0"], "val images to compare (--images)"),
    (["quantize", "inspect", "{RUN}", "--data", "{D}", "--calib-images", "999"], "calibration images"),
    (["bench", "{MODEL}", "--cell", "1", "--seed", "-1", "--out", "{W}/b"], "--seed -1"),
]
ENV_CASES = [  # (environment, args, message)
    ({"WORLD_SIZE": "abc"}, ["train", "{D}", "--out", "{W}/r", "--size", "64x48"], "WORLD_SIZE='abc'"),
    ({"WORLD_SIZE": "2"}, ["train", "{D}", "--out", "{W}/r", "--size", "64x48"], "start multi-process training with"),
    ({"WORLD_SIZE": "0"}, ["train", "{D}", "--out", "{W}/r", "--size", "64x48"], "WORLD_SIZE=0"),
    ({"WORLD_SIZE": "2", "RANK": "5", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29500"},
     ["train", "{D}", "--out", "{W}/r", "--size", "64x48"], "does not fit WORLD_SIZE=2"),
    ({"WORLD_SIZE": "2", "RANK": "x", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29500"},
     ["train", "{D}", "--out", "{W}/r", "--size", "64x48"], "RANK='x'"),
]
ALL = [({}, a, m) for a, m in OUTPUT_CASES + CONTENT_CASES + NUMBER_CASES] + ENV_CASES


def _fill_all(arg: str, ws: dict) -> str:
    for key in sorted(ws, key=len, reverse=True):  # {meta-list} before {M}
        arg = arg.replace("{" + key + "}", str(ws[key]))
    return arg


@pytest.mark.parametrize("env, args, message", ALL, ids=[" ".join(a)[:70] for _, a, _ in ALL])
def test_a_bad_file_or_path_is_one_line_exit_2_and_nothing_written(bw, capfd, monkeypatch, env, args, message):
    monkeypatch.chdir(bw["W"])
    for key in ("WORLD_SIZE", "RANK", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        monkeypatch.delenv(key, raising=False)
    for key, value in env.items():
        monkeypatch.setenv(key, value)
    roots = [bw["W"], bw["D"], bw["RUN"]]
    before = [_tree(r) for r in roots]
    code = run([_fill_all(a, bw) for a in args])
    assert_refused(code, *capfd.readouterr(), message)
    assert [_tree(r) for r in roots] == before, "something was written"


def test_there_are_at_least_150_cases_of_files_paths_and_numbers():
    assert len(ALL) >= 150
    assert len({a[0] if a[0] != "quantize" else " ".join(a[:2]) for _, a, _ in ALL}) >= 12  # across the commands


def test_the_device_the_issue_found_is_not_replaced(bw, capfd):
    """eval --out and calibrate --out given a character device exit 2 and leave it a device."""
    if not ROOT:
        pytest.skip("making a device node needs root")
    for args in (["eval", str(bw["MODEL"]), str(bw["D"]), "--out", str(bw["O"] / "full.json")],
                 ["calibrate", str(bw["W"] / "pairs.csv"), "--out", str(bw["O"] / "full.json")]):
        assert run(args) == 2
        assert stat.S_ISCHR(os.lstat(bw["O"] / "full.json").st_mode)
    capfd.readouterr()


def test_a_bad_thread_variable_is_neither_libgomps_line_nor_a_second_line_of_a_refusal(tmp_path):
    """Dropped before libgomp reads it, and said with edgepick's own warning once a command has run: a
    refusal is its error line alone (tests/cli/test_one_line.py has the command that runs)."""
    from tests.conftest import run_cli

    proc = run_cli("export", str(tmp_path / "none"), "--out", str(tmp_path / "m.onnx"), env={"OMP_NUM_THREADS": "0"})
    assert proc.returncode == 2 and "libgomp" not in proc.stderr, proc.stderr
    assert proc.stderr.splitlines() == [f"edgepick: error: no checkpoint at {tmp_path / 'none'}"], proc.stderr


def test_an_existing_folder_holding_the_users_files_is_never_removed(tmp_path, capfd, monkeypatch):
    """Item 0 of the issue: --workdir, --out and OUT on a folder with the user's notes are refused
    and the notes stay; a folder the same command made is reused."""
    notes = tmp_path / "mine"
    notes.mkdir()
    (notes / "notes.txt").write_text("the user's")
    monkeypatch.chdir(tmp_path)
    for args in (["demo", "--workdir", "mine"], ["data", "synth", "mine", "--scenes", "3"],
                 ["bench", "x.onnx", "--cell", "1", "--out", "mine"], ["train", "d", "--out", "mine"],
                 ["pick", "--overlay-dir", "mine"], ["data", "import", "cvat", "src", "mine"],
                 ["data", "capture", "mine", "--camera", "synth"], ["quantize", "qat", "--data", "d", "--out",
                                                                     "q.onnx", "--run", "mine"],
                 ["demo", "--workdir", "."], ["demo", "--workdir", ".."], ["data", "synth", "."]):
        assert run(args) == 2, args
        assert (notes / "notes.txt").read_text() == "the user's"
    err = capfd.readouterr().err
    assert "was not made by edgepick demo" in err and "was not made by edgepick pick" in err and "working folder" in err
