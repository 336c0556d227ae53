"""Int8 passes (static PTQ, QaT, hybrid-QaT) on torchao's pt2e flow; see passes.py."""
