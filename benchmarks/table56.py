"""Thesis Table 5.6 for the reference model (edgepick/reference/MODEL_CARD.md): its fp32, static and
hybrid-QaT files, 50 executions each of the whole pick cycle in the synthetic cell, with the scenes'
true labels as the first row (the grasp step's own ceiling) and on further scene sets (the spread).

    bash benchmarks/reference_model.sh reference-run      # makes the three files on one GPU (MODEL_CARD.md)
    python benchmarks/table56.py --models reference-run/models/{fp32,static,hybrid}.onnx --save
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from grasp_success import cell_report, parse_args  # noqa: E402

NOTE = ("The models: `bash benchmarks/reference_model.sh` (edgepick/reference/MODEL_CARD.md: data seed, "
        "training command, test-split metrics); the shipped int8 file is the static row.\n")
RUN = "reference-run/models"


def main() -> None:
    args = parse_args(__doc__, [f"{RUN}/fp32.onnx", f"{RUN}/static.onnx", f"{RUN}/hybrid.onnx"], "1,2,3,4,5,6,7,8,9")
    cell_report(args, "python benchmarks/table56.py", NOTE)


if __name__ == "__main__":
    main()
