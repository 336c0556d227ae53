"""Int8 passes (static PTQ, QaT, hybrid-QaT) on torchao's pt2e flow; see passes.py."""

import edgepick.export  # noqa: F401 - quiets torchao's and the exporter's import-time logging
