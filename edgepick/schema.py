"""Checked reading of the files a user hands edgepick: JSON parsed strictly, every field typed and
range-checked, and a one-line error that names the file and the field; and the two sides of a
config's choices: `member` (a value as its enum, refused by name) and `plain` (an enum as its value).

Every reader of a user's file (a data set's meta.json and grasps.json, intrinsics, calibration,
checkpoint descriptions, importer inputs) goes through these helpers, so a malformed file ends
as a `FileContentError` (exit status 2, docs/contracts.md#command-line) and is never taken as if
fine. Numbers must be finite (JSON's NaN and Infinity are refused), whole where a count or a size
is meant, and inside their range; names are non-empty strings.

    where = Where("data/meta.json")
    meta = as_dict(read_json(path, "data set meta"), where)
    classes = as_names(field(meta, "classes", where), where.at("classes"), min_length=2)
"""

from __future__ import annotations

import enum
import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal, NoReturn, TypeVar, overload

from edgepick.errors import EdgepickError, ParameterError

MISSING: Any = object()  # field(): no default, the key is required
E = TypeVar("E", bound=enum.Enum)


class FileContentError(EdgepickError):
    """A file whose content is not what its kind needs: not text, not JSON, a field missing or wrong."""


@dataclass(frozen=True)
class Where:
    """A place in a file, for messages: the file's name and the path to a field inside it."""

    file: str
    path: str = ""

    def at(self, key: str | int) -> Where:
        step = f"[{key}]" if isinstance(key, int) else (f".{key_name(key)}" if self.path else key_name(key))
        return Where(self.file, self.path + step)

    def fail(self, problem: str) -> NoReturn:
        raise FileContentError(f"{self.file}: {self.path + ' ' if self.path else ''}{problem}")


def key_name(key: object) -> str:
    """KEY as a message shows it: as is when it is plain one-line text, else quoted (a name with a
    line break or surrounding spaces must not break the one-line error)."""
    text = str(key)
    return text if text and text.isprintable() and text.strip() == text else repr(text)


def refuse_unknown(values: dict, known: Iterable[str], where: Where) -> None:
    """Fail at WHERE naming every key of VALUES that is not one of KNOWN."""
    known = set(known)
    unknown = sorted({key_name(k) for k in values if k not in known})
    if unknown:
        where.fail(f"has unknown fields {', '.join(unknown)}")


def describe(value: Any) -> str:
    """A short description of a JSON value for an error message."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f"the string {value[:30]!r}" + ("..." if len(value) > 30 else "")
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


def read_text(path: str | Path, what: str) -> str:
    """The file as UTF-8 text, or a one-line error (missing, unreadable, binary or another encoding)."""
    try:
        data = Path(path).read_bytes()
    except IsADirectoryError:
        raise FileContentError(f"{what} {path} is a folder, not a file") from None
    except OSError as exc:
        raise FileContentError(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    if b"\0" in data:
        raise FileContentError(f"{what} {path} is not a text file (it holds NUL bytes)")
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise FileContentError(f"{what} {path} is not UTF-8 text (byte {exc.start}); save it as UTF-8") from None


def _refuse_constant(name: str) -> NoReturn:
    raise ValueError(f"{name} is not a number JSON allows")


def read_json(path: str | Path, what: str) -> Any:
    """The file's JSON value, parsed strictly: NaN and Infinity are refused, as JSON itself does."""
    text = read_text(path, what)
    try:
        return json.loads(text, parse_constant=_refuse_constant)
    except json.JSONDecodeError as exc:
        raise FileContentError(f"{what} {path} is not valid JSON: {exc.msg} (line {exc.lineno}, "
                               f"column {exc.colno})") from None
    except ValueError as exc:
        raise FileContentError(f"{what} {path} is not valid JSON: {exc}") from None
    except RecursionError:
        raise FileContentError(f"{what} {path} is nested too deeply to be a {what}") from None


def as_dict(value: Any, where: Where) -> dict:
    if not isinstance(value, dict):
        where.fail(f"must be a JSON object, got {describe(value)}")
    return value


def field(obj: dict, key: str, where: Where, default: Any = MISSING) -> Any:
    """OBJ[KEY]; a missing key is an error naming it, unless a DEFAULT is given."""
    if key in obj:
        return obj[key]
    if default is MISSING:
        where.fail(f"has no {key!r}" if where.path else f"has no field {key!r}")
    return default


@overload
def as_number(value: Any, where: Where, *, integer: Literal[True], minimum: float | None = None,
              above: float | None = None, maximum: float | None = None) -> int: ...


@overload
def as_number(value: Any, where: Where, *, integer: bool = False, minimum: float | None = None,
              above: float | None = None, maximum: float | None = None) -> float: ...


def as_number(value: Any, where: Where, *, integer: bool = False, minimum: float | None = None,
              above: float | None = None, maximum: float | None = None) -> float | int:
    """A finite number (whole when INTEGER), >= MINIMUM, > ABOVE, <= MAXIMUM."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        where.fail(f"must be a number, got {describe(value)}")
    if not math.isfinite(value):
        where.fail(f"must be a finite number, got {value!r}")
    if integer:
        if value != int(value):
            where.fail(f"must be a whole number, got {value!r}")
        value = int(value)
    if minimum is not None and value < minimum:
        where.fail(f"must be {minimum} or more, got {value!r}")
    if above is not None and value <= above:
        where.fail(f"must be above {above}, got {value!r}")
    if maximum is not None and value > maximum:
        where.fail(f"must be {maximum} or less, got {value!r}")
    return value


def as_str(value: Any, where: Where, choices: tuple[str, ...] = ()) -> str:
    """A non-empty string (one of CHOICES when given)."""
    if not isinstance(value, str) or not value:
        where.fail(f"must be a non-empty string, got {describe(value)}")
    if choices and value not in choices:
        where.fail(f"must be one of {', '.join(choices)}, got {value!r}")
    return value


def as_list(value: Any, where: Where, length: int | None = None, min_length: int = 0) -> list:
    """A list (or tuple) of LENGTH items, or of MIN_LENGTH or more."""
    if not isinstance(value, (list, tuple)):
        where.fail(f"must be a list, got {describe(value)}")
    if length is not None and len(value) != length:
        where.fail(f"must be a list of {length}, got {len(value)}")
    if len(value) < min_length:
        where.fail(f"must list at least {min_length}, got {len(value)}")
    return list(value)


@overload
def as_numbers(value: Any, where: Where, length: int, *, integer: Literal[True], **limits: float | None) -> list[int]: ...


@overload
def as_numbers(value: Any, where: Where, length: int, *, integer: bool = False, **limits: float | None) -> list[float]: ...


def as_numbers(value: Any, where: Where, length: int, *, integer: bool = False,
               **limits: float | None) -> list[float] | list[int]:
    """A list of LENGTH finite numbers (whole when INTEGER), each within LIMITS (as_number's
    minimum, above, maximum)."""
    return [as_number(v, where.at(i), integer=integer, **limits)  # type: ignore[misc]
            for i, v in enumerate(as_list(value, where, length))]


def as_names(value: Any, where: Where, min_length: int = 1) -> list[str]:
    """A list of distinct non-empty strings (class names)."""
    names = [as_str(v, where.at(i)) for i, v in enumerate(as_list(value, where, min_length=min_length))]
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        where.fail(f"names {twice!r} twice")
    return names


def member(kind: type[E], parameter: str, value: Any) -> E:
    """VALUE (a member of the enum KIND or its value) as a member; anything else is a
    ParameterError naming PARAMETER and the choices."""
    try:
        return kind(value)
    except ValueError:
        choices = ", ".join(str(m.value) for m in kind)
        raise ParameterError(f"{{{parameter}}}: must be one of {choices}", **{parameter: value}) from None


def plain(value: Any) -> Any:
    """VALUE as a file records it: an enum member as its value (a checkpoint or JSON file then holds
    the same plain strings and numbers whichever classes wrote it)."""
    return value.value if isinstance(value, enum.Enum) else value
