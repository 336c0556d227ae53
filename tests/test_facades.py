"""The packages' facades (edgepick/lazy.py): each public name written once, in the package's `_WHERE`
map, imported under TYPE_CHECKING from the module that map names, and loaded only when first asked
for, so that importing a facade stays cheap (no torch, MuJoCo, OpenCV or onnxruntime)."""

from __future__ import annotations

import ast
import importlib
import pkgutil
import subprocess
import sys

import pytest

from tests.conftest import REPO

FACADES = ["edgepick.data", "edgepick.models", "edgepick.runtime", "edgepick.train", "edgepick.robot", "edgepick.export",
           "edgepick.sim", "edgepick.quant", "edgepick.bench"]


def _type_checking_imports(package: str) -> dict[str, str]:
    """name -> the module the package's `if TYPE_CHECKING:` block imports it from."""
    tree = ast.parse((REPO / package.replace(".", "/") / "__init__.py").read_text())
    found: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
            for imp in node.body:
                assert isinstance(imp, ast.ImportFrom) and imp.module, ast.unparse(imp)
                for alias in imp.names:
                    assert alias.name not in found, f"{package} imports {alias.name} twice"
                    found[alias.name] = imp.module
    return found


@pytest.mark.parametrize("package", FACADES)
def test_each_lazy_name_is_imported_for_type_checkers_from_the_module_it_loads_from(package):
    module = importlib.import_module(package)
    where = module._WHERE
    assert _type_checking_imports(package) == {name: f"{package}.{sub}" for name, sub in where.items()}
    assert len(module.__all__) == len(set(module.__all__)) and set(where) <= set(module.__all__)
    eager = set(module.__all__) - set(where)
    assert all(name in vars(module) for name in eager), f"{package}: {eager - set(vars(module))} neither lazy nor imported"


@pytest.mark.parametrize("package", FACADES)
def test_no_public_name_is_also_a_submodule(package):
    """A submodule, once imported, is an attribute of its package and would hide a name of that name."""
    module = importlib.import_module(package)
    submodules = {m.name for m in pkgutil.iter_modules(module.__path__)}
    assert submodules.isdisjoint(module.__all__), submodules & set(module.__all__)


def test_importing_every_facade_loads_none_of_the_heavy_libraries():
    code = ("import sys; import " + ", ".join(FACADES) +
            "; print(sorted(m for m in ('torch', 'mujoco', 'cv2', 'onnxruntime', 'onnx', 'numpy') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"
