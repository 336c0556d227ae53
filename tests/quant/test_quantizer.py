"""The pt2e calibration observers of quant/pt2e/quantizer.py."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from edgepick.quant.pt2e.quantizer import WeightObserver  # noqa: E402


def test_a_weight_is_observed_once_until_it_changes(monkeypatch):
    observer = WeightObserver(ch_axis=0, dtype=torch.int8, qscheme=torch.per_channel_symmetric, eps=2 ** -12)
    weight = torch.nn.Parameter(torch.tensor([[1.0, -2.0], [0.5, 0.25]]), requires_grad=False)
    calls = []
    original = torch.aminmax
    monkeypatch.setattr(torch, "aminmax", lambda *a, **k: calls.append(1) or original(*a, **k))
    for _ in range(5):
        assert observer(weight) is weight
    assert len(calls) == 1 and observer.max_val.tolist() == [1.0, 0.5]
    with torch.no_grad():
        weight.mul_(4.0)  # changed in place: observed again
    observer(weight)
    assert len(calls) == 2 and observer.max_val.tolist() == [4.0, 2.0] and observer.min_val.tolist() == [-8.0, 0.25]
    observer(torch.tensor([[9.0, 0.0], [0.0, 0.0]]))  # another tensor
    assert len(calls) == 3 and observer.max_val.tolist() == [9.0, 2.0]
