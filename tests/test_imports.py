"""The package's floors (docs/architecture.md): no import circle between modules, and no arrow from
a lower stage to a higher one where the layout forbids it. Read from the source with ast, so
imports inside functions count too."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.conftest import REPO

GROUND = {"errors", "files", "progress", "geometry", "frames", "metrics", "schema", "lazy", "onnx_graph"}


def _imports() -> dict[str, set[str]]:
    """module -> the edgepick modules it imports, at the top level ('top') or anywhere ('all')."""
    graph: dict[str, dict[str, set[str]]] = {}
    for path in (REPO / "edgepick").rglob("*.py"):
        parts = path.relative_to(REPO).with_suffix("").parts
        module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        tree = ast.parse(path.read_text())
        top, every = set(), set()
        for node in ast.walk(tree):
            names = [node.module] if isinstance(node, ast.ImportFrom) and node.module else \
                [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names = [n for n in names if n.startswith("edgepick")]
            every.update(names)
            if node in tree.body:
                top.update(names)
        graph[module] = {"top": top, "all": every}
    return graph


def _stage(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def test_no_module_level_import_circle():
    graph = {m: {t for t in v["top"]} for m, v in _imports().items()}
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for n in graph.get(m, ()):
            n = n if n in graph else n.rsplit(".", 1)[0]
            if state.get(n) == 1:
                raise AssertionError("import circle: " + " -> ".join(path[path.index(n):] + [n]))
            if n in graph and not state.get(n):
                visit(n, path + [n])
        state[m] = 2

    for m in graph:
        if not state.get(m):
            visit(m, [m])


def test_arrows_point_down():
    forbidden = {"data": {"runtime", "robot", "sim", "train", "quant", "export", "bench", "cli"},
                 "train": {"quant", "export", "runtime", "robot", "sim", "bench", "cli"},
                 "export": {"quant", "evaluation", "robot", "sim", "bench", "demo", "cli"},
                 "quant": {"robot", "sim", "bench", "demo", "cli"},
                 "robot": {"sim", "bench", "cli", "train", "quant", "export"},
                 "runtime": {"sim", "robot", "bench", "cli", "train", "quant", "export", "data"},
                 "models": {"train", "quant", "export", "runtime", "robot", "sim", "bench", "cli"},
                 **{g: {"data", "models", "train", "quant", "export", "runtime", "robot", "sim", "bench", "cli"}
                    for g in GROUND}}
    wrong = [f"{m} imports {n}" for m, v in _imports().items() for n in v["all"]
             if _stage(n) in forbidden.get(_stage(m), ())]
    assert wrong == []


def test_the_walk_sees_the_package():
    graph = _imports()
    assert "edgepick.cli" in graph and "edgepick.sim.robot" in graph["edgepick.cli.pick"]["all"]
    assert Path(REPO / "edgepick" / "sim" / "robot.py").is_file()


@pytest.mark.parametrize("package", ["edgepick", "edgepick.train", "edgepick.quant", "edgepick.export", "edgepick.runtime",
                                     "edgepick.models"])
def test_every_public_name_of_a_package_resolves(package):
    """The API packages load their objects on first use (a light config module must not import
    torch); every name in __all__ must still resolve, and nothing else be offered."""
    import importlib

    module = importlib.import_module(package)
    for name in module.__all__:
        assert getattr(module, name) is not None, f"{package}.{name}"
    with pytest.raises(AttributeError):
        module.no_such_name  # noqa: B018
