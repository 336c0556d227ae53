"""Progress on long work, on a terminal or in a log.

On a terminal: a tqdm bar on stderr. When stderr is a pipe or a file (CI, `2> log`, `| tee`),
tqdm would print nothing (or carriage returns); instead a plain line every `every_s` seconds,
"epoch 3/12: 40/120 batch, 12 s", so a long command never looks hung in a log. The interval is
10 s unless the environment sets EDGEPICK_PROGRESS_S (seconds, e.g. 60 for a quieter CI log).
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Iterable, Iterator, Mapping, Sized
from contextlib import contextmanager

from tqdm import tqdm

from edgepick.errors import ConfigError

EVERY_S = 10.0  # a log line's default interval
EVERY_S_VARIABLE = "EDGEPICK_PROGRESS_S"


class _LogProgress:
    """tqdm's small interface (iterate, update, set_postfix, close) as timed log lines."""

    def __init__(self, iterable: Iterable | None, desc: str, total: int | None, unit: str, every_s: float):
        self.iterable, self.desc, self.unit, self.every_s = iterable, desc, unit, every_s
        self.total = total if total is not None else (len(iterable) if isinstance(iterable, Sized) else None)
        self.n, self.postfix = 0, ""
        self.t0 = self.last = time.monotonic()

    def __iter__(self) -> Iterator:
        if self.iterable is None:
            raise TypeError(f"{self.desc}: a progress made without an iterable is updated, not iterated")
        for item in self.iterable:
            yield item
            self.update()

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self.last >= self.every_s:
            self.last = now
            of = f"/{self.total}" if self.total else ""
            post = f", {self.postfix}" if self.postfix else ""
            print(f"{self.desc}: {self.n}{of} {self.unit}, {now - self.t0:.0f} s{post}", file=sys.stderr, flush=True)

    def set_postfix(self, **values) -> None:
        self.postfix = ", ".join(f"{k} {v}" for k, v in values.items())

    def close(self) -> None:
        pass


def log_interval_s() -> float:
    """Seconds between two progress lines in a log: EDGEPICK_PROGRESS_S, else EVERY_S."""
    text = os.environ.get(EVERY_S_VARIABLE)
    if text is None:
        return EVERY_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise ConfigError(f"{EVERY_S_VARIABLE}={text!r}: must be a number of seconds, 0 or more")
    return value


def progress(iterable: Iterable | None = None, desc: str = "", total: int | None = None, unit: str = "it",
             enabled: bool = True, every_s: float | None = None):
    """A progress bar over ITERABLE (or one to update() by hand): tqdm on a terminal, a line
    every EVERY_S seconds otherwise (None: log_interval_s()), nothing when not ENABLED."""
    if not enabled:
        return tqdm(iterable, total=total, disable=True)
    if sys.stderr.isatty():
        return tqdm(iterable, desc=desc, total=total, unit=unit, leave=False)
    return _LogProgress(iterable, desc, total, unit, log_interval_s() if every_s is None else every_s)


def stage(message: str, enabled: bool = True) -> None:
    """A stage of a long pass on stderr: steps without a bar still say what they are doing."""
    if enabled:
        print(message, file=sys.stderr, flush=True)


class StageClock:
    """Wall seconds per named stage of a long job, summed where a stage comes back: where the time
    of a quantize went (the result's `stage_s`), so a user sees what each part of the recipe costs."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start

    def add(self, seconds: Mapping[str, float]) -> None:
        """SECONDS per stage (another clock's, or a result's stage_s) added to this clock's."""
        for name, s in seconds.items():
            self.seconds[name] = self.seconds.get(name, 0.0) + s

    def to_dict(self) -> dict[str, float]:
        """Each stage's seconds, to the millisecond, in the order they first ran."""
        return {name: round(s, 3) for name, s in self.seconds.items()}
