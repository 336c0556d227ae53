"""onnxruntime's pre-processing of a float ONNX model before static PTQ (shapes inferred, BatchNorm
folded, graph optimised), with the fallback its shape inference needs on some graphs."""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from edgepick.errors import ParameterError


def pre_process(proto: Any, out: Path) -> None:
    """onnxruntime's pre-processing (shapes inferred, BatchNorm folded, graph optimised) of PROTO into
    OUT. Its symbolic shape inference asserts on some graphs (a Concat of an LSTM's outputs, among
    them): then onnx's own shape inference does, and what still fails is refused in one line. It
    reads PROTO from a file: given a ModelProto, it moves the weights out of it (to a placeholder
    file) before its shape inference reads them."""
    import onnx
    from onnxruntime.quantization import quant_pre_process

    source = out.with_name(f"{out.stem}-in.onnx")
    onnx.save(proto, str(source))
    try:
        with quiet():
            quant_pre_process(str(source), str(out))
        return
    except Exception:  # noqa: BLE001 - its shape inference raises AssertionError and others
        pass
    try:
        with quiet():
            quant_pre_process(str(source), str(out), skip_symbolic_shape=True)
    except Exception as exc:  # noqa: BLE001
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        raise ParameterError(f"{{model:name}}: onnxruntime's pre-processing (shape inference, optimisation) fails "
                             f"on this graph: {first}", model=None) from None


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    """onnxruntime's quantizer prints its steps to stdout, where edgepick's commands print their
    JSON; edgepick's own progress bar says what it is doing."""
    with contextlib.redirect_stdout(io.StringIO()):
        yield
