"""`edgepick export` and `edgepick quantize static|inspect`: thin click shells over edgepick.quant (the
QaT commands are in cli/qat.py)."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import click

from edgepick.cli.options import (
    choice,
    default_of,
    emit,
    parse_numbers,
    preprocessing_of,
    preprocessing_options,
    with_options,
)
from edgepick.errors import ConfigError
from edgepick.files import check_output
from edgepick.geometry import Size
from edgepick.quant.config import (
    BIAS_CORRECTION_IMAGES,
    DEFAULT_CALIB_IMAGES,
    MAX_FLOAT_LAYERS,
    BiasCorrection,
    CalibMethod,
    GeluForm,
    OnnxOptions,
    Placement,
    PtqMethods,
    QatOptions,
    QuantConfig,
    Target,
    WeightBits,
)
from edgepick.quant.methods import MAX_STEPS


def check_onnx_out_flag(out: str, *inputs: str | None) -> None:
    """Refuse --out up front: not an .onnx file, one of the INPUTS, or in a folder that cannot be made."""
    check_output(out, "--out", suffixes=(".onnx",), inputs=inputs)


common = [
    click.option("--out", required=True, type=click.Path(dir_okay=False),
                 help="int8 ONNX to write (docs/contracts.md#onnx-model)."),
    click.option("--weight-bits", default=default_of(QuantConfig, "weight_bits"), show_default=True,
                 type=choice(WeightBits),
                 help="7: every conv, safe on every x86 CPU (onnxruntime's U8S8 kernels on AVX2-only CPUs add "
                      "pairs of products in int16, which 8-bit weights can saturate). 8: for AVX512-VNNI/AVX-VNNI "
                      "targets. first-7 (static PTQ): 7-bit only on the convs whose int16 pairs saturate on the "
                      "calibration images, 8-bit elsewhere."),
    click.option("--keep-float", default="", metavar="NAMES",
                 help="Comma-separated module names left in float, e.g. classifier.4,backbone.0 (for an .onnx "
                      "MODEL: node names)."),
]


# static PTQ and inspect
calibration = [
    click.option("--calib-images", default=None, type=int,
                 help=f"Train images for calibration [default: {DEFAULT_CALIB_IMAGES}, or the whole train split if "
                      "smaller]; for an .onnx MODEL, the first this many of --calib [default: all]."),
    click.option("--calib-method", default=default_of(QuantConfig, "calib_method"), show_default=True,
                 type=choice(CalibMethod),
                 help="Activation ranges: auto (each rule below measured on 8 held-out calibration inputs; the one "
                      "whose int8 outputs stay closest to fp32's is kept; for a RUN or checkpoint the one that "
                      "changes fewest of fp32's labels; for an .onnx MODEL one that changes fewer of its outputs' "
                      "decisions (--task) where the difference is beyond chance), a percentile of each histogram, min/max, "
                      "KL divergence (entropy) or L2 error (mse). Whatever the rule, a tensor that reaches an "
                      "output through no conv keeps its whole range."),
]


# static PTQ's methods (quant/pt2e/ptq.py): static and inspect
ptq_methods = [
    click.option("--equalize/--no-equalize", default=default_of(PtqMethods, "equalize"), show_default=True,
                 help="Cross-layer equalization: rescale conv pairs joined by ReLU-like ops so that each channel has "
                      "the same weight range in both (BN folded first); exact in float, done before calibration."),
    click.option("--adaround/--no-adaround", default=default_of(PtqMethods, "adaround"), show_default=True,
                 help=f"Learn each int8 conv's weight rounding (up or down) on the first {BIAS_CORRECTION_IMAGES} "
                      "calibration images (fewer above 320x240), so that its output stays closest to fp32's "
                      "(AdaRound)."),
    click.option("--adaround-budget", "adaround_budget_s", default=default_of(PtqMethods, "adaround_budget_s"),
                 type=float, metavar="SECONDS",
                 help="A time limit for AdaRound, shared by the convs (also where an .onnx MODEL's file is made "
                      "again with it: --adaround-if-far, --min-agreement); the file then depends on the machine's "
                      f"speed and load. [default: no limit: {MAX_STEPS} steps per conv, fewer on a large model "
                      "(docs/quantization.md), so that the same inputs give the same file whatever the load]"),
    click.option("--bias-correction", default=default_of(PtqMethods, "bias_correction"), show_default=True,
                 type=choice(BiasCorrection),
                 help=f"Shift each int8 conv's bias so that its output's per-channel mean is fp32's, on the first "
                      f"{BIAS_CORRECTION_IMAGES} calibration images (fewer above 320x240): empirical (each conv on the "
                      "int8 model's own input, layer by layer, AIMET's form; the median of the images' gaps), fast "
                      "(each conv on fp32's input, NNCF's form; not for .onnx models) or none."),
]


@click.command("export")
@click.argument("checkpoint", metavar="RUN_OR_CKPT", type=click.Path())
@click.option("--out", required=True, type=click.Path(dir_okay=False),
              help="fp32 ONNX to write (docs/contracts.md#onnx-model).")
def export_cmd(checkpoint: str, out: str) -> None:
    """Export a float checkpoint (or RUN's best.pt) as an fp32 ONNX: uint8 NHWC `image` in,
    uint8 `labels` out, normalisation and colour space in the graph, edgepick.* metadata."""
    from edgepick.export.onnx_export import export_checkpoint

    check_onnx_out_flag(out, checkpoint)
    emit(export_checkpoint(checkpoint, out))


@click.group()
def quantize() -> None:
    """Int8 passes (torchao pt2e -> QDQ ONNX for onnxruntime): static PTQ, QaT, hybrid-QaT.

    \b
    Activations uint8 (per tensor), weights int8 per channel, symmetric (U8S8: every conv
    fuses to QLinearConv in onnxruntime). Each pass checks that observers were inserted and
    that every conv (but --keep-float ones) has int8 weights in the file, and reports how
    often onnxruntime's labels agree with torch's simulation of the same int8 model.
    """


@quantize.command("static")
@click.argument("checkpoint", metavar="MODEL", type=click.Path())
@click.option("--data", "data_dir", default=None, type=click.Path(),
              help="Data set (for a RUN or checkpoint); calibration uses its train split.")
@click.option("--calib", default=None, type=click.Path(file_okay=False), metavar="DIR",
              help="For an .onnx MODEL: calibration inputs, .npy tensors (one input each, the model's layout) or "
                   "images made into tensors by the preprocessing options.")
@click.option("--input-shape", default=None, metavar="N,C,H,W",
              help="For an .onnx MODEL with dynamic input dims [default: the first calibration tensor's shape].")
@click.option("--placement", default=default_of(OnnxOptions, "placement"), show_default=True, type=choice(Placement),
              help="For an .onnx MODEL: all (every op onnxruntime runs in int8, with edgepick's activation "
                   "rewrites: for onnxruntime), convs (only the convs and the tensors they read; a conv's "
                   "activation reads its float output and the model's activations stay float as written, which "
                   "OpenVINO fuses into its int8 convs), joins (convs, matmuls, and the adds, concats, splits and "
                   "pools that join branches, a Concat's inputs on its grid, as NNCF places them) or "
                   "auto (each made and timed on --target on this machine; the fastest whose outputs stay within "
                   "1 dB SQNR of the closest candidate's, or at 35 dB or more, is written, or one within 3 dB that "
                   "runs 1.25x as fast; the times in its metadata).")
@click.option("--target", default=default_of(OnnxOptions, "target"), show_default=True, type=choice(Target),
              help="For an .onnx MODEL with --placement auto: the engine the file is timed on (openvino needs the "
                   "[peers] extra).")
@click.option("--gelu", default=default_of(OnnxOptions, "gelu"), show_default=True, type=choice(GeluForm),
              help="For an .onnx MODEL with --placement all: float (each GELU runs as the model writes it, in float "
                   "between its Q/DQ: onnxruntime has no integer Erf) or sigmoid (written as c*x*sigmoid(alpha*x), "
                   "alpha fitted per layer, on onnxruntime's integer kernels: faster, an approximation). Time both "
                   "and compare their agreement with benchmarks/peers_onnx.py.")
@click.option("--adaround-if-far/--no-adaround-if-far", default=default_of(OnnxOptions, "adaround_if_far"),
              show_default=True,
              help="For an .onnx MODEL: where the file's worst output SQNR against fp32 is under 10 dB, make it "
                   "again with AdaRound (see --adaround-budget) and keep that file when its outputs "
                   "come closer to fp32's on the check tensors and on their worse half (recorded as adaround_first).")
@click.option("--time-against-fp32/--no-time-against-fp32", default=default_of(OnnxOptions, "time_against_fp32"),
              show_default=True,
              help="For an .onnx MODEL: time the int8 file against the float model on onnxruntime on this machine "
                   "(2 threads, 20 runs each), record both (speed in the file's edgepick.quant) and warn where int8 is "
                   "the slower: on a CPU with AVX2 alone, without VNNI, it can be.")
@with_options(calibration)
@click.option("--percentile", default=default_of(QuantConfig, "percentile"), show_default=True,
              help="For --calib-method percentile (with auto: one of the percentiles tried).")
@click.option("--task", "tasks", multiple=True, metavar="[OUTPUT=]TASK",
              help="For an .onnx MODEL: what an output decides, for the agreement with fp32 in the report: labels "
                   "(argmax over channels), threshold:T (the F1 score of the cells above T), top1 (argmax per row), "
                   "boxes:T (a detector's table of cx, cy, w, h and class scores per row, as YOLOv8 exports it: the "
                   "F1 score of the boxes scoring above T, "
                   "0.25 by default, after NMS), boxes-obj:T (the same with an objectness score after the box, as "
                   "YOLOv5), ctc (a text recogniser's [steps, classes] scores: the character accuracy of its "
                   "greedy CTC strings, class 0 the blank) or raw (SQNR and cosine only); OUTPUT= for one output, "
                   "else all [default: guessed from each output's shape and op].")
@with_options(ptq_methods)
@click.option("--seed", default=0, show_default=True, help="Which calibration images are drawn.")
@click.option("--max-miou-drop", default=None, type=float, metavar="PP",
              help="Accuracy-aware: keep the layers adding the most drift in float, one at a time, until the val "
                   "mIoU (onnxruntime) is within PP percentage points of fp32's.")
@click.option("--min-agreement", default=None, type=float, metavar="SHARE",
              help="For an .onnx MODEL, accuracy-aware: where the file misses the budget, try AdaRound first (kept "
                   "when it brings the outputs closer), then leave the activations whose float values bring the "
                   "outputs closest to fp32 float, one at a time, then whole regions of the graph (with a large "
                   "enough --max-float-layers), until every output that decides something agrees with fp32 on at "
                   "least SHARE (0-1) of its decisions on the check tensors (the first calibration tensors: up "
                   "to 32 where they are small and --calib-images leaves them after AdaRound's).")
@click.option("--min-sqnr", default=None, type=float, metavar="DB",
              help="For an .onnx MODEL, accuracy-aware: ... until every output's SQNR against fp32 is at least DB.")
@click.option("--max-float-layers", default=MAX_FLOAT_LAYERS, show_default=True,
              help="With --max-miou-drop, --min-agreement or --min-sqnr: at most this many layers (activations) "
                   "left float.")
@click.option("--max-seconds", default=None, type=float, metavar="SECONDS",
              help="With --min-agreement or --min-sqnr: stop the search for activations to leave float after "
                   "SECONDS and write the closest file found by then (said in a warning and in the file's "
                   "accuracy_aware record; AdaRound, tried before the search, has its own: --adaround-budget) "
                   "[default: no limit].")
@with_options(common)
@with_options(preprocessing_options)
def quantize_static_cmd(checkpoint: str, out: str, **flags) -> None:
    """Static post-training quantization of MODEL: a float RUN or checkpoint of edgepick's (BN
    folded, ranges calibrated on --calib-images train images of --data), or a float ONNX file
    from any exporter (calibrated on --calib; --keep-float then names ONNX nodes).

    \b
    edgepick quantize static RUN --data DATA --out int8.onnx
    edgepick quantize static model.onnx --calib images/ --mean 0.485,0.456,0.406 --std 0.229,0.224,0.225 --out int8.onnx
    """
    onnx_model = Path(checkpoint).suffix.lower() == ".onnx"
    _refuse_other_kinds(flags, onnx_model)
    budget = _budget(flags.pop("min_agreement"), flags.pop("min_sqnr"), flags["max_float_layers"], flags.pop("max_seconds"))
    shared = {k: flags.pop(k) for k in ("calib_images", "max_float_layers", "seed", "max_miou_drop", "calib",
                                        "input_shape", "tasks", "data_dir")}
    prep = {k: flags.pop(k) for k in list(flags) if k not in _CONFIG_FIELDS}
    if onnx_model:
        _quantize_onnx(checkpoint, out, shared, configs_of(**flags), prep, budget)
        return
    if shared["data_dir"] is None:
        raise ConfigError("--data is needed to calibrate a RUN or checkpoint (--calib is for .onnx models)")
    check_onnx_out_flag(out, checkpoint, shared["data_dir"])
    if shared["seed"] < 0:
        raise ConfigError(f"--seed {shared['seed']}: must be 0 or positive")
    _quantize_checkpoint(checkpoint, out, shared, configs_of(**flags))


# flags only one kind of MODEL takes (parameter, flag as the error names it): another value than the default
# for the other kind is refused in one line
_ONNX_ONLY = (("calib", "--calib"), ("input_shape", "--input-shape"), ("tasks", "--task"),
              ("min_agreement", "--min-agreement"), ("min_sqnr", "--min-sqnr"), ("max_seconds", "--max-seconds"),
              ("placement", "--placement {}"), ("target", "--target {}"), ("gelu", "--gelu {}"),
              ("adaround_if_far", "--no-adaround-if-far"), ("time_against_fp32", "--no-time-against-fp32"))
_RUN_ONLY = (("data_dir", "--data"), ("max_miou_drop", "--max-miou-drop"), ("seed", "--seed"))
_CONFIGS = {"config": QuantConfig, "methods": PtqMethods, "options": OnnxOptions, "qat": QatOptions}
_CONFIG_FIELDS = {f.name for kind in _CONFIGS.values() for f in fields(kind)}


def _refuse_other_kinds(flags: dict, onnx_model: bool) -> None:
    """Refuse the flags the other kind of MODEL takes (given with another value than their default)."""
    defaults = {p.name: p.default for p in click.get_current_context().command.params}
    for name, flag in _RUN_ONLY if onnx_model else _ONNX_ONLY:
        value = flags[name]
        if value != defaults[name] and value not in (None, ()):
            kind = "a RUN or checkpoint, not an .onnx MODEL" if onnx_model else "an .onnx MODEL, not a RUN or checkpoint"
            raise ConfigError(f"{flag.format(value)} is for {kind}")
    if onnx_model and flags["bias_correction"] == BiasCorrection.FAST:
        raise ConfigError("--bias-correction fast is for a RUN or checkpoint; an .onnx MODEL takes empirical")


def configs_of(keep_float: str = "", **options) -> dict:
    """The configs of a command's options, each made of the options that are its fields (KEEP_FLOAT
    comma-separated), by the keyword the passes take them as."""
    options["keep_float"] = tuple(k.strip() for k in keep_float.split(",") if k.strip())
    found = {}
    for key, kind in _CONFIGS.items():
        names = {f.name for f in fields(kind)} & options.keys()
        if names:
            found[key] = kind(**{name: options[name] for name in names})
    return found


def _quantize_checkpoint(checkpoint: str, out: str, shared: dict, configs: dict) -> None:
    """`quantize static RUN --data DATA`: static PTQ (or the accuracy-aware search) of a checkpoint."""
    configs.pop("options", None)  # its defaults: a torch model's int8 graph quantizes every activation
    from edgepick.quant.pt2e.images import agreement_images, check_classes, check_image_count, folder_images
    from edgepick.train.checkpoint import Checkpoint

    data, count, seed = shared["data_dir"], shared["calib_images"], shared["seed"]
    check_image_count(data, "train", count)
    if shared["max_miou_drop"] is not None:
        from edgepick.quant.pt2e.inspect import quantize_accuracy_aware

        emit(quantize_accuracy_aware(checkpoint, folder_images(data, "train", count, seed), data, out,
                                     shared["max_miou_drop"], max_float_layers=shared["max_float_layers"], **configs))
        return
    from edgepick.quant.pt2e.passes import quantize_static

    ckpt = Checkpoint.load(checkpoint)
    check_classes(ckpt, data)
    emit(quantize_static(ckpt, folder_images(data, "train", count, seed), out, **configs,
                         check_images=agreement_images(data, seed)))


def _budget(min_agreement: float | None, min_sqnr: float | None, max_float: int, max_seconds: float | None):
    """The accuracy-aware mode's FidelityBudget of the flags, or None when neither is given."""
    if min_agreement is None and min_sqnr is None:
        if max_seconds is not None:
            raise ConfigError("--max-seconds limits the accuracy-aware mode: give --min-agreement or --min-sqnr too")
        return None
    from edgepick.quant.onnx.accuracy import FidelityBudget

    return FidelityBudget(min_agreement=min_agreement, min_sqnr_db=min_sqnr, max_float=max_float,
                          max_seconds=max_seconds)


def _quantize_onnx(model: str, out: str, shared: dict, configs: dict, preprocessing: dict, budget=None) -> None:
    """`quantize static MODEL.onnx --calib DIR`: edgepick's recipe on a float ONNX file."""
    from edgepick.export.onnx_io import image_size, load_float_onnx
    from edgepick.quant.fidelity import parse_tasks
    from edgepick.quant.onnx.inputs import folder_tensors
    from edgepick.quant.onnx.static import quantize_onnx_static

    calib, input_shape, calib_images = shared["calib"], shared["input_shape"], shared["calib_images"]
    if calib is None:
        raise ConfigError("--calib DIR is needed to calibrate an .onnx MODEL (.npy tensors or images)")
    check_onnx_out_flag(out, model, calib)
    prep = preprocessing_of(**preprocessing)
    shape = parse_numbers(input_shape, "--input-shape", integer=True) if input_shape else None
    if shape is not None and any(d < 1 for d in shape):
        raise ConfigError(f"--input-shape {input_shape}: every dim must be 1 or more")
    size = prep.size
    if size is None and shape is not None and len(shape) == 4:
        hw = shape[2:4] if prep.layout == "nchw" else shape[1:3]
        size = Size.from_hw(hw)
    if size is None:
        size = image_size(load_float_onnx(model), prep.layout)
    if calib_images is not None and calib_images < 1:
        raise ConfigError(f"--calib-images {calib_images}: must be 1 or more")
    tensors = folder_tensors(calib, prep, size, calib_images)
    emit(quantize_onnx_static(model, tensors, out, **configs, input_shape=shape, task=parse_tasks(shared["tasks"]),
                              budget=budget))


_GAIN_HEADERS = {"equalize": "CLE gain dB", "adaround": "AdaRound gain dB", "bias_correction": "bias corr. gain dB"}


@quantize.command("inspect")
@click.argument("checkpoint", metavar="RUN_OR_CKPT", type=click.Path())
@click.option("--data", "data_dir", required=True, type=click.Path(), help="Calibration (train) and comparison (val) images.")
@with_options(calibration)
@click.option("--images", default=8, show_default=True, help="Val images compared.")
@click.option("--top", default=10, show_default=True, help="Rows of the worst-layers table on stderr.")
@click.option("--weight-bits", default=default_of(QuantConfig, "weight_bits"), show_default=True,
              type=choice(WeightBits), help="As for quantize static.")
@with_options(ptq_methods)
def quantize_inspect_cmd(checkpoint: str, data_dir: str, calib_images: int | None, calib_method: str, images: int, top: int,
                         weight_bits: str, equalize: bool, adaround: bool, adaround_budget_s: float | None,
                         bias_correction: str) -> None:
    """Where int8 drifts from fp32: per conv layer, the SQNR of the int8 simulation against fp32 and
    the drift it adds; the worst layers are the --keep-float candidates. With --equalize,
    --adaround or a --bias-correction other than none (empirical by default), the model is made
    again with each added in turn (in that order), and each layer says how many dB each one gained
    it. JSON on stdout."""
    from edgepick.quant.pt2e.images import check_classes, check_image_count, folder_images
    from edgepick.quant.pt2e.inspect import inspect
    from edgepick.train.checkpoint import Checkpoint

    if top < 0:
        raise ConfigError(f"--top {top}: the number of rows must be 0 or more")
    check_image_count(data_dir, "train", calib_images)
    check_image_count(data_dir, "val", images, "val images to compare (--images)")
    ckpt = Checkpoint.load(checkpoint)
    check_classes(ckpt, data_dir)
    report = inspect(ckpt, folder_images(data_dir, "train", calib_images),
                     folder_images(data_dir, "val", images, what="val images"),
                     **configs_of(calib_method=calib_method, weight_bits=weight_bits, equalize=equalize,
                                adaround=adaround, adaround_budget_s=adaround_budget_s, bias_correction=bias_correction))
    by_name = {r["layer"]: r for r in report["layers"]}
    click.echo(f"logits SQNR {report['logits_sqnr_db']} dB, labels equal to fp32: {report['label_agreement']}", err=True)
    methods = [m for m in ("equalize", "adaround", "bias_correction") if m in report]
    for method in methods:
        click.echo(f"+ {method.replace('_', ' ')}: logits SQNR {report[method]['logits_sqnr_db']} dB, labels equal to "
                   f"fp32: {report[method]['label_agreement']}", err=True)
    gains = "".join(f" {_GAIN_HEADERS[m]:>19s}" for m in methods)
    click.echo(f"{'layer':40s} {'SQNR dB':>8s} {'added drift dB':>15s}{gains}", err=True)
    for name in report["ranked"][:top]:
        row = by_name[name]
        gains = "".join(f" {row[m + '_gain_db'] if row[m + '_gain_db'] is not None else '-':>19}" for m in methods)
        click.echo(f"{name:40s} {row['sqnr_db']:8.2f} {row['added_drift_db']:15.2f}{gains}", err=True)
    emit(report)
