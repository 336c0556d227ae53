"""Errors a user can cause. The CLI prints their one-sentence message and exits with their exit_code."""

from __future__ import annotations

import enum
import re
from collections.abc import Callable
from pathlib import Path

# {name}: the parameter NAME and its value; {name:name}: its name alone
_PLACE = re.compile(r"\{(\w+)(:name)?\}")


class EdgepickError(Exception):
    """Base class: a user's error, reported as one line without a traceback."""

    exit_code = 2  # docs/contracts.md#command-line


class DatasetError(EdgepickError):
    """A dataset is missing, half-written or does not follow the native layout."""


class ConfigError(EdgepickError):
    """An option value or combination of options is invalid."""


class ParameterError(ConfigError):
    """A value given for a parameter is refused. The message names each parameter as a Python caller
    gave it ("percentile=101.0: must be in (50, 100]"); the command line says the same of its own
    flags ("--percentile 101.0: ...") from TEMPLATE and PARAMETERS (the values the message shows)."""

    def __init__(self, template: str, **parameters: object):
        self.template, self.parameters = template, parameters
        super().__init__(self.render(python_name))

    def render(self, name: Callable[[str, object, bool], str]) -> str:
        """The message with each {parameter} as NAME(parameter, value, True) writes it, and each
        {parameter:name} as NAME(parameter, value, False) (without the value)."""
        def place(m: re.Match) -> str:
            key = m.group(1)
            return name(key, self.parameters[key], m.group(2) is None) if key in self.parameters else m.group(0)

        return _PLACE.sub(place, self.template)


def python_name(parameter: str, value: object, with_value: bool) -> str:
    """A parameter as a Python caller writes it: `percentile=101.0`, or `percentile` alone."""
    if not with_value:
        return parameter
    if isinstance(value, enum.Enum):
        value = value.value
    return f"{parameter}={str(value)!r}" if isinstance(value, Path) else f"{parameter}={value!r}"


class QuantizationError(EdgepickError):
    """A pass that would silently produce an unquantized model, or one far from its float model."""


class CheckpointError(EdgepickError):
    """A checkpoint or model file is missing, unreadable or incompatible."""


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (`timeout`, systemd, a closed terminal), raised as Ctrl-C's KeyboardInterrupt
    is, so that every clean-up that Ctrl-C runs runs for them too; the CLI exits with 128 + the signal."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum
