"""`edgepick data synth`: write a synthetic RGB-D data set in the native layout (docs/contracts.md#data-set-layout).

Each scene has its own seed derived from (seed, split, index), so the files do not depend
on the number of workers. Output goes to a temporary folder beside OUT and is renamed into
place at the end: an interrupted run leaves nothing half-written.
"""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import multiprocessing.pool
import multiprocessing.resource_tracker
import os
import shutil
import signal
import threading
import time
from collections.abc import Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from edgepick.data.config import Split
from edgepick.data.native import atomic_folder
from edgepick.data.render import CLASSES, LIGHTINGS, SceneRenderer
from edgepick.errors import ParameterError
from edgepick.geometry import Intrinsics
from edgepick.progress import progress as progress_bar

GENERATOR_VERSION = 2  # 2: objects rest where they would stay (data/stacking.py)
BYTES_PER_PIXEL = 2.2  # a scene's RGB, depth and mask PNGs per pixel: 1.9 at 640x480, 2.1 at 320x240, rounded up
MAX_SCENES = 1_000_000  # the thesis's set is 5100; beyond this the job list alone fills the memory


@dataclass(frozen=True)
class SynthConfig:
    """What `data synth` renders, checked on creation."""

    scenes: int = 510
    width: int = 640
    height: int = 480
    seed: int = 0
    splits: tuple[int, int, int] | None = None  # explicit train/val/test counts
    workers: int = 0  # 0 = one per core; never more than the scenes or the cores (worker_count)

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ParameterError("{seed}: must be 0 or positive", seed=self.seed)
        if self.workers < 0:
            raise ParameterError("{workers}: must be 0 (one per core) or positive", workers=self.workers)
        if self.splits is not None:
            object.__setattr__(self, "splits", tuple(self.splits))
            if len(self.splits) != 3 or min(self.splits) < 1:
                raise ParameterError("{splits}: give three scene counts (train, val, test), each at least 1",
                                     splits=self.splits)
        elif self.scenes < 3:
            raise ParameterError("{scenes}: must be at least 3 (one scene per split)", scenes=self.scenes)

    def split_counts(self) -> tuple[int, int, int]:
        """Scene counts per split; by default the thesis's 4000/1000/100 ratio."""
        if self.splits is not None:
            return tuple(int(s) for s in self.splits)  # type: ignore[return-value]
        n = self.scenes
        test = max(1, round(n / 51))
        val = max(1, round(n * 10 / 51))
        return n - val - test, val, test


_RENDERER: SceneRenderer | None = None
# The SUB filter with Huffman-only coding writes a noisy RGB frame faster than zlib level 1 at a
# similar size; label masks compress best as RLE (benchmarks/synth_speed.py times both).
_PNG_FAST = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB,
             cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
_PNG_RLE = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]


def _keep_freed_memory() -> bool:
    """glibc only: serve the renderer's frame-sized temporaries from the heap and keep freed
    memory in the process. By default each one is a fresh mmap that the kernel zero-fills page
    by page, a large share of a scene's time (benchmarks/synth_speed.py)."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        m_trim_threshold, m_mmap_threshold = -1, -3
        return bool(libc.mallopt(m_mmap_threshold, 64 << 20)) and bool(libc.mallopt(m_trim_threshold, 256 << 20))
    except (OSError, AttributeError):  # not glibc: keep the allocator's defaults
        return False


def _end_with_parent() -> None:
    """Linux: the kernel sends this process SIGTERM when the process that started it dies, so a
    worker never outlives a killed `data synth` (prctl PR_SET_PDEATHSIG)."""
    import ctypes
    import ctypes.util

    try:
        ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6").prctl(1, int(signal.SIGTERM))
    except (OSError, AttributeError):
        pass


def _init_worker() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group: the parent stops the workers
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # held since spawn (_start_pool); now ignored
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    _end_with_parent()
    cv2.setNumThreads(1)  # one process per core: no nested thread pools
    _keep_freed_memory()


@contextlib.contextmanager
def _signals_deferred(signums: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)):
    """Record SIGNUMS instead of acting on them for the body, then raise the first through the
    handler it had: an interrupt never lands half-way through what the body starts."""
    if threading.current_thread() is not threading.main_thread():  # only the main thread handles signals
        yield
        return
    caught: list[int] = []
    previous = {sig: signal.signal(sig, lambda signum, frame: caught.append(signum)) for sig in signums}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
        if caught:
            signal.raise_signal(caught[0])


def _start_pool(workers: int) -> multiprocessing.pool.Pool:
    """Start WORKERS spawned processes so that a Ctrl-C or SIGTERM at any moment stops them quietly.

    A spawned worker spends seconds importing before `_init_worker` can ignore SIGINT, so it starts
    with SIGINT blocked (inherited through exec; dropped once ignored). The parent holds its own
    signals until the pool stands: interrupted half-way, a worker would wait on a pipe never written.
    The resource tracker starts first, as starting it unblocks SIGINT in this thread
    (multiprocessing/resource_tracker.py, bpo-33613).
    """
    multiprocessing.resource_tracker.ensure_running()
    pool = None
    try:
        with _signals_deferred():
            held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
            try:
                # spawn, not fork: a fork after OpenCV's thread pool has run in this process deadlocks
                pool = multiprocessing.get_context("spawn").Pool(workers, initializer=_init_worker)
            finally:
                signal.pthread_sigmask(signal.SIG_SETMASK, held)
    except BaseException:
        if pool is not None:
            pool.terminate()
        raise
    return pool


def _render_one(job: tuple[str, int, int, int, int, int, str]) -> tuple[str, str, list, dict]:
    global _RENDERER
    split, index, seed, width, height, split_idx, root = job
    intr = Intrinsics.d415(width, height)
    if _RENDERER is None or _RENDERER.intr != intr:
        _RENDERER = SceneRenderer(intr)
    rng = np.random.default_rng([seed, split_idx, index])
    scene = _RENDERER.render(rng)
    sid = f"{index:06d}"
    base = Path(root) / split
    ok = cv2.imwrite(str(base / "rgb" / f"{sid}.png"), scene.rgb[..., ::-1], _PNG_FAST)
    ok &= cv2.imwrite(str(base / "depth" / f"{sid}.png"), scene.depth, _PNG_FAST)
    ok &= cv2.imwrite(str(base / "mask" / f"{sid}.png"), scene.mask, _PNG_RLE)
    if not ok:
        raise OSError(f"could not write scene {split}/{sid}")
    return split, sid, scene.grasps, scene.info


def check_room(config: SynthConfig, out: str | Path) -> None:
    """Refuse a data set too large to write: more scenes than MAX_SCENES, or more bytes than the
    disk under OUT has free (at BYTES_PER_PIXEL), before anything is rendered."""
    scenes = sum(config.split_counts())
    need = scenes * config.width * config.height * BYTES_PER_PIXEL
    name = "splits" if config.splits else "scenes"  # the parameter that asked for them
    given = {name: getattr(config, name)}
    if scenes > MAX_SCENES:
        raise ParameterError(f"{{{name}}}: {scenes} scenes is beyond the {MAX_SCENES} edgepick makes at once (they "
                             f"would take about {need / 1e9:.3g} GB)", **given)
    parent = Path(out).absolute()
    while not parent.exists():
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    if need > free:
        raise ParameterError(f"{{{name}}}: {scenes} scenes at {config.width}x{config.height} take about "
                             f"{need / 1e9:.3g} GB, but {parent} has {free / 1e9:.3g} GB free", **given)


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity: a container's or taskset's share)."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):  # not on Linux
        return os.cpu_count() or 1


def worker_count(asked: int, jobs: int) -> int:
    """The processes that render JOBS scenes: ASKED (0: one per core), never more than the scenes nor
    the cores. One more process than cores renders nothing faster, and each costs seconds to start
    and its own memory: --workers 1000 on 3 scenes would spend minutes starting processes that
    have nothing to do."""
    return max(1, min(asked or usable_cores(), jobs, usable_cores()))


def synthesize(out: str | Path, config: SynthConfig, progress: bool = True) -> dict:
    """Generate the data set at OUT; returns a summary with scenes/s."""
    out = Path(out)
    counts = config.split_counts()
    check_room(config, out)
    with atomic_folder(out) as tmp:
        for split in Split:
            for sub in ("rgb", "depth", "mask"):
                (tmp / split / sub).mkdir(parents=True)
        jobs = [(split, i, config.seed, config.width, config.height, si, str(tmp))
                for si, (split, cnt) in enumerate(zip(Split, counts)) for i in range(cnt)]
        workers = worker_count(config.workers, len(jobs))
        grasps: dict[str, dict] = {s: {} for s in Split}
        scenes: dict[str, dict] = {s: {} for s in Split}
        t0 = time.perf_counter()
        bar = progress_bar(total=len(jobs), desc="synth", unit="scene", enabled=progress)
        results: Iterable[tuple[str, str, list, dict]]
        if workers <= 1:
            results = map(_render_one, jobs)
            pool = None
        else:
            pool = _start_pool(workers)
            results = pool.imap(_render_one, jobs, chunksize=4)
        try:
            for name, sid, g, info in results:
                grasps[name][sid] = g
                scenes[name][sid] = info
                bar.update()
        except BaseException:
            if pool is not None:  # an error, Ctrl-C or SIGTERM: stop the workers now, not after their queue
                pool.terminate()
            raise
        finally:
            bar.close()
            if pool is not None:
                pool.close()
                pool.join()
        elapsed = time.perf_counter() - t0
        intr = Intrinsics.d415(config.width, config.height)
        for split in Split:
            (tmp / split / "grasps.json").write_text(json.dumps(grasps[split], indent=1))
            (tmp / split / "scenes.json").write_text(json.dumps(scenes[split], indent=1))
        meta: dict[str, Any] = {
            "classes": list(CLASSES),
            "intrinsics": intr.to_dict(),
            "depth_scale": intr.depth_scale,
            "generator": {"name": "edgepick.synth", "version": GENERATOR_VERSION, **asdict(config),
                          "split_counts": dict(zip(Split, counts)), "lightings": list(LIGHTINGS)},
        }
        meta["generator"].pop("workers")
        (tmp / "meta.json").write_text(json.dumps(meta, indent=1))
    return {"out": str(out), "scenes": len(jobs), "seconds": round(elapsed, 2),
            "scenes_per_s": round(len(jobs) / elapsed, 2), "workers": workers,
            "splits": dict(zip(Split, counts))}
