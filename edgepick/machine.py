"""What machine a measurement ran on: CPU model, the instruction sets that decide int8 speed,
cores, and the GPU when one was used. Results files are named and headed with it. No torch."""

from __future__ import annotations

import os
import platform
import re
from datetime import date
from pathlib import Path

# the flags that decide which int8 kernels onnxruntime / OpenVINO can use
INT8_FLAGS = ("avx2", "avx512f", "avx512_vnni", "avx_vnni", "amx_int8")


def _cpuinfo() -> dict[str, str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return {}
    info: dict[str, str] = {}
    for line in text.splitlines():
        key, _, value = line.partition(":")
        info.setdefault(key.strip(), value.strip())
    return info


def cpu_model() -> str:
    return _cpuinfo().get("model name") or platform.processor() or platform.machine()


def cpu_flags() -> list[str]:
    present = set(_cpuinfo().get("flags", "").split())
    return [f for f in INT8_FLAGS if f in present]


def machine_slug(gpu: str | None = None) -> str:
    """'nvidia-h100-80gb-hbm3' for a GPU run, else e.g. 'intel-xeon-avx2-avx512_vnni-amx_int8-2core'."""
    if gpu:
        return re.sub(r"[^a-z0-9]+", "-", gpu.lower()).strip("-")
    model = re.sub(r"\((r|tm)\)|\bcpu\b|\bprocessor\b|@.*$|\b\d+(-core)?\b", " ", cpu_model().lower())
    model = "-".join(re.sub(r"[^a-z0-9]+", " ", model).split()[:4]) or platform.machine()
    flags = [f for f in cpu_flags() if f != "avx512f"]
    return "-".join([model, *flags, f"{os.cpu_count()}core"])


def cpu_summary() -> str:
    """The CPU model and its int8 flags, for a record kept with a file timed on this machine."""
    return f"{cpu_model()} ({', '.join(cpu_flags()) or 'no int8 flags'})"


def machine_line(gpu: str | None = None) -> str:
    """One Markdown line for a results file's header."""
    flags = ", ".join(cpu_flags()) or "none of " + ", ".join(INT8_FLAGS)
    return (f"Machine: {cpu_model()}, {os.cpu_count()} cores, flags {flags}"
            + (f"; GPU {gpu}" if gpu else "; no GPU used"))


def results_file(results: str | Path, study: str, machine: str | None = None) -> Path:
    """RESULTS/<study>/<yyyy-mm-dd>-<machine>.md, the layout of benchmarks/results (MACHINE: this
    CPU's machine_slug() unless given)."""
    return Path(results) / study / f"{date.today().isoformat()}-{machine or machine_slug()}.md"
