"""The stages after export hand each other typed records, not dicts: robot/, sim/ and bench/ read a
grasp's fields (runtime/grasp_record.py's Grasp) and a cycle's result and verdicts (robot/cycle.py's
CycleResult, robot/verdict.py's Verdict) as attributes, never by key. Read from the source as text,
so that a key read anywhere in a module counts."""

from __future__ import annotations

import re

import pytest

from tests.conftest import REPO

RECORD_NAMES = ("grasp", "grasps", "record", "records", "rec", "chosen",  # what the loop calls a Grasp
                "result", "verdict", "physics")  # a CycleResult, a Verdict
KEY_READ = re.compile(r"(?<![.\w])(?:" + "|".join(RECORD_NAMES) + r")(?:\[\s*['\"]|\.get\(\s*['\"])")


def key_reads(text: str) -> list[str]:
    """The lines of TEXT that read a record's field by key: record["pose_robot"], result.get("verdict")."""
    return [line.strip() for line in text.splitlines() if KEY_READ.search(line)]


@pytest.mark.parametrize("package", ["robot", "sim", "bench"])
def test_no_record_field_is_read_by_key(package):
    wrong = [f"{path.relative_to(REPO)}: {line}" for path in sorted((REPO / "edgepick" / package).rglob("*.py"))
             for line in key_reads(path.read_text())]
    assert wrong == []


def test_the_guard_sees_a_key_read():
    assert key_reads('x = record["pose_robot"]\ny = chosen.get("class")\nz = grasp.pose_robot\nok = result["verdict"]') == \
        ['x = record["pose_robot"]', 'y = chosen.get("class")', 'ok = result["verdict"]']
    assert key_reads('recorded = rc.result.get("target")\nt["class"]\nresults[0]') == []  # a recording's JSON, truth
