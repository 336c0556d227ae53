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
