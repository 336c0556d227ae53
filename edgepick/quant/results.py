"""What the int8 passes return: small frozen records, with `to_dict()` for the JSON the CLI prints."""

from __future__ import annotations

from dataclasses import MISSING, asdict, dataclass, fields


@dataclass(frozen=True)
class Int8File:
    """An exported int8 ONNX model and the checks run on it."""

    out: str
    size_bytes: int
    convs: int  # convs of the model (a conv split into regions counts once)
    int8_convs: int  # of them, those whose weights are int8 in the file
    float_convs: list[str]  # the names of the others (kept float on purpose)
    agreement_vs_torch: float  # share of pixels where onnxruntime's labels equal torch's simulation's


@dataclass(frozen=True)
class PassResult:
    """A pass's int8 model (the fields of Int8File), the settings written into its metadata
    (`quant`: the `edgepick.quant` entry of docs/contracts.md#onnx-model) and the pass's own figures."""

    mode: str  # static, qat or hybrid
    out: str
    size_bytes: int
    convs: int
    int8_convs: int
    float_convs: list[str]
    agreement_vs_torch: float
    observers: int  # quantize/fake-quantize nodes of the prepared graph
    quant: dict
    calib_s: float | None = None  # static: prepare, calibrate and convert time
    run: str | None = None  # QaT and hybrid: the QaT run's folder
    float_phase_s: float | None = None  # hybrid: the float run's training time up to the switch
    qat_phase_s: float | None = None  # QaT and hybrid: the QaT epochs' training time
    val_miou_qat: float | None = None  # the exported QaT epoch's val mIoU (torch, fake-quant)
    qat_epoch: int | None = None  # the QaT run's epoch that was exported (its best on val)

    def to_dict(self) -> dict:
        """Every field, less the optional ones this pass leaves unset."""
        return {f.name: getattr(self, f.name) for f in fields(self)
                if getattr(self, f.name) is not None or f.default is MISSING}


@dataclass(frozen=True)
class AccuracyAwareResult:
    """Accuracy-aware static PTQ: the file kept, the budget, and every step tried."""

    out: str
    fp32_val_miou: float
    budget_pp: float
    met: bool  # whether the kept file is within budget_pp of the fp32 model's val mIoU
    chosen: dict  # the kept step: keep_float, val_miou, drop_pp
    steps: list[dict]  # every step tried, in order
    agreement_vs_torch: float

    def to_dict(self) -> dict:
        return asdict(self)
