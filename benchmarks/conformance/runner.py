"""One conformance run. Per model: its file fetched and given its input shape; calibration and test
inputs made and preprocessed as its package does; each quantizer run once on the calibration tensors
(timed, its peak memory sampled); each engine's file run on the test tensors, its decisions scored
against fp32's (and against the truth where the inputs know it) and its outputs' SQNR measured; then
every file of the model timed in one process, in alternating blocks. A step that fails is recorded
with its one-line reason and the run goes on."""

from __future__ import annotations

import math
import statistics
import tempfile
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from _common import interleaved_times

from edgepick.quant.fidelity import OutputFidelity, Task, TaskKind

from .engines import BASELINES, ONNXRUNTIME, Engine, Job, Quantized
from .fetch import entry_files
from .spec import Assets, Entry


@dataclass(frozen=True)
class Settings:
    """What a run does to each model: which engines, where fetched files are kept, how many inputs and runs."""

    engines: tuple[Engine, ...]
    cache: Path
    calib: int = 32  # calibration inputs, seed 0
    test: int = 16  # test inputs, seed 1
    runs: int = 20  # timed calls per engine
    threads: int = 2
    repeats: int = 1  # timings of every engine, one after another; the report gives their median and range


@dataclass(frozen=True)
class EngineResult:
    """One engine on one model; failure says why it has no figures."""

    engine: str
    runtime: str
    metric: float | None = None  # the task metric against fp32 on onnxruntime
    also: dict[str, float] = field(default_factory=dict)  # the entry's other metrics, by name
    truth: float | None = None  # the task metric against the inputs' own truth, where they have one
    sqnr_db: dict[str, float | None] = field(default_factory=dict)  # per output against fp32; None: exact
    p50_ms: float | None = None
    speedup: float | None = None  # fp32's p50 on the same runtime over this engine's (median over the repeats)
    speedup_range: tuple[float, float] | None = None  # the lowest and highest speed-up over the repeats (2 or more)
    size_mb: float | None = None
    quantize_s: float | None = None  # wall time of the quantizer call
    calib_s: float | None = None  # the quantizer's own calibration time, where it reports one
    stage_s: dict[str, float] = field(default_factory=dict)  # edgepick's seconds per stage of its recipe
    peak_mb: float | None = None  # the process's resident memory during the call, above its start
    note: str = ""
    failure: str | None = None
    minimum: float | None = None  # the pinned reference's value less its tolerance
    regressed: bool = False


@dataclass(frozen=True)
class ModelResult:
    """One model's run: what it is, every engine's result; failure when the model itself could not run."""

    name: str
    family: str
    origin: str
    licence: str
    input_shape: tuple[int, ...]
    layout: str
    metric: str
    engines: tuple[EngineResult, ...] = ()
    outputs: tuple[str, ...] = ()
    failure: str | None = None
    notes: str = ""
    fp32_jittered: float | None = None  # fp32's task metric on the test inputs moved by one grey level (grey_jitter)

    @property
    def regressions(self) -> list[EngineResult]:
        return [e for e in self.engines if e.regressed]


def one_line(exc: BaseException) -> str:
    """An exception as one short line: its type and the first line of its message, or where it was
    raised when it has no message (a bare assert in a library)."""
    text = next((line.strip() for line in str(exc).splitlines() if line.strip()), "")
    if not text and exc.__traceback__ is not None:
        frame = traceback.extract_tb(exc.__traceback__)[-1]
        text = f"raised in {Path(frame.filename).name}:{frame.lineno} ({frame.name})"
    return f"{type(exc).__name__}: {text}"[:300] if text else type(exc).__name__


class PeakRss:
    """The process's resident memory sampled every 20 ms while the block runs: peak_mb is its highest
    value above the value at the start (None where /proc is not there)."""

    def __init__(self) -> None:
        self.peak_mb: float | None = None
        self._stop = threading.Event()

    @staticmethod
    def rss_mb() -> float | None:
        try:
            import os

            return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6
        except (OSError, ValueError, IndexError):
            return None

    def __enter__(self) -> PeakRss:
        self._start = self.rss_mb()
        self._high = self._start
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def _sample(self) -> None:
        while not self._stop.wait(0.02):
            now = self.rss_mb()
            if now is not None and self._high is not None:
                self._high = max(self._high, now)

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()
        if self._start is not None and self._high is not None:
            self.peak_mb = round(max(self._high, self.rss_mb() or 0.0) - self._start, 1)


def prepare_fp32(entry: Entry, path: Path, out: Path) -> tuple[dict[str, str], list[str]]:
    """ENTRY's model as every engine gets it, written to OUT: what its package does to the graph, its
    input shape fixed, and each output's declared shape replaced by the one the model gives for that
    input (some files declare wrong ones). Returns the file's metadata_props and its output names."""
    import onnx

    from edgepick.export.onnx_io import fix_input_shape
    from edgepick.runtime.session import plain_session

    model = onnx.load(str(path))
    metadata = {p.key: p.value for p in model.metadata_props}
    if entry.prepare is not None:
        model = entry.prepare(model)
    fix_input_shape(model, entry.input_shape)
    onnx.save(model, str(out))
    session = plain_session(out, 1)
    given = session.run(None, {session.get_inputs()[0].name: np.zeros(entry.input_shape, np.float32)})
    for output, value in zip(model.graph.output, given):
        shape = output.type.tensor_type.shape
        del shape.dim[:]
        for n in value.shape:
            shape.dim.add().dim_value = n
    onnx.save(model, str(out))
    return metadata, [o.name for o in model.graph.output]


def tensors(entry: Entry, images: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The input tensors of IMAGES by ENTRY's preprocessing, each checked against its input shape."""
    out = []
    for img in images:
        x = np.ascontiguousarray(entry.preprocess(img), dtype=np.float32)
        if tuple(x.shape) != tuple(entry.input_shape):
            raise ValueError(f"preprocessing made {list(x.shape)}, the entry says {list(entry.input_shape)}")
        out.append(x)
    return out


def run_model(entry: Entry, settings: Settings, log: Callable[[str], None] = print) -> ModelResult:
    """ENTRY through every engine of SETTINGS."""
    base = ModelResult(entry.name, entry.family, entry.origin, entry.licence, tuple(entry.input_shape), entry.layout,
                       entry.metric.name, notes=entry.notes)

    def failed(reason: str) -> ModelResult:  # every engine failed with the model: a pinned one has regressed
        return replace(base, failure=reason, engines=tuple(
            _judge(entry, EngineResult(e.name, e.runtime, failure=f"model: {reason}")) for e in settings.engines))

    with tempfile.TemporaryDirectory(prefix=f"conformance-{entry.name}-") as tmp:
        work = Path(tmp)
        try:
            model_path, files = entry_files(entry, settings.cache)
            metadata, outputs = prepare_fp32(entry, model_path, work / "fp32.onnx")
            assets = Assets(files, metadata)
            calib_samples = entry.samples(settings.calib, 0, assets)
            test_samples = entry.samples(settings.test, 1, assets)
            calib, test = tensors(entry, [s.image for s in calib_samples]), tensors(entry, [s.image for s in test_samples])
            decide = entry.decoder(assets)
        except Exception as exc:  # noqa: BLE001 - any step of a foreign model may fail; the run goes on
            return failed(one_line(exc))
        quantized = _quantize(entry, settings, work, calib, log, own_judge(entry, decide))
        try:
            fp32 = next(e for e in settings.engines if e.name == BASELINES[ONNXRUNTIME])
            fp32_run = fp32.load(_file(quantized[fp32.quantizer.name]), settings.threads, outputs)
            reference = [fp32_run(x) for x in test]
            ref_decisions = [decide(o) for o in reference]
            jittered = tensors(entry, [grey_jitter(s.image, k) for k, s in enumerate(test_samples)])
            fp32_jittered = round(entry.metric.score(ref_decisions, [decide(fp32_run(x)) for x in jittered]), 5)
        except Exception as exc:  # noqa: BLE001
            return failed(f"fp32: {one_line(exc)}")
        truths = [s.truth for s in test_samples]
        results, runners = {}, {}
        for engine in settings.engines:
            made, seconds, peak = quantized[engine.quantizer.name]
            if isinstance(made, str):
                results[engine.name] = EngineResult(engine.name, engine.runtime, quantize_s=round(seconds, 2),
                                                    peak_mb=peak, failure=f"quantize: {made}")
            else:
                try:
                    run = engine.load(made, settings.threads, outputs)
                    results[engine.name] = _score(entry, engine, run, test, reference, ref_decisions, truths, outputs,
                                                  decide, made)
                    runners[engine.name] = run
                except Exception as exc:  # noqa: BLE001
                    results[engine.name] = EngineResult(engine.name, engine.runtime,
                                                        failure=f"run: {one_line(exc)}".replace(f"{work}/", ""))
                if engine.quantizer.name != "fp32":
                    results[engine.name] = replace(results[engine.name], quantize_s=round(seconds, 2), peak_mb=peak)
            log(f"{entry.name}: {engine.name} {results[engine.name].failure or 'scored'}")
        _time(results, runners, test, settings, log, entry.name)
    return replace(base, outputs=tuple(outputs), fp32_jittered=fp32_jittered,
                   engines=tuple(_judge(entry, results[e.name]) for e in settings.engines))


def grey_jitter(image: np.ndarray, seed: int) -> np.ndarray:
    """IMAGE (8-bit) with every value moved by -1, 0 or +1 grey level at random: a change of the
    size a camera's own 8-bit rounding makes. fp32's decisions on such inputs against its decisions
    on the inputs as made are the floor of a task metric: below it, a difference is the decision's
    own instability (a box or a character on its threshold), not the engine's."""
    if image.dtype != np.uint8:
        raise ValueError(f"a sample image is {image.dtype}, an 8-bit image was expected")
    step = np.random.default_rng([2, seed]).integers(-1, 2, image.shape)
    return np.clip(image.astype(np.int16) + step, 0, 255).astype(np.uint8)


Made = tuple[Quantized | str, float, float | None]  # the file or why there is none; seconds; peak MB


def _file(made: Made) -> Quantized:
    """The file of MADE, or its failure raised."""
    if isinstance(made[0], str):
        raise RuntimeError(made[0])
    return made[0]


def own_judge(entry: Entry, decide: Callable[[list[np.ndarray]], Any]) -> Callable[..., float]:
    """ENTRY's own judge of int8 outputs against fp32's, per check tensor a list of outputs in the graph's
    order: the package's decisions (DECIDE) scored by the entry's metric, as the suite scores the test inputs."""
    def judge(reference: list[list[np.ndarray]], outputs: list[list[np.ndarray]]) -> float:
        return float(entry.metric.score([decide(r) for r in reference], [decide(o) for o in outputs]))
    return judge


def _quantize(entry: Entry, settings: Settings, work: Path, calib: list[np.ndarray],
              log: Callable[[str], None], judge: Callable[..., float] | None = None) -> dict[str, Made]:
    """Each distinct quantizer of the engines once, on CALIB (edgepick's budget given the model's own JUDGE
    where an engine asks for it): its file (or the one-line reason it failed), the call's wall time and its
    peak memory."""
    done: dict[str, Made] = {}
    for engine in settings.engines:
        q = engine.quantizer
        if q.name in done:
            continue
        folder = work / q.name
        folder.mkdir(exist_ok=True)
        job = Job(work / "fp32.onnx", calib, folder, tuple(entry.input_shape), entry.task, judge)
        t0 = time.perf_counter()
        result: Quantized | str
        with PeakRss() as peak:
            try:
                result = q.run(job)
            except Exception as exc:  # noqa: BLE001 - a quantizer that cannot take the model is a finding
                result = one_line(exc).replace(f"{work}/", "")  # the temporary folder says nothing
        done[q.name] = (result, time.perf_counter() - t0, peak.peak_mb)
        log(f"{entry.name}: quantizer {q.name} {'failed: ' + result if isinstance(result, str) else 'done'} "
            f"in {done[q.name][1]:.1f} s")
    return done


def _score(entry: Entry, engine: Engine, run, test: list[np.ndarray], reference: list[list[np.ndarray]],
           ref_decisions: list, truths: list, outputs: list[str], decide, made: Quantized) -> EngineResult:
    """ENGINE's decisions on TEST against fp32's, its other metrics, its truth metric and SQNR per output."""
    fidelity = {name: OutputFidelity(Task(TaskKind.RAW)) for name in outputs}
    decisions = []
    for x, ref in zip(test, reference):
        out = run(x)
        decisions.append(decide(out))
        for name, a, b in zip(outputs, ref, out):
            fidelity[name].add(a, np.asarray(b).reshape(a.shape))
    sqnr = {n: (round(f.sqnr_db, 2) if math.isfinite(f.sqnr_db) else None) for n, f in fidelity.items()}
    return EngineResult(
        engine.name, engine.runtime, metric=round(entry.metric.score(ref_decisions, decisions), 5),
        also={m.name: round(m.score(ref_decisions, decisions), 5) for m in entry.also},
        truth=round(entry.metric.score(truths, decisions), 5) if all(t is not None for t in truths) else None,
        sqnr_db=sqnr, size_mb=made.size_mb, calib_s=made.calib_s, stage_s=made.stage_s, note=made.note)


def _time(results: dict[str, EngineResult], runners: dict, test: list[np.ndarray], settings: Settings,
          log: Callable[[str], None], name: str) -> None:
    """p50 of every engine that ran, timed in one process in alternating blocks, and its speed-up
    against fp32 on the same runtime (in RESULTS, in place). With settings.repeats, the timing is
    done that many times: the median p50 and speed-up (each speed-up a ratio within one timing),
    and the speed-ups' range."""
    if not runners or settings.runs < 1:
        return
    log(f"{name}: timing {len(runners)} engines, {settings.runs} runs each" +
        (f", {settings.repeats} times" if settings.repeats > 1 else ""))
    names = list(runners)
    p50s: dict[str, list[float]] = {n: [] for n in names}
    speedups: dict[str, list[float]] = {n: [] for n in names}
    for _ in range(settings.repeats):
        times = interleaved_times([lambda i, r=runners[n]: r(test[i % len(test)]) for n in names], settings.runs)
        p50 = {n: statistics.median(t) for n, t in zip(names, times)}
        for n in names:
            p50s[n].append(p50[n])
            base = p50.get(BASELINES[results[n].runtime])
            if base:
                speedups[n].append(base / p50[n])
    for n in names:
        spread = (round(min(speedups[n]), 3), round(max(speedups[n]), 3)) if len(speedups[n]) > 1 else None
        results[n] = replace(results[n], p50_ms=round(statistics.median(p50s[n]), 2), speedup_range=spread,
                             speedup=round(statistics.median(speedups[n]), 3) if speedups[n] else None)


def _judge(entry: Entry, result: EngineResult) -> EngineResult:
    """RESULT against ENTRY's pinned reference for its engine: below the minimum, or failed, regressed."""
    ref = entry.reference(result.engine)
    if ref is None:
        return result
    regressed = result.metric is None or result.metric < ref.minimum
    return replace(result, minimum=ref.minimum, regressed=regressed)
