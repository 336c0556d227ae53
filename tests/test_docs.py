"""The user's documents stay true: every `edgepick ...` line of the README names real commands and
options, every pointer into docs/contracts.md names a section that exists, and no document or
source file points outside the repository or tells how the repository was worked on."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import click
import pytest

from edgepick.cli import cli

REPO = Path(__file__).resolve().parents[1]
SOURCES = [*REPO.glob("edgepick/**/*.py"), *REPO.glob("benchmarks/*.py"), *REPO.glob("benchmarks/*.sh"),
           *REPO.glob("tests/**/*.py"), *REPO.glob("docs/*.md"), REPO / "README.md", REPO / "benchmarks" / "README.md",
           REPO / "Makefile"]
USER_FACING = [p for p in SOURCES if not p.is_relative_to(REPO / "tests")]


def readme_commands() -> list[list[str]]:
    """Each `edgepick ...` command in the code blocks of the README and its command tour (docs/cli.md),
    as tokens (continuations joined, comments dropped)."""
    blocks = [b for p in (REPO / "README.md", REPO / "docs" / "cli.md")
              for b in re.findall(r"```(?:sh|bash|console)?\n(.*?)```", p.read_text(), re.S)]
    text = "\n".join(blocks).replace("\\\n", " ")
    commands = []
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("edgepick ") or line.startswith("torchrun "):
            tokens = shlex.split(line, comments=True)
            if tokens[0] == "torchrun":
                tokens = ["edgepick", *tokens[tokens.index("edgepick") + 1:]]
            commands.append(tokens)
    return commands


def resolve(tokens: list[str]) -> tuple[click.Command, list[str]]:
    """The click command a token list names, and the tokens after it."""
    command: click.Command = cli
    rest = tokens[1:]
    while isinstance(command, click.Group) and rest and not rest[0].startswith("-"):
        name = command.resolve_command(click.Context(command), list(rest))[0]  # a group may have a default
        if name != rest[0]:
            rest = [name, *rest]
        sub = command.commands.get(rest[0])
        if sub is None:
            raise AssertionError(f"`{' '.join(tokens)}`: no command {rest[0]!r} under {command.name!r}")
        command, rest = sub, rest[1:]
    return command, rest


def test_readme_has_a_command_tour_and_the_users_sections():
    text = (REPO / "README.md").read_text()
    for heading in ("## Install", "## Quickstart", "## Command-line tour", "## Python API", "## Results"):
        assert heading in text, heading
    assert "docs/cli.md" in text and len(readme_commands()) >= 20
    for page in ("docs/cli.md", "docs/python-api.md", "docs/limits.md", "benchmarks/README.md"):
        assert f"({page}" in text, f"the README links {page}"
    assert len(text.splitlines()) <= 200, "the README says what edgepick is and links the rest (docs/)"


def test_architecture_lists_every_document():
    listed = (REPO / "docs" / "architecture.md").read_text()
    for page in (REPO / "docs").glob("*.md"):
        assert page.name == "architecture.md" or page.name in listed, f"docs/architecture.md does not list docs/{page.name}"


@pytest.mark.parametrize("tokens", readme_commands(), ids=lambda t: " ".join(t[:3]))
def test_readme_command_names_real_options(tokens):
    command, rest = resolve(tokens)
    known = {opt for p in command.params for opt in (*p.opts, *p.secondary_opts)} | {"--help", "-h"}
    for token in rest:
        if token.startswith("--"):
            assert token.split("=")[0] in known, f"`{' '.join(tokens)}`: {command.name} has no option {token}"


def test_readme_benchmark_scripts_exist():
    pages = (REPO / "README.md", *REPO.glob("docs/*.md"))
    scripts = {s for p in pages for s in re.findall(r"benchmarks/[a-z0-9_]+\.(?:py|sh)", p.read_text())}
    assert scripts
    for script in scripts:
        assert (REPO / script).is_file(), script


def _slug(heading: str) -> str:
    return re.sub(r"[^a-z0-9 -]", "", heading.lower()).strip().replace(" ", "-")


def test_every_contract_pointer_names_a_section_of_contracts_md():
    sections = {_slug(h) for h in re.findall(r"^##+ (.+)$", (REPO / "docs" / "contracts.md").read_text(), re.M)}
    pointers = {(p.relative_to(REPO), anchor) for p in SOURCES
                for anchor in re.findall(r"contracts\.md#([a-z0-9-]+)", p.read_text())}
    assert len(pointers) >= 20
    missing = sorted(str(p) + "#" + a for p, a in pointers if a not in sections)
    assert not missing, missing
    stale = [str(p.relative_to(REPO)) for p in SOURCES if re.search(r"[Cc]ontract[- ]3\.\d", p.read_text())]
    assert not stale, stale


# Words about how the repository was worked on, not about the product.
HISTORY = re.compile(r"\bsessions? \d+|\blease[ds]?\b|\bcall \d\b|\bour runs?\b|\.\./shared|"
                     r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b", re.I)


def test_documents_and_sources_hold_no_work_history():
    found = [f"{p.relative_to(REPO)}: {m.group(0)}" for p in USER_FACING for m in HISTORY.finditer(p.read_text())]
    assert not found, found


def test_result_files_named_in_the_documents_exist():
    named = {m.rstrip(".)") for p in (REPO / "README.md", *REPO.glob("docs/*.md"))
             for m in re.findall(r"benchmarks/results/[\w./-]+", p.read_text())}
    named |= {"benchmarks/" + m for m in re.findall(r"\((results/[^)]+)\)", (REPO / "benchmarks" / "README.md").read_text())}
    assert len(named) >= 10
    missing = sorted(m for m in named if not (REPO / m).exists())
    assert not missing, missing
