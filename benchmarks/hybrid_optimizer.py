"""Hybrid-QaT with and without the float run's AdamW moments: one small float run on CPU, then
the last 10% of its epoch budget in QaT twice from the same kept epoch, fresh optimizer against
carried moments (quantize_hybrid's carry_optimizer), with the validation mIoU of each epoch.

    python benchmarks/hybrid_optimizer.py [--epochs 40] [--out FILE.md | --save]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.data.synth import SynthConfig, synthesize  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.quant.config import QuantConfig  # noqa: E402
from edgepick.quant.pt2e.qat import train_qat  # noqa: E402
from edgepick.train.checkpoint import Checkpoint  # noqa: E402
from edgepick.train.loop import TrainConfig, train  # noqa: E402
from edgepick.train.run import Run  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=40, help="float epoch budget E; QaT runs the last E/10")
    add_output(ap)
    args = ap.parse_args()
    switch = args.epochs - max(1, args.epochs // 10)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        data = root / "data"
        synthesize(data, SynthConfig(scenes=110, width=320, height=240, seed=3, splits=(80, 20, 10)), progress=False)
        tc = TrainConfig(data=str(data), out=str(root / "float"), epochs=args.epochs, batch_size=8, size=Size(96, 64),
                         lr=2e-3, device="cpu", keep_epochs=[switch])
        train(tc, progress=False)
        rows = {"float (no QaT)": json.loads(Run(root / "float").metrics.read_text())["history"]}
        for carry in (False, True):
            out = root / f"hybrid{int(carry)}"
            train_qat(replace(tc, out=str(out), keep_epochs=()), QuantConfig(),
                      start=Checkpoint.load(Run(root / "float").epoch(switch)), carry_optimizer=carry,
                      progress=False)
            label = "hybrid-QaT, carried AdamW moments" if carry else "hybrid-QaT, fresh AdamW"
            rows[label] = json.loads(Run(out).metrics.read_text())["history"]
    epochs = list(range(switch + 1, args.epochs + 1))
    lines = ["# Hybrid-QaT: fresh optimizer against the float run's AdamW moments", "",
             f"Command: `python benchmarks/hybrid_optimizer.py --epochs {args.epochs}`", "",
             f"- {machine_line()}; synthetic 80/20 scenes at 320x240, "
             f"input 96x64, batch 8, E = {args.epochs}, QaT from the float run's epoch {switch}",
             "- validation mIoU (%) after each epoch, 20 val images (small: differences under ~1 pp are noise)", "",
             "| Run | " + " | ".join(f"epoch {e}" for e in epochs) + " |", "|---|" + "---|" * len(epochs)]
    for label, history in rows.items():
        by_epoch = {h["epoch"]: h["miou"] for h in history}
        lines.append(f"| {label} | " + " | ".join(f"{100 * by_epoch[e]:.2f}" for e in epochs) + " |")
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
