"""Float training: quality after a short CPU run, resume after a kill, DDP with gloo, bad input."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from edgepick.geometry import Size
from edgepick.train.checkpoint import Checkpoint, load_model
from tests.conftest import REPO, run_cli, without_torch


def test_short_cpu_training_beats_chance_and_is_not_degenerate(trained_run, small_data):
    from edgepick.data.native import NativeDataset
    from edgepick.metrics import confusion_matrix, segmentation_metrics
    from tests.conftest import EPOCHS

    metrics = json.loads((trained_run / "metrics.json").read_text())
    assert len(metrics["history"]) == EPOCHS
    first, best = metrics["history"][0], max(h["miou"] for h in metrics["history"])
    ds = NativeDataset.open(small_data, "val")
    cm = sum(confusion_matrix(m, np.zeros_like(m), 5) for m in (ds.mask(s) for s in ds.ids))
    chance = segmentation_metrics(cm)["miou"]  # predicting background everywhere
    assert best > chance + 0.05, (chance, metrics["history"])
    assert best > first["miou"]
    assert metrics["history"][-1]["loss"] < first["loss"]
    for key in ("loss", "pixel_acc", "miou", "per_class_iou", "epoch_s", "images_per_s"):
        assert key in metrics["history"][-1]
    assert metrics["train_time_s"] > 0
    # eval-mode predictions use several classes, not all background
    import cv2

    model, ckpt = load_model(trained_run)
    ds = NativeDataset.open(small_data, "val")
    h, w = ckpt.input_size.hw
    seen = set()
    with torch.no_grad():
        for sid in ds.ids:
            x = torch.from_numpy(cv2.resize(ds.rgb(sid), (w, h))).permute(2, 0, 1)[None].float()
            seen |= set(model(x)["out"].argmax(1).unique().tolist())
    assert 0 in seen and len(seen) >= 3


def test_checkpoints_carry_their_config(trained_run):
    ckpt = Checkpoint.load(trained_run / "best.pt")
    assert ckpt.classes == ("background", "bearing", "disk", "adapter", "box")
    assert ckpt.input_size == Size(128, 96)
    assert ckpt.colorspace == "rgb" and ckpt.model_config.arch == "deeplabv3-mobilenetv3"
    assert ckpt.normalisation["mean"] == (0.485, 0.456, 0.406)
    assert (trained_run / "last.pt").is_file() and (trained_run / "epoch_002.pt").is_file()
    assert Checkpoint.load(trained_run / "epoch_002.pt").epoch == 2
    assert not [p.name for p in trained_run.iterdir() if ".tmp" in p.name]


def test_eval_cli_reports_metrics(trained_run, small_data, tmp_path):
    proc = run_cli("eval", str(trained_run / "best.pt"), str(small_data), "--split", "test",
                   "--out", str(tmp_path / "m.json"), check=True)
    result = json.loads(proc.stdout)
    assert result["images"] == 4 and 0 <= result["miou"] <= 1 and 0 <= result["pixel_acc"] <= 1
    assert np.array(result["confusion_matrix"]).shape == (5, 5)
    assert np.array(result["confusion_matrix"]).sum() == 4 * 240 * 320  # at the data's own resolution
    assert json.loads((tmp_path / "m.json").read_text())["miou"] == result["miou"]


@pytest.mark.slow
def test_resume_after_kill_loses_at_most_one_epoch(small_data, tmp_path):
    run = tmp_path / "run"
    args = [sys.executable, "-m", "edgepick", "train", str(small_data), "--out", str(run), "--epochs", "4",
            "--size", "96x64", "--batch-size", "6", "--device", "cpu"]
    proc = subprocess.Popen(args, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 300
    while time.time() < deadline and not (run / "last.pt").exists():
        time.sleep(0.1)
    proc.send_signal(signal.SIGKILL)  # no chance to clean up: atomic writes must hold
    proc.wait()
    done = Checkpoint.load(run / "last.pt").epoch
    assert 1 <= done < 4
    other = tmp_path / "other"  # the same images under other class names: not the run's data set
    shutil.copytree(small_data, other)
    meta = json.loads((other / "meta.json").read_text())
    (other / "meta.json").write_text(json.dumps({**meta, "classes": meta["classes"][:-1] + ["crate"]}))
    refused = run_cli("train", str(other), "--out", str(run), "--resume")
    assert refused.returncode == 2 and "give the run's own data set" in refused.stderr, refused.stderr
    moved = tmp_path / "elsewhere" / "data"  # the data set moved; resumed from another folder, by a relative path
    shutil.copytree(small_data, moved)
    resumed = subprocess.run([sys.executable, "-m", "edgepick", "train", "data", "--out", str(run), "--resume"],
                             cwd=moved.parent, capture_output=True, text=True, timeout=600,
                             env={**os.environ, "PYTHONPATH": str(REPO)})
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    assert f"resuming {run} after epoch {done}" in resumed.stderr
    history = json.loads((run / "metrics.json").read_text())["history"]
    assert [h["epoch"] for h in history] == [1, 2, 3, 4]
    last = Checkpoint.load(run / "last.pt")
    assert last.epoch == 4 and last.train_config.data == "data"
    best = Checkpoint.load(run / "best.pt")  # what export and quantize take: no optimizer state
    assert best.optimizer is None and last.optimizer is not None
    assert (run / "best.pt").stat().st_size < 0.5 * (run / "last.pt").stat().st_size


@pytest.mark.slow
def test_ddp_two_cpu_processes_with_gloo(small_data, tmp_path):
    run = tmp_path / "ddp"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nproc_per_node", "2",
                           "--master_port", "29517", "-m", "edgepick", "train", str(small_data), "--out", str(run),
                           "--epochs", "1", "--size", "96x64", "--batch-size", "4", "--device", "cpu"],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    ckpt = Checkpoint.load(run / "last.pt")
    assert ckpt.world_size == 2 and ckpt.epoch == 1
    hist = json.loads((run / "metrics.json").read_text())["history"]
    # each rank saw half of the 36 training images; the loss/metrics are all-reduced over both
    assert hist[0]["miou"] is not None


@pytest.mark.parametrize("args,needle", [  # the rest: tests/cli/test_bad_input.py, in-process
    (["train", "{missing}", "--out", "{out}"], "not an edgepick data set"),
    (["eval", "{out}/none.pt", "{data}"], "no checkpoint"),
])
def test_bad_input_is_one_line_and_exit_2(args, needle, small_data, tmp_path):
    """train's mistakes are found before torch is imported: here it cannot be."""
    fill = {"missing": str(tmp_path / "nope"), "out": str(tmp_path / "run"), "data": str(small_data)}
    proc = run_cli(*[a.format(**fill) for a in args], env=without_torch(tmp_path / "blocked") if args[0] == "train" else None)
    assert proc.returncode == 2, proc.stderr
    assert needle in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "run").exists()


def test_epoch_and_val_subsets(small_data, tmp_path):
    """--epoch-images draws that many train images per epoch; --val-images scores that many
    (with the lamp augmentation, which the run records)."""
    from edgepick.train.loop import TrainConfig, train

    run = tmp_path / "run"
    train(TrainConfig(data=str(small_data), out=str(run), epochs=2, batch_size=4, size=Size(96, 64), device="cpu",
                      epoch_images=8, val_images=3, augment="lights"), progress=False)
    history = json.loads((run / "metrics.json").read_text())["history"]
    assert [(h["images"], h["val_images"]) for h in history] == [(8, 3), (8, 3)]
    assert Checkpoint.load(run / "last.pt").train_config.augment == "lights"
