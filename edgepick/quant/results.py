"""What the int8 passes return: small frozen records, with `to_dict()` for the JSON the CLI prints."""

from __future__ import annotations

from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from typing import Any


@dataclass(frozen=True)
class PassResult:
    """A torch pass's int8 model (the fields of pt2e.int8_file.Int8File), the settings written into its metadata
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


@dataclass(frozen=True)
class OnnxPassResult:
    """The int8 file of a model edgepick did not make (an ONNX file or an nn.Module), what was done
    to it and how close it stays to fp32."""

    out: str
    size_bytes: int
    input_shape: list[int]
    opset_in: int | None  # None for an nn.Module
    opset_out: int
    convs: int
    int8_convs: int
    float_convs: list[str]
    agreement_vs_fp32: dict[str, float]  # per output that decides something: share of equal decisions
    fidelity: dict[str, dict]  # per output: task, sqnr_db, cosine, agreement (quant/fidelity.py)
    rewrites: dict[str, int]  # float rewrites before quantizing, and the int8 graph passes after
    quant: dict
    calib_tensors: int
    calib_s: float
    # wall seconds per stage of the recipe (ONNX static PTQ: prepare, calibrate, choose_ranges, write_qdq,
    # corrections, finish, write_check), so the cost of each measurement is seen; empty where not kept
    stage_s: dict[str, float] = field(default_factory=dict)

    @classmethod
    def of(cls, out: Path, report: dict, fidelity: dict[str, dict], **rest: Any) -> OnnxPassResult:
        """The result for the file OUT, its conv REPORT (export.checks.conv_weight_report) and its
        FIDELITY per output; REST: the other fields."""
        return cls(out=str(out), size_bytes=out.stat().st_size, convs=report["convs"], int8_convs=report["int8"],
                   float_convs=report["float"], fidelity=fidelity,
                   agreement_vs_fp32={n: f["agreement"] for n, f in fidelity.items() if f["agreement"] is not None},
                   **rest)

    def to_dict(self) -> dict:
        return asdict(self)
