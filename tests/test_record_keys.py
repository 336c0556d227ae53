"""The stages after export hand each other typed records, not dicts: robot/, sim/ and bench/ read a
grasp's fields as attributes (runtime/grasp_record.py's Grasp), never by key. Read from the source
as text, so that a key read anywhere in a module counts."""

from __future__ import annotations

import re

import pytest

from tests.conftest import REPO

GRASP_NAMES = ("grasp", "grasps", "record", "records", "rec", "chosen")  # what the loop calls a Grasp
KEY_READ = re.compile(r"\b(?:" + "|".join(GRASP_NAMES) + r")(?:\[\s*['\"]|\.get\(\s*['\"])")


def key_reads(text: str) -> list[str]:
    """The lines of TEXT that read a grasp's field by key: record["pose_robot"], chosen.get("class")."""
    return [line.strip() for line in text.splitlines() if KEY_READ.search(line)]


@pytest.mark.parametrize("package", ["robot", "sim", "bench"])
def test_no_grasp_field_is_read_by_key(package):
    wrong = [f"{path.relative_to(REPO)}: {line}" for path in sorted((REPO / "edgepick" / package).rglob("*.py"))
             for line in key_reads(path.read_text())]
    assert wrong == []


def test_the_guard_sees_a_key_read():
    assert key_reads('x = record["pose_robot"]\ny = chosen.get("class")\nz = grasp.pose_robot') == \
        ['x = record["pose_robot"]', 'y = chosen.get("class")']
    assert key_reads('recorded = rc.result.get("target")\nt["class"]') == []
