"""Shared fixtures: one small synthetic data set and one short training run per test session."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "2")
REPO = Path(__file__).resolve().parents[1]
EPOCHS = 25  # ~60 s on 2 cores


def run_cli(*args: str, check: bool = False, timeout: float = 600, env: dict | None = None) -> subprocess.CompletedProcess:
    """Run `python -m edgepick ARGS` in a subprocess, as a user would."""
    proc = subprocess.run([sys.executable, "-m", "edgepick", *args], capture_output=True, text=True, timeout=timeout,
                          cwd=REPO, env={**os.environ, **(env or {})})
    if check and proc.returncode != 0:
        raise AssertionError(f"edgepick {' '.join(args)} exited {proc.returncode}\n{proc.stderr[-3000:]}")
    return proc


@pytest.fixture(scope="session")
def small_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """48 scenes at 320x240 (train 36 / val 8 / test 4)."""
    from edgepick.data.synth import SynthConfig, synthesize

    out = tmp_path_factory.mktemp("data") / "synth"
    synthesize(out, SynthConfig(scenes=48, width=320, height=240, seed=7, splits=(36, 8, 4)), progress=False)
    return out


@pytest.fixture(scope="session")
def trained_run(small_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A short CPU training run (MobileNetV3, 128x96) shared by the eval and quality tests."""
    from edgepick.geometry import Size
    from edgepick.train.loop import TrainConfig, train

    out = tmp_path_factory.mktemp("runs") / "run"
    train(TrainConfig(data=str(small_data), out=str(out), epochs=EPOCHS, batch_size=4, size=Size(128, 96), device="cpu",
                      lr=2e-3, keep_epochs=[2, EPOCHS - 1]), progress=False)
    return out
