"""Errors a user can cause. The CLI prints their one-sentence message and exits with their exit_code."""


class EdgepickError(Exception):
    """Base class: a user's error, reported as one line without a traceback."""

    exit_code = 2  # docs/contracts.md#command-line


class DatasetError(EdgepickError):
    """A dataset is missing, half-written or does not follow the native layout."""


class ConfigError(EdgepickError):
    """An option value or combination of options is invalid."""


class CheckpointError(EdgepickError):
    """A checkpoint or model file is missing, unreadable or incompatible."""


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP (`timeout`, systemd, a closed terminal), raised as Ctrl-C's KeyboardInterrupt
    is, so that every clean-up that Ctrl-C runs runs for them too; the CLI exits with 128 + the signal."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum
