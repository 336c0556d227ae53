from tests.conftest import run_cli


def test_help_lists_the_commands():
    proc = run_cli("--help", check=True)
    for cmd in ("data", "train", "eval", "demo"):
        assert cmd in proc.stdout


def test_train_help_explains_options():
    proc = run_cli("train", "--help", check=True)
    assert "--keep-epochs" in proc.stdout and "--resume" in proc.stdout and "torchrun" in proc.stdout


def test_unknown_command_exits_2():
    proc = run_cli("frobnicate")
    assert proc.returncode == 2 and "No such command" in proc.stderr


def test_a_group_alone_prints_its_help(capfd):
    from edgepick.cli import run

    for group in ("quantize", "calibrate", "data"):
        assert run([group]) == 0
        out, err = capfd.readouterr()
        assert out.startswith(f"Usage: edgepick {group}") and "Commands:" in out and err == ""


def test_a_library_parameter_is_named_by_the_commands_flag():
    """A ParameterError names the Python parameter; the error line names the command's flag: by name,
    by alias, a switch by its side, an argument by its metavar, another command's flag for a hint at
    it, and the Python name where the command line has no option for it."""
    from pathlib import Path

    from edgepick.cli import cli, command_line_message
    from edgepick.errors import ParameterError

    quantize = cli.commands["quantize"]
    static, hybrid, train = quantize.commands["static"], quantize.commands["hybrid"], cli.commands["train"]
    percentile = ParameterError("{percentile}: must be in (50, 100]", percentile=101.0)
    assert str(percentile) == "percentile=101.0: must be in (50, 100]"
    assert command_line_message(percentile, static) == "--percentile 101.0: must be in (50, 100]"
    drop = ParameterError("{max_drop_pp}: must be 0 or more", max_drop_pp=float("nan"))
    assert command_line_message(drop, static) == "--max-miou-drop nan: must be 0 or more"
    held = ParameterError("{out} already holds a run; pass {resume} or choose another {out:name}", out=Path("r"),
                          resume=True)
    assert str(held) == "out='r' already holds a run; pass resume=True or choose another out"
    assert command_line_message(held, train) == "--out r already holds a run; pass --resume or choose another --out"
    bits = ParameterError("{weight_bits}: not here", weight_bits="first-7")
    assert command_line_message(bits, static) == "--weight-bits first-7: not here"
    hint = ParameterError("train the float run with {keep_epochs}", keep_epochs=(12,))
    assert command_line_message(hint, hybrid) == "train the float run with --keep-epochs 12"
    synth = ParameterError("{out}: not empty", out="x")
    assert command_line_message(synth, cli.commands["data"].commands["synth"]) == "OUT x: not empty"
    gate = ParameterError("{hardswish_gate}: no option", hardswish_gate=False)
    assert command_line_message(gate, static) == "hardswish_gate=False: no option"


def test_choices_and_defaults_are_the_librarys():
    """The options offer the library's enums, in their order, and its defaults."""
    from edgepick.cli import cli
    from edgepick.quant.config import FREEZE_AT, CalibMethod, QuantConfig
    from edgepick.train.config import Device, TrainConfig

    quantize = cli.commands["quantize"]
    static = {p.name: p for p in quantize.commands["static"].params}
    assert list(static["calib_method"].type.choices) == [m.value for m in CalibMethod]
    assert static["percentile"].default == QuantConfig().percentile and static["calib_method"].default == "auto"
    train = {p.name: p for p in cli.commands["train"].params}
    assert list(train["device"].type.choices) == [m.value for m in Device] and train["device"].default == "auto"
    defaults = TrainConfig(data="d", out="r")
    assert (train["lr"].default, train["batch_size"].default) == (defaults.lr, defaults.batch_size)
    assert {p.name: p for p in quantize.commands["hybrid"].params}["freeze_at"].default == FREEZE_AT
