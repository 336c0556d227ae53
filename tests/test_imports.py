"""The package's floors (docs/architecture.md): no import circle between modules, and no arrow from
a lower stage to a higher one where the layout forbids it. Read from the source with ast, so
imports inside functions count too."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.conftest import REPO

GROUND = {"errors", "files", "progress", "geometry", "frames", "metrics", "intervals", "schema", "lazy", "onnx_graph",
          "machine"}


def _imports() -> dict[str, dict[str, set[str]]]:
    """module -> the edgepick modules it imports, at the top level ('top', under TYPE_CHECKING too:
    a type-only circle is a circle all the same) or anywhere ('all')."""
    graph: dict[str, dict[str, set[str]]] = {}
    for path in (REPO / "edgepick").rglob("*.py"):
        parts = path.relative_to(REPO).with_suffix("").parts
        module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        tree = ast.parse(path.read_text())
        top, every = set(), set()
        module_level = [*tree.body, *(n for node in tree.body if _is_type_checking(node) for n in node.body)]
        for node in ast.walk(tree):
            names = [node.module] if isinstance(node, ast.ImportFrom) and node.module else \
                [a.name for a in node.names] if isinstance(node, ast.Import) else []
            names = [n for n in names if n.startswith("edgepick")]
            every.update(names)
            if node in module_level:
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
                 "robot": {"sim", "bench", "cli", "train", "quant", "export", "data", "models", "evaluation", "demo"},
                 "runtime": {"sim", "robot", "bench", "cli", "train", "quant", "export", "data", "models", "evaluation",
                             "demo"},
                 "sim": {"train", "quant", "export", "evaluation", "bench", "demo", "cli", "models"},
                 "evaluation": {"quant", "export", "robot", "sim", "bench", "demo", "cli"},
                 "bench": {"demo", "cli"},
                 "demo": {"cli"},
                 "models": {"train", "quant", "export", "runtime", "robot", "sim", "bench", "cli"},
                 **{g: {"data", "models", "train", "quant", "export", "runtime", "robot", "sim", "bench", "cli"}
                    for g in GROUND}}
    wrong = [f"{m} imports {n}" for m, v in _imports().items() for n in v["all"]
             if _stage(n) in forbidden.get(_stage(m), ())]
    assert wrong == []


def _is_type_checking(node: ast.AST) -> bool:
    test = node.test if isinstance(node, ast.If) else None
    return isinstance(test, ast.Name) and test.id == "TYPE_CHECKING" or \
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING"


def _every_import() -> dict[str, dict[str, set[str]]]:
    """module -> every module it imports, edgepick's and others' ('all': anywhere, under TYPE_CHECKING
    too; 'run': what importing it runs: its top level less TYPE_CHECKING blocks), with a name
    imported from a package counted as that package's submodule where there is one."""
    modules = {}
    for path in (REPO / "edgepick").rglob("*.py"):
        parts = path.relative_to(REPO).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = ast.parse(path.read_text())

    def names(node: ast.AST) -> set[str]:
        if isinstance(node, ast.Import):
            return {a.name for a in node.names}
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            return {node.module} | {f"{node.module}.{a.name}" for a in node.names if f"{node.module}.{a.name}" in modules}
        return set()

    def run(body: list) -> set[str]:
        """The imports of the statements BODY runs: not those in functions or under TYPE_CHECKING."""
        found: set[str] = set()
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) or _is_type_checking(node):
                continue
            found |= names(node)
            for field in ("body", "orelse", "finalbody", "handlers"):
                found |= run(getattr(node, field, None) or [])
        return found

    return {module: {"all": {n for node in ast.walk(tree) for n in names(node)}, "run": run(tree.body)}
            for module, tree in modules.items()}


def test_the_onnx_pass_reaches_no_torch_and_no_pt2e_module():
    """What a module of edgepick.quant.onnx imports, anywhere in it (in functions, under TYPE_CHECKING),
    and what those modules import in turn, with what importing each one's packages runs: never torch,
    torchao or edgepick.quant.pt2e. The ONNX pass runs on the torch-free base install plus onnx."""
    graph = _every_import()
    for start in (m for m in graph if m.startswith("edgepick.quant.onnx")):
        seen, todo = set(), [start]
        while todo:
            module = todo.pop()
            if module in seen:
                continue
            seen.add(module)
            parts = module.split(".")
            packages = [".".join(parts[:k]) for k in range(1, len(parts))]
            todo.extend(graph[module]["all"] if module in graph else ())
            todo.extend(n for p in packages if p in graph for n in graph[p]["run"])
        wrong = sorted(m for m in seen if m.split(".")[0] in ("torch", "torchao") or m.startswith("edgepick.quant.pt2e"))
        assert wrong == [], f"{start} reaches {wrong}"


def test_the_math_both_backends_share_imports_neither():
    """quant/'s own modules (configs, record, results, ranges, fidelity, methods) stand below both
    backends: they import nothing of quant/pt2e, quant/onnx or torch."""
    graph = _every_import()
    shared = [m for m in graph if m.startswith("edgepick.quant.") and m.count(".") == 2]
    wrong = {m: sorted(n for n in graph[m]["all"] if n.startswith(("edgepick.quant.pt2e", "edgepick.quant.onnx"))
                       or n.split(".")[0] in ("torch", "torchao")) for m in shared}
    assert len(shared) >= 6 and {m: w for m, w in wrong.items() if w} == {}


def test_no_private_name_is_imported_from_another_module():
    """A name with a leading underscore stays in its module: what two modules share is public."""
    wrong = []
    for path in (REPO / "edgepick").rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("edgepick"):
                wrong += [f"{path.relative_to(REPO)}: {node.module}.{a.name}" for a in node.names
                          if a.name.startswith("_") and not a.name.startswith("__")]
    assert wrong == []


def test_the_walk_sees_the_package():
    graph = _imports()
    assert "edgepick.cli" in graph and "edgepick.sim.robot" in graph["edgepick.cli.cell"]["all"]
    assert Path(REPO / "edgepick" / "sim" / "robot.py").is_file()


@pytest.mark.parametrize("package", ["edgepick", "edgepick.train", "edgepick.quant", "edgepick.export", "edgepick.runtime",
                                     "edgepick.models", "edgepick.data", "edgepick.robot", "edgepick.sim", "edgepick.bench"])
def test_every_public_name_of_a_package_resolves(package):
    """The API packages load their objects on first use (a light config module must not import
    torch); every name in __all__ must still resolve, and nothing else be offered."""
    import importlib

    module = importlib.import_module(package)
    for name in module.__all__:
        assert getattr(module, name) is not None, f"{package}.{name}"
    with pytest.raises(AttributeError):
        module.no_such_name  # noqa: B018
