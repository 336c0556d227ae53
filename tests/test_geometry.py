"""edgepick/geometry.py's Size: width first as the command line writes it, (height, width) only
when asked for by name, and never a tuple that could be unpacked in the wrong order."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from edgepick.errors import ConfigError
from edgepick.geometry import Size, check_size


def test_parse_str_and_the_two_orders():
    size = Size.parse("640x480")
    assert size == Size(640, 480) and (size.width, size.height) == (640, 480)
    assert str(size) == "640x480" and Size.parse(str(Size(96, 64))) == Size(96, 64)
    assert Size.parse("320X240") == Size(320, 240)
    assert size.hw == (480, 640)
    assert Size.from_hw((480, 640)) == size and Size.from_hw(size.hw) == size
    assert Size.of(np.zeros((48, 64, 3), np.uint8)) == Size(64, 48) and Size.of(np.zeros((48, 64))) == Size(64, 48)


def test_whole_numbers_from_numpy_are_plain_ints():
    size = Size(np.int64(64), np.int32(48))
    assert size == Size(64, 48) and type(size.width) is int and type(size.height) is int


@pytest.mark.parametrize("width, height, message", [
    (0, 480, "size: width must be a positive whole number"),
    (640, -1, "size: height must be a positive whole number"),
    (640.0, 480, "size: width must be a positive whole number"),
    (True, 480, "size: width must be a positive whole number"),
    ("640", 480, "size: width must be a positive whole number"),
])
def test_bad_sides_are_refused_naming_the_side(width, height, message):
    with pytest.raises(ConfigError, match=message):
        Size(width, height)


@pytest.mark.parametrize("text", ["640by480", "640x480x3", "x480", "640", "", "wxh"])
def test_parse_refuses_anything_but_widthxheight(text):
    with pytest.raises(ConfigError, match="size must be WIDTHxHEIGHT like 640x480"):
        Size.parse(text)


def test_parse_refuses_a_side_of_zero():
    with pytest.raises(ConfigError, match="size: height must be a positive whole number"):
        Size.parse("640x0")


def test_a_size_cannot_be_unpacked_indexed_or_changed():
    size = Size(640, 480)
    with pytest.raises(TypeError):
        h, w = size  # noqa: F841 - the (H, W) tuple habit fails loudly
    with pytest.raises(TypeError):
        size[0]
    with pytest.raises(TypeError):
        tuple(size)
    with pytest.raises(dataclasses.FrozenInstanceError):
        size.width = 320
    assert size != (480, 640) and size != (640, 480)


def test_check_size_refuses_a_tuple_in_one_line():
    assert check_size(Size(64, 48), "x") == Size(64, 48)
    with pytest.raises(ConfigError, match=r"^TrainConfig size must be a Size\(width, height\)") as exc:
        check_size((480, 640), "TrainConfig size")
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("change, message", [
    ({"fx": 1e-9}, "x.json: fx must be in [32, 64000] px for an image 640 px in width (a field of view of 169 to 0.6"),
    ({"fx": 31.9}, "fx must be in [32, 64000] px"),
    ({"fy": 48001.0}, "fy must be in [24, 48000] px for an image 480 px in height"),
    ({"cx": 1e9}, "cx must lie within one image width of the 640 px image, in [-640, 1280] px, got 1000000000.0"),
    ({"cy": -481.0}, "cy must lie within one image height of the 480 px image, in [-480, 960] px"),
    ({"depth_scale": 1000}, "depth_scale must be in [1e-06, 0.01] metres per depth unit (0.001: millimetres), got 1000"),
    ({"depth_scale": 1e-7}, "depth_scale must be in [1e-06, 0.01]"),
])
def test_intrinsics_no_camera_has_are_refused_naming_the_file_and_field(change, message):
    from edgepick.geometry import Intrinsics
    from edgepick.schema import FileContentError, Where

    good = Intrinsics.d415(640, 480).to_dict()
    Intrinsics.from_dict({**good, "fx": 32.0, "cy": 960.0, "depth_scale": 0.01}, Where("x.json"))  # the bounds hold
    with pytest.raises(FileContentError) as err:
        Intrinsics.from_dict({**good, **change}, Where("x.json"))
    assert message in str(err.value)
