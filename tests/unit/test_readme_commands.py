"""README.md's set-up and test commands are the ones `.ci/run` runs, character for character.

CI judges a submission by `.ci/run` on a clean clone; a user judges the project by the README. When the two
drift, CI proves a set-up nobody is told to run. These tests read both files and fail on any difference.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def readme_block(heading: str) -> list[str]:
    """The commands of the first ```sh block under ``## heading``, without their trailing comments."""
    text = (ROOT / "README.md").read_text()
    section = re.search(rf"^## {re.escape(heading)}\b.*?^```sh\n(.*?)^```", text, re.M | re.S)
    assert section, f"README.md has no ```sh block under '## {heading}'"
    commands = []
    for line in section.group(1).splitlines():
        command = re.sub(r"\s+#.*$", "", line).strip()
        if command:
            commands.append(command)
    return commands


def ci_commands() -> list[str]:
    """The commands `.ci/run` executes, in order (comments, `set` and `cd` left out)."""
    lines = (ROOT / ".ci" / "run").read_text().splitlines()
    return [line.strip() for line in lines if line.strip() and not line.lstrip().startswith(("#", "set ", "cd "))]


def test_readme_sets_up_with_two_commands() -> None:
    assert len(readme_block("Set up")) == 2


def test_ci_runs_the_readme_set_up_first_and_exactly() -> None:
    setup = readme_block("Set up")
    assert ci_commands()[: len(setup)] == setup


def test_ci_ends_with_the_readme_test_command() -> None:
    (test_command,) = readme_block("Test")
    assert ci_commands()[-1] == test_command


def test_ci_checks_lint_format_and_types_before_testing() -> None:
    commands = ci_commands()
    for check in ("python3 -m ruff check .", "python3 -m ruff format --check .", "python3 -m mypy"):
        assert check in commands
        assert commands.index(check) < len(commands) - 1


def test_ci_prints_the_tool_versions_it_ran_with() -> None:
    assert "python3 scripts/tool-versions.py" in ci_commands()
