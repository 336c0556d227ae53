"""`edgepick bench`: thesis Table 5.5 (accuracy, latency, training time, size per model) and the
Table 5.6 analogue (whole pipeline time per frame), measured in one process; `bench --cell`'s
closed loop in the synthetic cell. No torch, except `make_table55`, which trains.

    from edgepick.bench import BenchConfig, run_bench
"""

from typing import TYPE_CHECKING

from edgepick.lazy import lazy_attributes

_WHERE = {
    "CellRow": "cell", "run_cell": "cell", "write_cell_reports": "cell", "Measured": "compare",
    "compare_section": "compare", "rounds_section": "compare", "BenchConfig": "measure", "Row": "measure",
    "bench_model": "measure", "markdown": "report", "write_reports": "report", "run_bench": "run",
    "Setting": "table55", "make_table55": "table55"
}
__all__ = sorted(_WHERE)

if TYPE_CHECKING:
    from edgepick.bench.cell import CellRow, run_cell, write_cell_reports
    from edgepick.bench.compare import Measured, compare_section, rounds_section
    from edgepick.bench.measure import BenchConfig, Row, bench_model
    from edgepick.bench.report import markdown, write_reports
    from edgepick.bench.run import run_bench
    from edgepick.bench.table55 import Setting, make_table55


__getattr__ = lazy_attributes(__name__, _WHERE)
