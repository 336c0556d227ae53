"""edgepick.runtime (and the CLI module) must import with torch unavailable: the laptop install has none."""

import subprocess
import sys

from tests.conftest import REPO

BLOCK = """
import importlib.abc, sys
class _NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ImportError("torch is blocked in this test")
sys.meta_path.insert(0, _NoTorch())
"""


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", BLOCK + code], cwd=REPO, capture_output=True, text=True, timeout=120)


def test_runtime_robot_sim_bench_and_every_submodule_import_without_torch():
    proc = _run("""
import importlib, pkgutil, edgepick.runtime, edgepick.robot, edgepick.sim, edgepick.bench, edgepick.cli
names = [m.name for pkg in (edgepick.runtime, edgepick.robot, edgepick.sim, edgepick.bench, edgepick.cli)
         for m in pkgutil.walk_packages(pkg.__path__, pkg.__name__ + '.')]
names += ['edgepick.geometry', 'edgepick.frames', 'edgepick.files', 'edgepick.progress', 'edgepick.onnx_graph']
for n in names:
    importlib.import_module(n)
assert 'torch' not in sys.modules
print(len(names))
""")
    assert proc.returncode == 0, proc.stderr
    assert int(proc.stdout.strip()) >= 1


def test_blocker_really_blocks():
    proc = _run("import torch")
    assert proc.returncode != 0 and "blocked" in proc.stderr


def test_cli_and_data_modules_import_without_torch():
    proc = _run("import edgepick.cli, edgepick.data.synth, edgepick.data.native, edgepick.metrics; "
                "assert 'torch' not in sys.modules")
    assert proc.returncode == 0, proc.stderr
