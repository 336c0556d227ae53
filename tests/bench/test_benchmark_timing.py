"""benchmarks/_common.interleaved_times: alternating blocks, one untimed call before each block."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from _common import interleaved_times  # noqa: E402


def test_models_alternate_in_blocks_after_an_untimed_call():
    log: list[str] = []
    calls = [lambda i, name=name: log.append(name) for name in "ab"]
    times = interleaved_times(calls, runs=7, block=3)
    assert [len(t) for t in times] == [7, 7]
    assert all(ms >= 0 for t in times for ms in t)
    # per round: 1 untimed + up to 3 timed calls of a, then of b
    assert "".join(log) == "aaaa" "bbbb" "aaaa" "bbbb" "aa" "bb"
