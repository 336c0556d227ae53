"""The pt2e verbs: a prepare that inserts nothing is refused (the silent-float trap)."""

from __future__ import annotations

import pytest

from edgepick.errors import QuantizationError
from edgepick.geometry import Size


def test_a_quantizer_that_marks_nothing_is_refused(trained_run, monkeypatch):
    from edgepick.quant.pt2e import graph
    from edgepick.quant.pt2e.quantizer import EdgeQuantizer, QuantConfig
    from edgepick.train.checkpoint import load_model

    monkeypatch.setattr(EdgeQuantizer, "annotate", lambda self, model: model)
    model, _ = load_model(trained_run)
    with pytest.raises(QuantizationError):
        graph.prepare(model, QuantConfig(), Size(128, 96), qat=False)
