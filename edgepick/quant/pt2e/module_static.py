"""Static PTQ of a segmentation nn.Module edgepick did not build, on the pt2e path its own models
take: torch.export, edgepick's quantizer (U8S8, per-channel weights, hardswish gated), the
caller's calibration batches, convert, an int8 ONNX with the module's own float input and
outputs, and the ONNX passes of `edgepick.export`. `model wrap` then makes it an edgepick model.
"""

from __future__ import annotations

import copy
import itertools
import json
import time
from collections.abc import Iterable, Iterator, Sized
from pathlib import Path
from typing import Any

import torch

from edgepick.errors import ParameterError
from edgepick.export.checks import check_onnx_out
from edgepick.export.onnx_export import export_module_onnx
from edgepick.geometry import Size
from edgepick.quant.config import (
    BIAS_CORRECTION_IMAGES,
    HELD_OUT_INPUTS,
    CalibMethod,
    Pt2eOptions,
    PtqMethods,
    QuantConfig,
    check_inputs,
)
from edgepick.quant.fidelity import compare_outputs, guess_task
from edgepick.quant.onnx.inputs import check_tensor
from edgepick.quant.pt2e.graph import choose_rule, expected_int8_convs, prepare
from edgepick.quant.pt2e.int8_file import checked_int8
from edgepick.quant.pt2e.ptq import convert_static, measures
from edgepick.quant.pt2e.rewrites import GatedHardswish
from edgepick.quant.record import QuantRecord, RecordKind
from edgepick.quant.results import OnnxPassResult


def _tensor(x: Any, shape: tuple[int, ...] | None, what: str) -> torch.Tensor:
    """X (a tensor or an array) as a float32 batch of SHAPE, refused in one line naming `calib`
    (quant/onnx/inputs.check_tensor's checks)."""
    if isinstance(x, torch.Tensor):
        x = x.detach().cpu().numpy()
    return torch.from_numpy(check_tensor(x, shape, what))


def _outputs(out: Any) -> list[torch.Tensor]:
    """A module's output as a list of tensors: a {"out": ...} dict's `out`, a tensor, or a tuple."""
    if isinstance(out, dict):
        out = out["out"]
    return list(out) if isinstance(out, (tuple, list)) else [out]


def _calibrate(prepared: torch.fx.GraphModule, first: torch.Tensor, batches: Iterator[Any], shape: tuple[int, ...],
               config: QuantConfig, keep: int, total: int | None, progress: bool) -> tuple[list[torch.Tensor], int, dict]:
    """Run PREPARED on FIRST and BATCHES (checked against SHAPE), the first HELD_OUT_INPUTS held out
    with calib_method auto for choosing the rule; returns the first KEEP batches, how many were
    seen, and the range rule's record."""
    from edgepick.progress import progress as progress_bar

    kept, held, seen = [first], [], 0
    hold = HELD_OUT_INPUTS if config.calib_method == CalibMethod.AUTO else 0
    with torch.no_grad():
        for k, x in enumerate(progress_bar(itertools.chain([first], batches), desc="calibrate", unit="batch",
                                           total=total, enabled=progress)):
            x = first if k == 0 else _tensor(x, shape, f"calibration batch {k + 1}")
            if k < hold:
                held.append(x)  # counted in by choose_rule, after the candidates are measured on them
            else:
                prepared(x)
            seen += 1
            if 0 < k < keep:
                kept.append(x)
    return kept, seen, choose_rule(prepared, held, config, seen - len(held))


def _fidelity(module: torch.nn.Module, path: Path, kept: list[torch.Tensor]) -> dict[str, dict]:
    """Each output's fidelity (quant/fidelity.py) of the int8 file at PATH against MODULE on KEPT."""
    from edgepick.runtime.session import plain_session

    session = plain_session(path)
    names = [o.name for o in session.get_outputs()]
    float_model = copy.deepcopy(module).eval()
    with torch.no_grad():
        pairs = [([r.numpy() for r in _outputs(float_model(x))], session.run(names, {"input": x.numpy()}))
                 for x in kept]
    # a map inside [0, 1] is taken as a probability (threshold 0.5), else a logit (0)
    tasks = {name: guess_task(ref.shape, bool(ref.min() >= 0.0 and ref.max() <= 1.0))
             for name, ref in zip(names, pairs[0][0])}
    return {n: f.to_dict() for n, f in compare_outputs(names, tasks, pairs).items()}


def quantize_module_static(module: torch.nn.Module, calib: Iterable[Any], out: str | Path,
                           config: QuantConfig | None = None, methods: PtqMethods | None = None,
                           pt2e: Pt2eOptions | None = None, input_shape: tuple[int, ...] | None = None,
                           progress: bool = True) -> OnnxPassResult:
    """Static PTQ of MODULE (any segmentation nn.Module taking [N, C, H, W]: a torchvision-style
    `{"out": ...}` dict or tensors out), calibrated on CALIB (input batches, tensors or arrays,
    with or without the batch axis), METHODS applied on them, written to OUT as an int8 ONNX with
    the module's own input and outputs. INPUT_SHAPE [default: the first batch's]. MODULE itself is
    left as it was."""
    import onnx

    config, methods = config or QuantConfig(), methods or PtqMethods()
    check_onnx_out(out)
    batches = iter(calib)
    first = next(batches, None)
    if first is None:
        raise ParameterError("{calib:name}: no batches; calibration needs at least one", calib=None)
    first = _tensor(first, None, "calibration batch 1")
    shape = tuple(input_shape) if input_shape else tuple(first.shape if first.dim() == 4 else (1, *first.shape))
    if len(shape) != 4:
        raise ParameterError(f"{{input_shape}}: must be [N, C, H, W], got {list(shape)}", input_shape=shape)
    first = _tensor(first, shape, "calibration batch 1")
    model = copy.deepcopy(module).eval()
    t0 = time.perf_counter()
    prepared = prepare(model, config, Size(shape[3], shape[2]), qat=False, input_shape=shape,
                       equalize=methods.equalize, pt2e=pt2e)
    gated = sum(isinstance(m, GatedHardswish) for m in model.modules())
    check = check_inputs(shape[2], shape[3])
    keep = max(check, BIAS_CORRECTION_IMAGES if measures(config, methods) else 0)
    kept, seen, ranges = _calibrate(prepared, first, batches, shape, config, keep,
                                    len(calib) if isinstance(calib, Sized) else None, progress)
    converted, measured = convert_static(prepared, lambda: kept[:BIAS_CORRECTION_IMAGES], config, methods, progress)
    calib_s = time.perf_counter() - t0
    quant = QuantRecord(RecordKind.MODULE, config, seen, methods, ranges=ranges, measured=measured).to_dict()
    path = export_module_onnx(converted, out, shape, {"edgepick.quant": json.dumps(quant)})
    report = checked_int8(path, expected_int8_convs(prepared, config))
    return OnnxPassResult.of(path, report, _fidelity(module, path, kept[:check]), input_shape=list(shape),
                             opset_in=None,
                             opset_out=next(o.version for o in onnx.load(str(path)).opset_import if o.domain == ""),
                             rewrites={"gated_hardswish": gated}, quant=quant, calib_tensors=seen,
                             calib_s=round(calib_s, 2))
