"""The engines a conformance run compares: a quantizer (none for fp32) and the runtime that runs its
file. Every quantizer gets the same fp32 file (input shape fixed) and the same calibration tensors,
and runs once per model even where two engines share its file (fp32 on onnxruntime and on OpenVINO).
Another edgepick setting is one more Engine with its own edgepick_quantizer(QuantConfig(...)):
edgepick-openvino is the file `--placement auto --target openvino` makes.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from _quantizers import OpenVino, Ort, nncf_quantize, ort_quantize, ort_ready

from edgepick.quant.config import OnnxOptions, PtqMethods, QuantConfig
from edgepick.quant.onnx.accuracy import FidelityBudget

ONNXRUNTIME, OPENVINO = "onnxruntime", "openvino"


@dataclass(frozen=True)
class Job:
    """What a quantizer is given: the fp32 file, the calibration tensors, a folder of its own for its
    files, edgepick's --task for the model (None: guessed) and the model's own judge of int8 outputs
    against fp32's (its package's decisions scored by its metric), for edgepick's budget."""

    fp32: Path
    calib: Sequence[np.ndarray]
    work: Path
    input_shape: tuple[int, ...]
    task: str | None = None
    judge: Callable[[list[list[np.ndarray]], list[list[np.ndarray]]], float] | None = None


@dataclass(frozen=True)
class Quantized:
    """A quantizer's result: the file a runtime loads (.onnx, or OpenVINO's .xml), every file it
    takes (for the size), the quantizer's own calibration time where it reports one, and a note;
    edgepick's also its seconds per stage (the result's stage_s)."""

    model: Path
    files: tuple[Path, ...]
    calib_s: float | None = None
    note: str = ""
    stage_s: dict[str, float] = field(default_factory=dict)

    @property
    def size_mb(self) -> float:
        return round(sum(p.stat().st_size for p in self.files) / 1e6, 2)


@dataclass(frozen=True)
class Quantizer:
    """A named function from a Job to its int8 file; engines that share one share its file."""

    name: str
    run: Callable[[Job], Quantized]


@dataclass(frozen=True)
class Engine:
    """A quantizer's file on a runtime."""

    name: str
    runtime: str  # onnxruntime | openvino
    quantizer: Quantizer

    def load(self, quantized: Quantized, threads: int, outputs: Sequence[str]) -> Callable[[np.ndarray], list[np.ndarray]]:
        """The file as a function of one input tensor, its outputs in OUTPUTS' order."""
        if self.runtime == ONNXRUNTIME:
            return Ort(quantized.model, threads, outputs)
        return OpenVino(quantized.model, threads, outputs)


def _fp32(job: Job) -> Quantized:
    """No quantizer: the fp32 file itself."""
    return Quantized(job.fp32, (job.fp32,))


def _ort(best: bool) -> Callable[[Job], Quantized]:
    """onnxruntime's quantize_static after its pre-processing; where the pre-processing itself fails
    on the model, without it, as a user would go on (the note says so)."""
    def run(job: Job) -> Quantized:
        from .runner import one_line

        pre, out = job.work / "pre.onnx", job.work / "int8.onnx"
        notes = []
        try:
            lifted = ort_ready(job.fp32, pre)
        except Exception as exc:  # noqa: BLE001 - quant_pre_process's shape inference fails on some graphs
            notes.append(f"quant_pre_process failed ({one_line(exc)}), quantized without it")
            lifted = ort_ready(job.fp32, pre, preprocess=False)
        if lifted:
            notes.append("opset lifted to 13 first")
        ort_quantize(pre, out, job.calib, best)
        return Quantized(out, (out,), note="; ".join(notes))
    return run


def _nncf(job: Job) -> Quantized:
    """NNCF's defaults, saved as OpenVINO IR with its float parts in f32 (as run, for the size)."""
    import logging

    import nncf
    import openvino as ov

    nncf.set_log_level(logging.ERROR)
    xml = job.work / "nncf.xml"
    ov.save_model(nncf_quantize(job.fp32, job.calib), xml, compress_to_fp16=False)
    return Quantized(xml, (xml, xml.with_suffix(".bin")))


def edgepick_quantizer(name: str, options: OnnxOptions, budget: FidelityBudget | None = None,
                       methods: PtqMethods | None = None, config: QuantConfig | None = None,
                       judged: bool = False) -> Quantizer:
    """edgepick's static PTQ of the fp32 file with OPTIONS (and the accuracy-aware mode's BUDGET, the
    PTQ METHODS and quantization CONFIG other than the defaults), through its public API; JUDGED: the
    budget held by the model's own decisions (the job's judge) rather than edgepick's tasks."""
    def run(job: Job) -> Quantized:
        from edgepick.quant.onnx.static import quantize_onnx_static

        out = job.work / f"{name}.onnx"
        given = replace(budget, judge=job.judge) if judged and budget is not None else budget
        result = quantize_onnx_static(job.fp32, list(job.calib), out, config=config, options=options, methods=methods,
                                      input_shape=job.input_shape, progress=False,
                                      task=edgepick_task(job.task), budget=given)
        note = f"{result.int8_convs} of {result.convs} convs int8, ranges {result.quant['ranges']['rule']}"
        grid = result.quant.get("outputs_on_grid")
        if grid:
            note += ", outputs on the uint8 grid" if grid["kept"] else ", outputs float (closer than on the grid)"
        if "placement_choice" in result.quant:
            note += f", placement {result.quant['placement_choice']['chosen']} (timed on {options.target})"
        tried = result.quant.get("adaround_first")
        if tried is not None:
            why = "budget missed" if tried.get("why") == "budget" else "under the SQNR floor"
            note += f"; AdaRound first ({why}): {'kept' if tried['kept'] else 'not kept'}"
        if budget is not None:
            note += "; " + accuracy_note(result.quant["accuracy_aware"])
        return Quantized(Path(result.out), (Path(result.out),), calib_s=result.calib_s, note=note,
                         stage_s=result.stage_s)
    return Quantizer(name, run)


def openvino_placement_quantizer(placement: str) -> Quantizer:
    """One of the candidates `--placement auto --target openvino` chooses among, made as it makes
    them (the float model in OpenVINO's forms, then PLACEMENT), to show what the choice left."""
    def run(job: Job) -> Quantized:
        from edgepick.quant.onnx.placement import openvino_forms, worst_sqnr
        from edgepick.quant.onnx.static import quantize_onnx_static

        name = f"edgepick-openvino-{placement}"
        forms = job.work / f"{name}-forms"
        forms.mkdir()
        source, made = openvino_forms(job.fp32, forms)
        result = quantize_onnx_static(source, list(job.calib), job.work / f"{name}.onnx",
                                      options=OnnxOptions(placement=placement), input_shape=job.input_shape,
                                      progress=False, task=edgepick_task(job.task))
        worst = worst_sqnr(result.fidelity)
        note = f"placement {placement}; worst SQNR on the check tensors " + \
            ("exact" if math.isinf(worst) else f"{worst:.1f} dB")
        if made:
            note += f"; {made['subsampled_pointwise_convs']} strided 1x1 convs subsampled first"
        return Quantized(Path(result.out), (Path(result.out),), calib_s=result.calib_s, note=note,
                         stage_s=result.stage_s)
    return Quantizer(f"edgepick-openvino-{placement}", run)


def edgepick_task(text: str | None) -> Any:
    """An entry's task as quantize_onnx_static takes it: one Task for every output ("ctc"), or one per
    output name ("537=threshold:0.2 538=raw", as the CLI's --task OUTPUT=TASK); None: guessed."""
    from edgepick.quant.fidelity import parse_tasks

    return parse_tasks((text or "").split())


NOTE_TENSORS = 6  # float activations the table names; the rest are counted


def accuracy_note(record: dict) -> str:
    """What the accuracy-aware mode did, for the table: the activations it left float (with the SQNR
    the scan measured each one gains), whether the budget was met on how many check tensors, and the
    speed it cost."""
    gains = {s["tensor"]: s["gain_db"] for s in record.get("scan", [])}
    kept = record.get("float_tensors", [])
    checked = f" on {record['check_tensors']} check tensors" if "check_tensors" in record else ""
    closest = " (the graph closest to the budget by its own measure)" if record.get("closest_by_budget") else ""
    if not kept:
        return "accuracy-aware: " + (f"budget met all-int8{checked}" if record.get("met") else
                                     "no float activation brought the budget's measure closer" if closest else
                                     "no float activation helped")
    listed = ", ".join(f"{t} (+{gains[t]:.1f} dB alone)" if t in gains else t for t in kept[:NOTE_TENSORS])
    if len(kept) > NOTE_TENSORS:
        listed += f" and {len(kept) - NOTE_TENSORS} more"
    convs = len(record.get("float_weight_convs", []))
    if convs:
        listed += f" ({convs} convs with them float)"
    speed = record.get("speed", {})
    cost = f", {speed['slowdown']:.2f}x the all-int8 file's time" if "slowdown" in speed else ""
    if "speedup_vs_fp32" in speed:
        cost += f" ({speed['speedup_vs_fp32']:.2f}x fp32's speed{', slower than fp32' if speed['speedup_vs_fp32'] < 1 else ''})"
    verdict = "met" if record.get("met") else f"not met{closest}"
    return f"accuracy-aware: {len(kept)} float: {listed}; budget {verdict}{checked}{cost}"


FP32 = Quantizer("fp32", _fp32)
# edgepick-aa's: 99.5% of every output's decisions (the task each model's entry names, else guessed), up to 160
# activations float (room for a float start of the graph, not only for regions)
ACCURACY_BUDGET = FidelityBudget(min_agreement=0.995, max_float=160)
EDGEPICK = edgepick_quantizer("edgepick", OnnxOptions())
ENGINES: tuple[Engine, ...] = (
    Engine("fp32", ONNXRUNTIME, FP32),
    Engine("fp32-openvino", OPENVINO, FP32),  # what the OpenVINO engines' speed-up is measured against
    Engine("ort-default", ONNXRUNTIME, Quantizer("ort-default", _ort(best=False))),
    Engine("ort-best", ONNXRUNTIME, Quantizer("ort-best", _ort(best=True))),
    Engine("nncf", OPENVINO, Quantizer("nncf", _nncf)),
    Engine("edgepick", ONNXRUNTIME, EDGEPICK),
    # the accuracy-aware mode: activations left float, most sensitive first, until every output is within the budget
    Engine("edgepick-aa", ONNXRUNTIME, edgepick_quantizer("edgepick-aa", OnnxOptions(), ACCURACY_BUDGET)),
    # the same budget held by the model's own decisions: its package's post-processing scored by its metric on the
    # check tensors (FidelityBudget.judge, as NNCF's accuracy control takes a validation function)
    Engine("edgepick-aa-judged", ONNXRUNTIME, edgepick_quantizer("edgepick-aa-judged", OnnxOptions(), ACCURACY_BUDGET,
                                                                 judged=True)),
    # the recipe without the measurements that choose it: min/max ranges (no histograms, no candidate rules), no
    # bias correction and no AdaRound under the SQNR floor (`--calib-method minmax --bias-correction none
    # --no-adaround-if-far`), to show what they cost and what they buy
    Engine("edgepick-minmax", ONNXRUNTIME, edgepick_quantizer("edgepick-minmax", OnnxOptions(adaround_if_far=False),
                                                              methods=PtqMethods(bias_correction="none"),
                                                              config=QuantConfig(calib_method="minmax"))),
    # one measurement at a time: min/max ranges with bias correction, and the percentile rule pinned (the check
    # tensors counted first, not held out), how far a small change of ranges moves a model's decisions
    Engine("edgepick-minmax-bc", ONNXRUNTIME, edgepick_quantizer("edgepick-minmax-bc", OnnxOptions(),
                                                                 config=QuantConfig(calib_method="minmax"))),
    Engine("edgepick-percentile", ONNXRUNTIME, edgepick_quantizer("edgepick-percentile", OnnxOptions(),
                                                                  config=QuantConfig(calib_method="percentile"))),
    # AdaRound on top of the defaults (`--adaround`), its budget halved to bound the run
    Engine("edgepick-ada", ONNXRUNTIME, edgepick_quantizer("edgepick-ada", OnnxOptions(),
                                                           methods=PtqMethods(adaround=True, adaround_budget_s=60.0))),
    # 8-bit weights (`--weight-bits 8`: exact on CPUs with VNNI, which add in int32), with the defaults and with the
    # percentile rule pinned (beside edgepick-percentile: the weight bits alone)
    Engine("edgepick-w8", ONNXRUNTIME, edgepick_quantizer("edgepick-w8", OnnxOptions(), config=QuantConfig(weight_bits="8"))),
    Engine("edgepick-percentile-w8", ONNXRUNTIME, edgepick_quantizer("edgepick-percentile-w8", OnnxOptions(),
                                                                     config=QuantConfig(calib_method="percentile",
                                                                                        weight_bits="8"))),
    # the file made for OpenVINO: placement auto, the candidates timed on OpenVINO
    Engine("edgepick-openvino", OPENVINO, edgepick_quantizer("edgepick-openvino",
                                                             OnnxOptions(placement="auto", target="openvino"))),
    # the candidates it chose among, each on its own: what the choice left
    *(Engine(f"edgepick-openvino-{p}", OPENVINO, openvino_placement_quantizer(p)) for p in ("all", "convs", "joins")),
)
BASELINES = {ONNXRUNTIME: "fp32", OPENVINO: "fp32-openvino"}  # the fp32 engine of each runtime


def select(names: Sequence[str] | None, available: Sequence[Engine] = ENGINES) -> tuple[Engine, ...]:
    """The engines NAMES asks for (all when None), in the table's order, with the fp32 engine of each
    runtime they use: every metric is measured against fp32 on onnxruntime, each speed-up against fp32
    on the same runtime."""
    by_name = {e.name: e for e in available}
    unknown = [n for n in names or () if n not in by_name]
    if unknown:
        raise SystemExit(f"--engines: unknown {', '.join(unknown)} (known: {', '.join(by_name)})")
    wanted = set(names or by_name)
    wanted |= {BASELINES[ONNXRUNTIME]} | {BASELINES[by_name[n].runtime] for n in wanted}
    return tuple(e for e in available if e.name in wanted)
