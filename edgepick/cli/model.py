"""`edgepick model info|wrap`: look into an ONNX file, and make a model from elsewhere one the runtime runs."""

from __future__ import annotations

import click

from edgepick.cli.options import emit, preprocessing_of, preprocessing_options, with_options
from edgepick.files import check_output


@click.group()
def model() -> None:
    """ONNX files from anywhere: what they are (info), and a segmentation model from elsewhere
    made into an edgepick model (wrap) that eval, bench, grasp and pick run."""


@model.command("info")
@click.argument("model_file", metavar="MODEL", type=click.Path())
def model_info(model_file: str) -> None:
    """Print what MODEL is: inputs, outputs, opset, precision, int8 conv count, metadata, and
    whether the runtime takes it as an edgepick model (docs/contracts.md#onnx-model)."""
    from edgepick.export.onnx_io import describe

    emit(describe(model_file))


@model.command("wrap")
@click.argument("model_file", metavar="MODEL", type=click.Path())
@click.option("--classes", required=True, metavar="A,B,C",
              help="Class names of the output's channels, in order (two for a one-channel map: below, above "
                   "the threshold).")
@click.option("--output", default=None, metavar="NAME", help="The output the labels come from [default: the first].")
@click.option("--threshold", default=None, type=float,
              help="For a one-channel output [default: 0.5 after a Sigmoid, else 0].")
@click.option("--out", required=True, type=click.Path(dir_okay=False), help="The edgepick model to write (.onnx).")
@with_options(preprocessing_options)
def model_wrap(model_file: str, classes: str, output: str | None, threshold: float | None, out: str, **preprocessing) -> None:
    """Put the preprocessing (colour order, scale, mean/std, layout) and the label step (ArgMax
    over the output's channels, or a threshold of a one-channel map) into MODEL's graph and
    write edgepick's metadata: uint8 RGB image in, uint8 labels out. Works on fp32 and int8 files.

    \b
    edgepick model wrap det.onnx --classes background,text --size 640x480 --channels bgr \\
        --mean 0.5,0.5,0.5 --std 0.5,0.5,0.5 --out det-wrapped.onnx
    """
    from edgepick.export.wrap import wrap_model

    check_output(out, "--out", suffixes=(".onnx",), inputs=(model_file,))
    names = [c.strip() for c in classes.split(",")]
    emit(wrap_model(model_file, out, names, preprocessing_of(**preprocessing), output=output, threshold=threshold))
