"""The math of static PTQ's methods that the torch pass (quant/pt2e/) and the ONNX pass (quant/onnx/)
share, in numpy, so that the ONNX pass runs without torch:

- cross-layer equalization's scale rule (`equalizing_scales`);
- first-7's measure: the share of a conv's outputs whose int16 pair sums saturate on an AVX2 CPU
  (`saturated_share`);
- AdaRound's solver: one conv's up/down rounding learnt on its sampled inputs (`round_conv`), and
  its steps per conv where no time budget is given (`planned_steps`);
- empirical bias correction's rule: the median over the images of each channel's mean gap
  (`bias_shift`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Iterator

import numpy as np

ROUNDS = 20  # CLE: passes over the pairs; a conv between two others is pulled both ways and settles in a few
TOLERANCE = 1e-3  # CLE: stop when no scale moves by more than this share

# first-7 (see quant/pt2e/overflow.py for the kernel it models)
INT16 = 32767
PAIRS_AT_ONCE = 32  # K pairs multiplied per step: memory is pairs x positions x output channels

# AdaRound
COLUMNS = 4096  # input columns (positions) kept per conv, spread over the calibration images
BATCH = 512  # columns per optimisation step
MAX_STEPS = 2000
MIN_STEPS = 20
LEARNING_RATE = 1e-2
REGULARIZATION = 0.01  # AIMET's default weight of the rounding regulariser
WARM_START = 0.2  # share of the steps without the regulariser
BETA = (20.0, 2.0)
STEP_OVERHEAD = 20_000  # weights' worth of per-step cost that does not grow with the conv
# weight-steps a model's AdaRound may take without a time budget: MAX_STEPS per conv while the convs' costs
# (weights plus STEP_OVERHEAD each) sum to at most 4M
WORK = 8e9
ZETA, GAMMA = 1.1, -0.1  # the rectified sigmoid's stretch
ADAM = (0.9, 0.999, 1e-8)  # Adam's betas and epsilon (torch.optim.Adam's defaults)


def planned_steps(costs: Iterable[int]) -> int:
    """AdaRound's steps per conv where no time budget is given: MAX_STEPS where the convs' COSTS (a
    step's work: the conv's weights plus STEP_OVERHEAD) afford them within WORK, fewer on a larger
    model, MIN_STEPS at least. From the model alone, so that the same inputs give the same file
    whatever the machine's speed and load."""
    return int(min(MAX_STEPS, max(MIN_STEPS, WORK // max(sum(costs), 1))))


def adaround_done(report: dict[str, dict]) -> dict[str, int]:
    """What a pass records of AdaRound's REPORT (per conv: its errors and steps): how many convs
    kept a learnt rounding, and the steps per conv (their median where a time budget shared them)."""
    steps = sorted(r["steps"] for r in report.values())
    return {"adaround_convs": sum(r["error_adaround"] < r["error_nearest"] for r in report.values()),
            "adaround_steps": steps[len(steps) // 2] if steps else 0}


def equalizing_scales(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Per channel s = sqrt(r1 / r2), which gives both layers the range sqrt(r1 * r2); 1 where
    either range is 0 (a dead channel stays as it is)."""
    live = (r1 > 0) & (r2 > 0)
    return np.where(live, np.sqrt(r1 / np.where(live, r2, 1.0)), 1.0)


def conv_taps(x: np.ndarray, kernel: tuple[int, int], stride: tuple[int, ...], dilation: tuple[int, ...]
              ) -> Iterator[tuple[int, int, np.ndarray]]:
    """For each kernel tap (i, j), in row-major order, the [N, C, Ho, Wo] view of the (already
    padded) input X that the tap multiplies at every output position of the conv."""
    kh, kw = kernel
    out_h = (x.shape[2] - dilation[0] * (kh - 1) - 1) // stride[0] + 1
    out_w = (x.shape[3] - dilation[1] * (kw - 1) - 1) // stride[1] + 1
    for i in range(kh):
        for j in range(kw):
            top, left = i * dilation[0], j * dilation[1]
            yield i, j, x[:, :, top:top + stride[0] * (out_h - 1) + 1:stride[0], left:left + stride[1] * (out_w - 1) + 1:
                          stride[1]]


def saturated_share(codes: np.ndarray, weights: np.ndarray, zero_point: int, stride: tuple[int, ...],
                    padding: tuple[int, ...], dilation: tuple[int, ...], groups: int, limit: float = INT16) -> float:
    """Share of a conv's outputs (positions x output channels) where at least one int16 pair sum of
    uint8 input CODES [N, C, H, W] and int8 WEIGHTS [M, C/groups, kh, kw] leaves +-LIMIT: the kernel
    pairs neighbouring products along K in kernel-row, kernel-column, input-channel order (input
    padded with the zero point). Depthwise convs run on a kernel that widens to 32 bits first: 0."""
    m, c_group, kh, kw = weights.shape
    if c_group == 1 and groups > 1:
        return 0.0
    pads = ((0, 0), (0, 0), (padding[0], padding[0]), (padding[1], padding[1]))
    x = np.pad(codes.astype(np.float32), pads, constant_values=float(zero_point))
    per_group = m // groups
    hits = []
    for g in range(groups):
        taps = [t for _, _, t in conv_taps(x[:, g * c_group:(g + 1) * c_group], (kh, kw), stride, dilation)]
        n, positions = taps[0].shape[0], taps[0].shape[2] * taps[0].shape[3]
        cols = np.stack(taps, axis=1).reshape(n, kh * kw * c_group, positions)  # K in (kh, kw, c) order
        w = weights[g * per_group:(g + 1) * per_group].astype(np.float32).transpose(0, 2, 3, 1).reshape(per_group, -1)
        k = w.shape[1] + w.shape[1] % 2
        cols = np.pad(cols, ((0, 0), (0, k - cols.shape[1]), (0, 0)))
        w = np.pad(w, ((0, 0), (0, k - w.shape[1])))
        a = cols.transpose(1, 0, 2).reshape(k // 2, 2, n * positions)  # [pairs, 2, N*L]
        b = w.T.reshape(k // 2, 2, per_group)  # [pairs, 2, M_g]
        over = np.zeros((n * positions, per_group), dtype=bool)
        for j in range(0, k // 2, PAIRS_AT_ONCE):
            sums = np.matmul(a[j:j + PAIRS_AT_ONCE].transpose(0, 2, 1), b[j:j + PAIRS_AT_ONCE])  # [pairs, N*L, M_g]
            over |= (np.abs(sums) > limit).any(axis=0)
        hits.append(over)
    return float(np.concatenate(hits, axis=1).mean())


def bias_shift(fp32_means: np.ndarray, int8_means: np.ndarray) -> np.ndarray:
    """Empirical bias correction's shift of one conv's bias: per channel, the median over the images
    of fp32's minus int8's output mean (both [images, channels]); the median, so that one image whose
    activations are clipped hard does not set every image's bias."""
    return np.quantile(fp32_means - int8_means, 0.5, axis=0)


def _grouped(w: np.ndarray, groups: int) -> np.ndarray:
    """[M, C/g, kh, kw] as [g, M/g, C/g*kh*kw], the order im2col gives the columns of each group."""
    return w.reshape(groups, w.shape[0] // groups, -1)


def _output(w: np.ndarray, bias: np.ndarray, x: np.ndarray, groups: int) -> np.ndarray:
    """The conv's output [M, P] on columns X [C*kh*kw, P] with weights W [g, M/g, K/g]."""
    return np.matmul(w, x.reshape(groups, x.shape[0] // groups, -1)).reshape(-1, x.shape[1]) + bias[:, None]


def _error(w: np.ndarray, bias: np.ndarray, x_rows: np.ndarray, target_rows: np.ndarray, groups: int) -> float:
    """AIMET's reconstruction loss of the conv with weights W [g, M/g, K/g] on the rows X_ROWS [P, K]
    against TARGET_ROWS [P, M]: squared error summed over channels, mean over positions. On the rows,
    as the solver holds them: the columns' grouped view of a wide conv would be a copy of them all."""
    if groups == 1:
        y = x_rows @ w[0].T
    else:
        y = np.einsum("pgk,gmk->pgm", x_rows.reshape(len(x_rows), groups, -1), w).reshape(len(x_rows), -1)
    return float(np.square(y + bias - target_rows).sum(axis=1).mean())


def _soft(v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rectified sigmoid h(V) in [0, 1], its sigmoid, and where it is not clipped."""
    sig = 1.0 / (1.0 + np.exp(-v))
    stretched = sig * np.float32(ZETA - GAMMA) + np.float32(GAMMA)
    return np.clip(stretched, 0.0, 1.0), sig, (stretched >= 0.0) & (stretched <= 1.0)


class _Adam:
    """torch.optim.Adam's update of one parameter array, without weight decay."""

    def __init__(self, shape: tuple[int, ...]):
        self.m: np.ndarray = np.zeros(shape, np.float32)
        self.v: np.ndarray = np.zeros(shape, np.float32)
        self.t = 0

    def step(self, param: np.ndarray, grad: np.ndarray, lr: float) -> np.ndarray:
        b1, b2, eps = ADAM
        self.t += 1
        self.m = b1 * self.m + (1 - b1) * grad
        self.v = b2 * self.v + (1 - b2) * grad * grad
        denom = np.sqrt(self.v) / math.sqrt(1 - b2 ** self.t) + eps
        return (param - (lr / (1 - b1 ** self.t)) * self.m / denom).astype(np.float32)


def _gradient(v: np.ndarray, floor: np.ndarray, s: np.ndarray, lo: int, hi: int, bias: np.ndarray, x: np.ndarray,
              target: np.ndarray, groups: int, beta: float | None) -> np.ndarray:
    """d loss / d V on the columns X against TARGET: the reconstruction error of the soft-rounded
    weights, plus, with BETA, the regulariser pushing every h(V) to 0 or 1."""
    h, sig, inside = _soft(v)
    pre = _grouped(floor + h, groups)
    sg = _grouped(s, groups)
    y = _output(np.clip(pre, lo, hi) * sg, bias, x, groups)
    dy = (2.0 / x.shape[1]) * (y - target)  # [M, B]
    xg = x.reshape(groups, x.shape[0] // groups, -1)
    dsoft = np.matmul(dy.reshape(groups, -1, x.shape[1]), xg.transpose(0, 2, 1))  # [g, M/g, K/g]
    dh = (dsoft * sg * ((pre >= lo) & (pre <= hi))).reshape(v.shape)
    if beta is not None:
        t = 2.0 * h - 1.0
        dh = dh - np.float32(REGULARIZATION * beta * 2.0) * np.abs(t) ** (beta - 1.0) * np.sign(t)
    return (dh * inside * sig * (1.0 - sig) * np.float32(ZETA - GAMMA)).astype(np.float32)


def round_conv(w: np.ndarray, scale: np.ndarray, lo: int, hi: int, bias: np.ndarray, x: np.ndarray,
               target: np.ndarray, groups: int, seconds: float, rng: np.random.Generator,
               steps: int | None = None) -> tuple[np.ndarray, float, float, int]:
    """AdaRound's solver for one conv: learn the rounding of float weights W [M, C/g, kh, kw] (scales
    SCALE per output channel, codes LO..HI) so that its output on the columns X [C*kh*kw, P] stays
    closest to TARGET [M, P], in the steps SECONDS afford (or exactly STEPS), with Adam on the
    rectified sigmoid h(V) and the annealed regulariser. Returns (codes, error with nearest
    rounding, error with the learnt one, steps taken); nearest rounding where it does no worse."""
    # X as given where it is float32 already (a caller holding rows passes their transposed view: no copy)
    w, x, target = w.astype(np.float32), np.asarray(x, np.float32), target.astype(np.float32)
    bias = bias.astype(np.float32)
    s = np.broadcast_to(scale.astype(np.float32).reshape(-1, *[1] * (w.ndim - 1)), w.shape)
    floor = np.floor(w / s)
    nearest = np.clip(np.round(w / s), lo, hi)
    rest = np.clip(w / s - floor, 1e-4, 1 - 1e-4)
    v = (-np.log(np.float32(ZETA - GAMMA) / (rest - np.float32(GAMMA)) - 1)).astype(np.float32)
    adam = _Adam(v.shape)
    # a step's batch gathered as rows of [P, K] and [P, M], not as strided columns of [K, P]: on a conv with
    # many input rows K the column gather cost more than the step's products
    x_rows, target_rows = np.ascontiguousarray(x.T), np.ascontiguousarray(target.T)
    nearest_error = _error(_grouped(nearest * s, groups), bias, x_rows, target_rows, groups)
    fixed = steps is not None
    start, planned, taken = time.perf_counter(), steps or MAX_STEPS, 0
    while taken < planned:
        take = rng.integers(0, x.shape[1], min(BATCH, x.shape[1]))
        progress = taken / planned
        beta = None if progress < WARM_START else \
            BETA[1] + (BETA[0] - BETA[1]) * (1 - (progress - WARM_START) / (1 - WARM_START))
        grad = _gradient(v, floor, s, lo, hi, bias, x_rows[take].T, target_rows[take].T, groups, beta)
        v = adam.step(v, grad, LEARNING_RATE)
        taken += 1
        if taken == 5 and not fixed:  # plan the steps this conv's share of the budget affords
            per_step = (time.perf_counter() - start) / taken
            planned = int(min(MAX_STEPS, max(MIN_STEPS, seconds / per_step)))
    codes = np.clip(floor + (_soft(v)[0] >= 0.5), lo, hi)
    learnt_error = _error(_grouped(codes * s, groups), bias, x_rows, target_rows, groups)
    if learnt_error >= nearest_error:
        return nearest, nearest_error, nearest_error, taken
    return codes, nearest_error, learnt_error, taken
