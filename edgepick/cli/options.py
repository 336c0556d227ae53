"""Options and parsers shared by the command groups (click only, no torch). An option's choices
and default come from the library's own config (`choice`, `default_of`), so each is written once.

Every `--size` in edgepick is WIDTHxHEIGHT, as cameras and image files state it (640x480),
and is parsed here into a `Size(width, height)` (edgepick.geometry), the form every size takes
in the Python API; arrays and file metadata keep (height, width), as numpy and torch do (`Size.hw`).
"""

from __future__ import annotations

import dataclasses
import enum
import inspect
import json
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import click

from edgepick.errors import ConfigError
from edgepick.geometry import Size
from edgepick.train.config import TrainConfig

if TYPE_CHECKING:
    from edgepick.runtime.preprocessing import ChannelOrder, Layout, Preprocessing

SIZE_HELP = "WIDTHxHEIGHT"


def parse_size(text: str, model_input: bool = False) -> Size:
    """'640x480' -> Size(640, 480). A model input needs sides that are multiples of 8 and >= 32
    (the backbone's stride); a camera or rendered image needs 32..4096 per side."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--size must be {SIZE_HELP} like 640x480, got {text!r}") from None
    if model_input and (w < 32 or h < 32 or w % 8 or h % 8):
        raise ConfigError(f"--size {text!r}: both sides must be multiples of 8 and at least 32")
    if not (32 <= w <= 4096 and 32 <= h <= 4096):
        raise ConfigError(f"--size {text!r} out of range (32..4096 per side)")
    return Size(w, h)


def model_size(text: str) -> Size:
    """A model input --size: sides that are multiples of 8 and at least 32."""
    return parse_size(text, model_input=True)


def check_orientation(size: Size, image: Size, option: str = "--size") -> None:
    """Refuse a model input SIZE that is the data's IMAGE size turned on its side: the usual sign of a
    size given as HEIGHTxWIDTH (e.g. 480x640 for 640x480 images)."""
    (h, w), (ih, iw) = size.hw, image.hw
    if h != w and ih != iw and (h > w) != (ih > iw):
        if h * ih == w * iw:
            raise ConfigError(f"{option} {w}x{h} turns the {iw}x{ih} images on their side; sizes are "
                              f"{SIZE_HELP} in edgepick: did you mean {h}x{w}?")
        shape = "portrait" if h > w else "landscape"
        click.echo(f"edgepick: warning: {option} {w}x{h} is {shape} but the {iw}x{ih} images are not; they will "
                   f"be squeezed to it (sizes are {SIZE_HELP})", err=True)


def check_data_orientation(data_dir: str, size: Size) -> None:
    """check_orientation against the first train image of DATA (one PNG read)."""
    from edgepick.data.native import NativeDataset

    ds = NativeDataset.open(data_dir, "train")
    if len(ds):
        check_orientation(size, Size.of(ds.rgb(ds.ids[0])))


class EnumChoice(click.Choice[Any]):
    """A click choice of an enum's values, in their order, that hands the command the enum member
    (`--arch unet` -> Arch.UNET): the command passes on the library's own type, and help and refusals
    read as click's plain choice of strings."""

    def __init__(self, kind: type[enum.Enum]) -> None:
        self.kind = kind
        self.members = {str(m.value): m for m in kind}
        super().__init__(list(self.members))

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, self.kind):
            return value
        return self.members[super().convert(value, param, ctx)]


def choice(kind: type[enum.Enum]) -> EnumChoice:
    """The option type of the enum KIND's values, which yields KIND's members: the library's own choices."""
    return EnumChoice(kind)


def default_of(owner: type | Callable, name: str) -> Any:
    """The default a library config (a dataclass field) or function (a parameter) gives NAME, as a
    plain value (an enum member as its value), so an option's default is written once."""
    if dataclasses.is_dataclass(owner):
        (f,) = [f for f in dataclasses.fields(owner) if f.name == name]
        value = f.default if f.default_factory is dataclasses.MISSING else f.default_factory()
    else:
        value = inspect.signature(owner).parameters[name].default
    if value is dataclasses.MISSING or value is inspect.Parameter.empty:
        raise TypeError(f"{name} of {owner.__name__} has no default")
    return value.value if isinstance(value, enum.Enum) else value


def with_options(options):
    """Apply a list of click options to a command, in the order listed."""
    def wrap(f):
        for opt in reversed(options):
            f = opt(f)
        return f
    return wrap


# shared by `edgepick train` and `edgepick quantize qat`
epoch_subset = [
    click.option("--epoch-images", default=default_of(TrainConfig, "epoch_images"), show_default=True,
                 help="Images per epoch, drawn afresh from the train split each epoch; 0 = the whole split."),
    click.option("--val-images", default=default_of(TrainConfig, "val_images"), show_default=True,
                 help="Validate each epoch on this many evenly spaced val images; 0 = the whole split."),
]


def emit(result: dict | Any) -> None:
    """A command's result (a dict, or a result record's `to_dict()`): JSON on stdout (progress and
    tables go to stderr)."""
    click.echo(json.dumps(result if isinstance(result, dict) else result.to_dict(), indent=1))


def parse_numbers(text: str, option: str, count: int | None = None, integer: bool = False) -> tuple:
    """'0.485,0.456,0.406' -> (0.485, 0.456, 0.406); COUNT of them when given, whole numbers when INTEGER."""
    try:
        values = tuple((int if integer else float)(v) for v in text.split(","))
    except ValueError:
        kind = "whole numbers" if integer else "numbers"
        raise ConfigError(f"{option} {text}: must be comma-separated {kind}") from None
    if count is not None and len(values) != count:
        raise ConfigError(f"{option} {text}: must be {count} comma-separated numbers")
    return values


def _preprocessing_options() -> list:
    from edgepick.runtime.preprocessing import ChannelOrder, Layout, Preprocessing

    return [
        click.option("--size", "image_size", default=None, metavar=SIZE_HELP,
                     help="The image size the model takes [default: its input's fixed size]."),
        click.option("--channels", default=default_of(Preprocessing, "channels"), show_default=True,
                     type=choice(ChannelOrder), help="The colour order the model was trained on."),
        click.option("--scale", default=default_of(Preprocessing, "scale"), show_default="1/255",
                     help="Pixel values (0..255) are multiplied by this first."),
        click.option("--mean", default="0,0,0", show_default=True, metavar="A,B,C",
                     help="Then this is subtracted, per channel (in the model's channel order)."),
        click.option("--std", default="1,1,1", show_default=True, metavar="A,B,C",
                     help="Then divided by this, per channel; ImageNet: --mean 0.485,0.456,0.406 "
                          "--std 0.229,0.224,0.225."),
        click.option("--layout", default=default_of(Preprocessing, "layout"), show_default=True,
                     type=choice(Layout), help="Where the channel axis is (nhwc: TensorFlow models)."),
    ]


preprocessing_options = _preprocessing_options()


def preprocessing_of(image_size: str | None, channels: ChannelOrder, scale: float, mean: str, std: str,
                     layout: Layout) -> Preprocessing:
    """The Preprocessing of the options above."""
    from edgepick.runtime.preprocessing import Preprocessing

    size = parse_size(image_size) if image_size else None
    return Preprocessing(size=size, channels=channels, scale=scale, mean=parse_numbers(mean, "--mean", 3),
                         std=parse_numbers(std, "--std", 3), layout=layout)


def round_config(rounds: int | None, max_cycles: int | None) -> Any:
    """The RoundConfig of --rounds and --max-cycles (None without --rounds), refused in one line where they
    cannot be: pick and bench --cell take them alike."""
    if rounds is None:
        if max_cycles is not None:
            raise ConfigError(f"--max-cycles {max_cycles}: caps the cycles of a round; it needs --rounds")
        return None
    if rounds < 1:
        raise ConfigError(f"--rounds {rounds}: must be at least 1")
    from edgepick.sim.clutter import RoundConfig

    return RoundConfig(max_cycles=max_cycles)
