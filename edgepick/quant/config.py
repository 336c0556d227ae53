"""How a model is quantized: the core every pass is given (`QuantConfig`), and what only some passes
choose (`PtqMethods`, `OnnxOptions`, `QatOptions`, `Pt2eOptions`): each pass takes the configs it
uses and no other. Their choices and the passes' shared defaults too, without torch: the command
line builds its options and defaults from them."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields
from typing import Self

from edgepick.errors import ParameterError
from edgepick.schema import member, plain

DEFAULT_CALIB_IMAGES = 64  # or the whole train split when it is smaller
FREEZE_AT = 0.7  # share of the QaT steps after which observers and BN statistics are frozen
# the images bias correction, first-7 and AdaRound measure on: BIAS_CORRECTION_IMAGES calibration images (an
# .onnx model's: those after its check inputs), fewer where the model's input is larger than 320x240. The
# empirical form and AdaRound run them in lockstep, holding every image's live activations at once, so the
# pixels are bounded rather than the images: 32 images at 320x240 peak at about 2.6 GB with
# DeepLabV3-MobileNetV3 (benchmarks/results/ptq-methods/).
BIAS_CORRECTION_IMAGES = 32
LOCKSTEP_PIXELS = BIAS_CORRECTION_IMAGES * 320 * 240
MIN_LOCKSTEP_IMAGES = 4  # below this the per-channel means and AdaRound's sampled positions get too few images
# calib_method auto: calibration inputs the candidate rules are compared on, held out of the ranges while they are
# (with fewer other inputs than these to calibrate on, they are used for both)
HELD_OUT_INPUTS = 8
SATURATION_CHECK_INPUTS = 8  # calibration inputs on which first-7 measures where 8-bit weights saturate
# first-7 also gives 7 bits to a conv whose pair sums come within this share of the int16 limit on those
# inputs, since other images go further (benchmarks/results/ptq-methods/ measures the agreement it keeps).
HEADROOM = 0.8


# an .onnx model's check inputs (its fidelity, the held-out inputs of calib_method auto): fp32's outputs on them are
# held in memory, so their pixels are bounded: 8 inputs up to 640x480, fewer above, never under 2
CHECK_PIXELS = 8 * 640 * 480


# the accuracy-aware mode checks its budget on more inputs where they are small: a budget of 99.5% of the
# decisions needs hundreds of them (one character misread among 200 is already 0.5%)
ACCURACY_CHECK_INPUTS = 32
ACCURACY_CHECK_PIXELS = 4 * CHECK_PIXELS


def check_inputs(height: int, width: int) -> int:
    """How many HEIGHT x WIDTH inputs an .onnx model's fidelity is checked on (and auto holds out)."""
    return min(HELD_OUT_INPUTS, max(2, CHECK_PIXELS // max(height * width, 1)))


def accuracy_check_inputs(height: int, width: int, total: int | None, fitting: int) -> int:
    """How many HEIGHT x WIDTH inputs the accuracy-aware mode checks its budget on: `check_inputs`, or up to
    ACCURACY_CHECK_INPUTS where their pixels allow and TOTAL calibration inputs (None: not known) leave
    FITTING after them for AdaRound and bias correction to fit on."""
    more = min(ACCURACY_CHECK_INPUTS, ACCURACY_CHECK_PIXELS // max(height * width, 1))
    if total is not None:
        more = min(more, total - fitting)
    return max(check_inputs(height, width), more)


def lockstep_images(height: int, width: int) -> int:
    """How many HEIGHT x WIDTH calibration images bias correction and AdaRound measure on."""
    return min(BIAS_CORRECTION_IMAGES, max(MIN_LOCKSTEP_IMAGES, LOCKSTEP_PIXELS // max(height * width, 1)))
MAX_FLOAT_LAYERS = 6  # accuracy-aware static PTQ: the most layers it keeps in float


class CalibMethod(enum.StrEnum):
    """How static PTQ sets activation ranges (compared by benchmarks/calib_methods.py)."""

    # every rule below, each tried on held-out calibration inputs; the one whose int8 outputs stay closest to
    # fp32's is kept, or one that changes fewer of fp32's decisions (labels on a run; on an .onnx model, beyond
    # chance) (quant/onnx/qdq.py, quant/pt2e/graph.py, quant/fidelity.py ranked_rule)
    AUTO = "auto"
    MINMAX = "minmax"
    PERCENTILE = "percentile"  # a percentile of each histogram: clips rare outliers
    ENTROPY = "entropy"  # KL-divergence minimisation (TensorRT's entropy calibration)
    MSE = "mse"  # L2 error of the histogram's quantization (slower)


class BiasCorrection(enum.StrEnum):
    """How static PTQ corrects the mean shift quantization gives each conv's output (quant/pt2e/bias_correction.py)."""

    NONE = "none"
    FAST = "fast"  # each conv on the float model's input (NNCF's fast bias correction)
    EMPIRICAL = "empirical"  # each conv on the int8 model's own input, errors before it included (AIMET's)


class Placement(enum.StrEnum):
    """Which tensors of an .onnx model static PTQ puts on the int8 grid (quant/onnx/static.py); the
    faster file depends on the engine and the model (benchmarks/results/peers-onnx/)."""

    ALL = "all"  # every op onnxruntime runs in int8, with edgepick's activation rewrites: made for onnxruntime
    # only the convs (inputs, weights) and what a conv reads; a conv's output on the grid only where a quantized op reads
    # it, the model's activation ops float, as written: OpenVINO fuses them into its int8 convs where it recognises them
    CONVS = "convs"
    # the convs, matmuls and the ops that join branches (Add, Concat, Split; a Concat's inputs on its own grid) and pool,
    # the model's other activations float as written: where NNCF places its fake-quants for OpenVINO
    JOINS = "joins"
    # each of the above made, timed on the target engine on this machine, and the fastest whose outputs stay as close
    # to fp32 as the closest's (quant/onnx/placement.py)
    AUTO = "auto"


class Target(enum.StrEnum):
    """The engine an .onnx model's int8 file is made for: placement auto times the candidates on it."""

    ONNXRUNTIME = "onnxruntime"
    OPENVINO = "openvino"  # the [peers] extra


class GeluForm(enum.StrEnum):
    """How static PTQ of an .onnx model runs a GELU (x * Phi(x), written with Erf): onnxruntime has no
    integer kernel for Erf (quant/onnx/gelu.py; benchmarks/results/peers-onnx/ times both)."""

    FLOAT = "float"  # as the model writes it, each step in float between its Q/DQ: exact but for their rounding
    SIGMOID = "sigmoid"  # c * x * sigmoid(alpha * x), alpha fitted per layer: integer kernels, an approximation


class WeightBits(enum.StrEnum):
    """Weight precision. onnxruntime's U8S8 kernels on AVX2 CPUs without VNNI (the thesis's laptop) add pairs
    of u8*s8 products in int16, which can saturate with 8-bit weights and never with 7-bit ones (quant/pt2e/overflow.py)."""

    SEVEN = "7"  # every conv: safe on every x86 CPU
    EIGHT = "8"  # every conv: for AVX512-VNNI / AVX-VNNI CPUs, which add in int32
    FIRST_SEVEN = "first-7"  # static PTQ: 7-bit only on the convs measured to saturate on the calibration images


class _Config:
    """What the configs share: their fields as a file records them, and back."""

    def to_dict(self) -> dict:
        """The fields as ONNX metadata and QaT checkpoints record them (plain values, lists)."""
        return {f.name: list(v) if isinstance(v := plain(getattr(self, f.name)), tuple) else v
                for f in fields(self)}  # type: ignore[arg-type]

    @classmethod
    def from_dict(cls, record: dict) -> Self:
        """The config of the fields RECORD has for it (a record may hold other configs' fields too)."""
        return cls(**{f.name: record[f.name] for f in fields(cls) if f.name in record})  # type: ignore[arg-type]


@dataclass(frozen=True)
class QuantConfig(_Config):
    """What every pass is given: the weights' precision, how activation ranges are calibrated, and
    what stays float. Checked on creation; written into the file's metadata (`edgepick.quant`)."""

    calib_method: CalibMethod = CalibMethod.AUTO  # activation ranges for static PTQ
    percentile: float = 99.99  # static PTQ's percentile rule; hybrid-QaT's calibrated start
    weight_bits: WeightBits = WeightBits.SEVEN
    keep_float: tuple[str, ...] = ()  # module names (prefixes), or an .onnx model's node names, left in float

    def __post_init__(self) -> None:
        object.__setattr__(self, "calib_method", member(CalibMethod, "calib_method", self.calib_method))
        object.__setattr__(self, "weight_bits", member(WeightBits, "weight_bits", str(self.weight_bits)))
        object.__setattr__(self, "keep_float", tuple(self.keep_float))
        if not 50.0 < self.percentile <= 100.0:
            raise ParameterError("{percentile}: must be in (50, 100]", percentile=self.percentile)

    @property
    def reduce_range(self) -> bool:
        """7-bit weights on every conv the quantizer annotates (first-7 starts from 8 and measures)."""
        return self.weight_bits == WeightBits.SEVEN

    @classmethod
    def from_dict(cls, record: dict) -> Self:
        """A config as to_dict wrote it, also from files written before weight_bits (reduce_range: bool)."""
        record = dict(record)
        if "reduce_range" in record:
            record.setdefault("weight_bits", WeightBits.SEVEN if record.pop("reduce_range") else WeightBits.EIGHT)
        return super().from_dict(record)


@dataclass(frozen=True)
class PtqMethods(_Config):
    """Static PTQ's methods on the calibration images, in the order the passes apply them (the torch
    pass, the ONNX pass and `inspect` take them; QaT learns its weights instead)."""

    equalize: bool = False  # cross-layer equalization of conv pairs before calibration
    adaround: bool = False  # learn each conv's weight rounding on the calibration images
    # AdaRound's time budget, shared by the convs; None: steps planned from the model's size (a repeatable file)
    adaround_budget_s: float | None = None
    # shift conv biases back to fp32's means; empirical was as close to fp32 as none or closer on every model
    # measured (benchmarks/results/ptq-methods/, ptq-methods-onnx/); fast is the torch pass's only
    bias_correction: BiasCorrection = BiasCorrection.EMPIRICAL

    def __post_init__(self) -> None:
        object.__setattr__(self, "bias_correction", member(BiasCorrection, "bias_correction", self.bias_correction))
        if self.adaround_budget_s is not None and not (math.isfinite(self.adaround_budget_s) and self.adaround_budget_s > 0):
            raise ParameterError("{adaround_budget_s}: must be a positive number of seconds",
                                 adaround_budget_s=self.adaround_budget_s)

    @property
    def measures(self) -> bool:
        """Whether conversion runs the model on calibration inputs for these methods (AdaRound, bias correction)."""
        return self.adaround or self.bias_correction != BiasCorrection.NONE


@dataclass(frozen=True)
class OnnxOptions(_Config):
    """What only the ONNX pass (`quantize_onnx_static`) can choose: which tensors go on the int8 grid,
    for which engine, how a GELU runs, and whether a file far from fp32 is made again with AdaRound."""

    placement: Placement = Placement.ALL
    target: Target = Target.ONNXRUNTIME  # with placement auto: the engine the candidates are timed on
    gelu: GeluForm = GeluForm.FLOAT  # with placement all
    # where the file's worst output SQNR is under the floor (10 dB), make it again with AdaRound, kept when closer:
    # on the conformance models under it, AdaRound moved the task metric most (docs/quantization.md)
    adaround_if_far: bool = True
    # time the file against the float model on onnxruntime on this machine, record both and warn where int8 is the
    # slower (quant/onnx/speed.py: on a CPU with AVX2 alone it can be)
    time_against_fp32: bool = True

    def __post_init__(self) -> None:
        object.__setattr__(self, "placement", member(Placement, "placement", self.placement))
        object.__setattr__(self, "target", member(Target, "target", self.target))
        object.__setattr__(self, "gelu", member(GeluForm, "gelu", self.gelu))
        if self.gelu != GeluForm.FLOAT and self.placement in (Placement.CONVS, Placement.JOINS):
            raise ParameterError("{gelu}: with {placement} the GELU's own ops stay float; it needs placement all",
                                 gelu=self.gelu, placement=self.placement)
        if self.target != Target.ONNXRUNTIME and self.placement != Placement.AUTO:
            raise ParameterError("{target}: the engine placement auto times the candidates on; with {placement} the "
                                 "file is made as that placement says: give placement auto",
                                 target=self.target, placement=self.placement)


@dataclass(frozen=True)
class QatOptions(_Config):
    """What only QaT and hybrid-QaT choose: how the weight ranges follow training, and when the
    observers and BatchNorm statistics freeze."""

    # moving-average constant of the per-channel weight ranges (torch.ao's default 0.01; 1.0: each step's own
    # range). With the conv-BN fusion the quantized weight is w * gamma / sqrt(running_var + eps), which moves
    # with the BN statistics every step: a lagging range clips it (benchmarks/results/hybrid-start/).
    weight_averaging: float = 0.01
    freeze_at: float = FREEZE_AT  # share of the QaT steps after which observers and BN statistics freeze (1.0: never)

    def __post_init__(self) -> None:
        if not 0.0 < self.weight_averaging <= 1.0:
            raise ParameterError("{weight_averaging}: must be in (0, 1]", weight_averaging=self.weight_averaging)
        if not 0.0 <= self.freeze_at <= 1.0:
            raise ParameterError("{freeze_at}: must be inside [0, 1]", freeze_at=self.freeze_at)


@dataclass(frozen=True)
class Pt2eOptions(_Config):
    """How the torch passes prepare a model's graph (static PTQ of a checkpoint or an nn.Module, QaT,
    hybrid-QaT); the ONNX pass rewrites a graph's activations itself."""

    # hardswish as x * hardsigmoid(x), both quantized (rewrites.GatedHardswish): onnxruntime then runs it on integer
    # kernels; as one quantized op it dequantizes the map and runs in float (benchmarks/quant_speed.py times both).
    hardswish_gate: bool = True
    skip: tuple[str, ...] = ("preprocess",)  # module names never quantized

    def __post_init__(self) -> None:
        object.__setattr__(self, "skip", tuple(self.skip))
