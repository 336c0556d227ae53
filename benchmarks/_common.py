"""Helpers shared by the benchmark scripts (run as `python benchmarks/NAME.py`)."""

from __future__ import annotations

from pathlib import Path


def untrained_checkpoint(path: Path, size: tuple[int, int], classes: list[str], variant: str = "standard") -> Path:
    """A seeded, untrained default model (DeepLabV3-MobileNetV3) as a checkpoint: latency does
    not depend on the weights, so speed benchmarks need no training run."""
    import torch

    from edgepick.models.deeplabv3 import ModelConfig, build_model
    from edgepick.train.checkpoint import model_meta

    torch.manual_seed(0)
    cfg = ModelConfig(num_classes=len(classes), variant=variant)
    torch.save({"model": build_model(cfg).state_dict(), "train_time_s": 0.0, **model_meta(cfg, classes, size)}, path)
    return path


def emit(report: str, out: str | None) -> None:
    """Print a Markdown report, and write it to OUT when given."""
    print(report)
    if out:
        Path(out).write_text(report)


def interleaved_times(calls: list, runs: int, block: int = 5) -> list[list[float]]:
    """Milliseconds per call of each CALLS[k](i), RUNS timed calls each, in alternating blocks of BLOCK
    after one untimed call: a shared machine's load drifts over all models alike, and no timed call
    starts while the previous model's thread pool is still spinning (timing models one call each in
    turn put 25-40 ms on every call here, onnxruntime sessions on 2 cores)."""
    import time

    times: list[list[float]] = [[] for _ in calls]
    i = 0
    while any(len(t) < runs for t in times):
        for call, t in zip(calls, times):
            call(i)
            for _ in range(min(block, runs - len(t))):
                i += 1
                t0 = time.perf_counter()
                call(i)
                t.append(1000 * (time.perf_counter() - t0))
    return times
