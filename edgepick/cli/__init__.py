"""The `edgepick` command line: a thin click layer over the package's public functions.

One module per command group; options, parsers and checks they share are in `options.py`.
Heavy modules (torch, the trainer) are imported inside the commands, so `edgepick --help`
and the runtime commands start fast and work on the torch-free base install.

Exit status (docs/contracts.md#command-line): 0 done; 2 a user's error (one line on stderr,
nothing half-written left behind); 3 the robot halted or its link failed (`pick`); 130
interrupted (Ctrl-C), 143 terminated (SIGTERM), 129 hung up (SIGHUP), each after the same clean-up;
1 anything else (a bug: the traceback is printed).
"""

from __future__ import annotations

import contextlib
import enum
import functools
import logging
import os
import re
import signal
import sys
import threading
import warnings

import click

from edgepick import __version__
from edgepick.cli.bench import bench
from edgepick.cli.calibrate import calibrate
from edgepick.cli.data import data
from edgepick.cli.grasp import grasp
from edgepick.cli.model import model
from edgepick.cli.pick import pick
from edgepick.cli.qat import quantize_hybrid_cmd, quantize_qat_cmd
from edgepick.cli.quant import export_cmd, quantize
from edgepick.cli.replay import replay
from edgepick.cli.train import demo, eval_cmd, train
from edgepick.errors import EdgepickError, ParameterError, Terminated, python_name
from edgepick.progress import log_interval_s

EXIT_USER_ERROR = 2
EXIT_ROBOT_HALTED = 3
EXIT_INTERRUPTED = 130

# modules of the [train] extra: a command that needs one on the base install says which extra to add
TRAIN_EXTRA = {"torch", "torchao", "onnx", "onnxscript", "torchvision"}

# library parameters whose command-line option has another name (a unit in the name, or a shorter one)
ALIASES = {"calib": "calib_images", "data": "data_dir", "debug_log": "robot_log", "depth_scale_m": "depth_scale",
           "interval_s": "interval", "max_drop_pp": "max_miou_drop", "max_rmse_m": "max_rmse",
           "offset_m": "marker_offset", "settle_s": "settle", "sizes": "subsets", "spec": "marker_spec",
           "split_fractions": "splits", "size": "image_size", "task": "tasks",
           "min_sqnr_db": "min_sqnr", "max_float": "max_float_layers", "model": ("checkpoint", "model_file")}


@click.group(context_settings={"help_option_names": ["-h", "--help"], "max_content_width": 100})
@click.version_option(__version__, prog_name="edgepick")
def cli() -> None:
    """edgepick: train DeepLabV3, quantize it to int8, and run robot picking on a CPU.

    \b
    The path: data synth -> train -> eval (-> quantize -> export -> grasp/pick -> bench).
    `edgepick demo` runs the main job end to end on synthetic data.
    Exit status: 0 done, 2 a mistake in the input (one line on stderr), 3 the robot halted
    or its link failed, 130 interrupted (143 on SIGTERM), 1 a bug (with its traceback).
    In a log (stderr not a terminal) long work prints a progress line every 10 s, or every
    EDGEPICK_PROGRESS_S seconds when the environment sets it.
    """
    log_interval_s()  # a bad EDGEPICK_PROGRESS_S is refused before any work, not when the first bar starts


for _command in (quantize_qat_cmd, quantize_hybrid_cmd):
    quantize.add_command(_command)
for _command in (data, train, eval_cmd, calibrate, grasp, demo, export_cmd, quantize, model, pick, replay, bench):
    cli.add_command(_command)


def _commands(command: click.Command) -> list[click.Command]:
    """The commands under COMMAND (itself when it is not a group)."""
    if isinstance(command, click.Group):
        return [c for sub in command.commands.values() for c in _commands(sub)]
    return [command]


def _tag_parameter_errors(command: click.Command) -> None:
    """Have COMMAND's ParameterErrors carry the command, so that the error line names its flags."""
    callback = command.callback

    @functools.wraps(callback)
    def tagged(*args, **kwargs):
        try:
            return callback(*args, **kwargs)
        except ParameterError as exc:
            exc.command = command
            raise

    command.callback = tagged


for _command in _commands(cli):
    _tag_parameter_errors(_command)


def _option_for(parameter: str, command: click.Command) -> click.Parameter | None:
    """The click parameter that gives the library's PARAMETER: COMMAND's own (by name, or by its
    alias), else the one option of that name that other commands share (a hint at another command's
    flag, e.g. train's --keep-epochs in hybrid-QaT's error)."""
    alias = ALIASES.get(parameter, ())
    names = (parameter, *((alias,) if isinstance(alias, str) else alias))
    own = [p for p in command.params if p.name in names]
    if own:
        return own[0]
    others = {p.opts[0]: p for c in _commands(cli) for p in c.params
              if p.name in names and isinstance(p, click.Option)}
    return next(iter(others.values())) if len(others) == 1 else None


def _shown(value: object) -> str:
    """A value as a user types it on the command line."""
    if isinstance(value, enum.Enum):
        return str(value.value)
    if isinstance(value, (list, tuple)):
        return ",".join(_shown(v) for v in value)
    return str(value)


def command_line_message(exc: ParameterError, command: click.Command) -> str:
    """EXC's message with COMMAND's flags where it names a library parameter ("--percentile 101.0"
    for "percentile=101.0"); a parameter the command line has no option for keeps its Python name."""
    def name(parameter: str, value: object, with_value: bool) -> str:
        param = _option_for(parameter, command)
        if param is None:
            return python_name(parameter, value, with_value)
        if isinstance(param, click.Argument):
            label = param.human_readable_name
        elif param.is_flag and isinstance(value, bool):
            return param.opts[0] if value or not param.secondary_opts else param.secondary_opts[0]
        else:
            label = next((o for o in param.opts if o.startswith("--")), param.opts[0])
        return f"{label} {_shown(value)}" if with_value else label

    return exc.render(name)


def quiet_dependencies() -> None:
    """Silence dependency noise that says nothing actionable to an edgepick user: torchao's log
    line per optional CUDA kernel library, torch's pytree deprecation for torchao's classes, the
    ONNX exporter's note per skipped torchvision op, and OpenCV's decoder warnings (edgepick
    reports an unreadable image itself)."""
    for name in ("torchao", "torch.utils._pytree", "torch.onnx._internal.exporter._registration"):
        logging.getLogger(name).setLevel(logging.ERROR)
    warnings.filterwarnings("ignore", category=FutureWarning, message=r".*LeafSpec.*")
    warnings.filterwarnings("ignore", category=FutureWarning, module=r"torch\.utils\._pytree")
    try:
        import cv2

        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # no "[ WARN:0@0.05] ... findDecoder"
    except (ImportError, AttributeError):
        pass


# thread-count variables that OpenMP (libgomp, loaded with torch) reads: it prints its own line
# for a value it cannot use, before edgepick could say anything
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS")


def sanitize_thread_variables() -> list[str]:
    """Drop a thread-count variable that is not one or more positive whole numbers ("4" or
    OpenMP's nested "4,2"); returns edgepick's one-line warning for each (instead of libgomp's),
    for `run` to print once the command is over."""
    said = []
    for name in THREAD_VARIABLES:
        value = os.environ.get(name)
        if value is None or re.fullmatch(r"\s*[1-9]\d*(\s*,\s*[1-9]\d*)*\s*", value):
            continue
        del os.environ[name]
        said.append(f"edgepick: warning: {name}={value!r} is not a positive whole number; ignored (the libraries "
                    "chose their thread counts)")
    return said


@contextlib.contextmanager
def signals_as_interrupts():
    """SIGTERM and SIGHUP raise Terminated (a KeyboardInterrupt) in the main thread, so a command
    cleans up for them as for Ctrl-C; a second one while cleaning up is ignored."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame) -> None:
        for sig in (signal.SIGTERM, signal.SIGHUP):
            signal.signal(sig, signal.SIG_IGN)
        raise Terminated(signum)

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGTERM, signal.SIGHUP)}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def _fail(message: str, code: int) -> int:
    lines = [line.strip() for line in str(message).splitlines() if line.strip()]
    click.echo(f"edgepick: error: {lines[0] if lines else 'failed'}", err=True)  # one line, always
    return code


def _click_message(exc: click.ClickException) -> str:
    """click's usage errors as one line: 'train: Invalid value for ... (see edgepick train --help)'."""
    message = " ".join(exc.format_message().split())
    ctx = getattr(exc, "ctx", None)
    if ctx is None:
        return message
    command = ctx.command_path.partition(" ")[2]
    return f"{command + ': ' if command else ''}{message} (see 'edgepick {command + ' ' if command else ''}--help')"


def run(args: list[str] | None = None) -> int:
    """Run one edgepick command line (None: sys.argv) and return its exit status, having said
    any failure a user can cause in one line on stderr. A bug still raises, with its traceback."""
    held = sanitize_thread_variables()
    quiet_dependencies()
    code = None
    try:
        with signals_as_interrupts():
            code = _run(args)
        return code
    finally:
        # the environment's warnings come after the command: a refusal stays its one line (exit 2 says
        # nothing else; the warning comes with the run that follows once the mistake is mended)
        if code != EXIT_USER_ERROR:
            for line in held:
                click.echo(line, err=True)


def _run(args: list[str] | None) -> int:
    try:
        # make_context + invoke rather than cli.main: main turns an interrupt into click's Abort and
        # prints a blank line, losing which signal it was
        with cli.make_context("edgepick", list(sys.argv[1:] if args is None else args)) as ctx:
            cli.invoke(ctx)
    except EdgepickError as exc:
        command = getattr(exc, "command", None)
        if isinstance(exc, ParameterError) and command is not None:  # tagged by _tag_parameter_errors
            message = command_line_message(exc, command)
        else:
            message = str(exc)
        return _fail(message, getattr(exc, "exit_code", EXIT_USER_ERROR))
    except click.exceptions.Abort:
        click.echo("edgepick: aborted", err=True)
        return EXIT_INTERRUPTED
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.exceptions.NoArgsIsHelpError as exc:  # `edgepick quantize` alone: its help, as --help gives it
        click.echo(exc.ctx.get_help())
        return 0
    except click.ClickException as exc:
        return _fail(_click_message(exc), exc.exit_code)
    except Terminated as exc:
        click.echo(f"edgepick: terminated ({signal.Signals(exc.signum).name})", err=True)
        return 128 + exc.signum
    except KeyboardInterrupt:
        click.echo("edgepick: interrupted", err=True)
        return EXIT_INTERRUPTED
    except ModuleNotFoundError as exc:
        if (exc.name or "").split(".")[0] not in TRAIN_EXTRA:
            raise
        return _fail(f"this command needs the [train] extra ({exc.name} is not installed): "
                     "pip install 'edgepick[train]'", EXIT_USER_ERROR)
    except SystemExit as exc:  # a command (or a library under it) that ends with its own status
        return exc.code if isinstance(exc.code, int) else 1
    return 0


def main() -> None:
    """Console entry point."""
    sys.exit(run())


if __name__ == "__main__":
    main()
