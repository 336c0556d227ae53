"""The reference int8 model shipped with edgepick: DeepLabV3-MobileNetV3 trained on synthetic
scenes of the thesis's four objects, for the synthetic cell (`make demo`'s pick step, `bench --cell`)
and as a known-good model to compare a user's own against. How it was made, and what it scores,
is in MODEL_CARD.md beside it; the card's sha256 line names the file it describes."""

from __future__ import annotations

from pathlib import Path

HERE = Path(__file__).resolve().parent
CARD = HERE / "MODEL_CARD.md"


def reference_model() -> Path | None:
    """The shipped reference model's path, or None when this install has none."""
    found = sorted(HERE.glob("*.onnx"))
    return found[0] if found else None
