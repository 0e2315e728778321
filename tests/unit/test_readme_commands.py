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


def test_readme_sets_up_in_a_venv_before_installing() -> None:
    """Debian's own python3 refuses ``pip install`` outside a venv (PEP 668): the venv comes before the install."""
    deps, venv, install = readme_block("Set up")
    assert deps == "./scripts/install-system-deps.sh"
    assert venv.startswith("python3 -m venv .venv") and ". .venv/bin/activate" in venv
    assert install == "python3 -m pip install -e '.[dev]'"


def test_the_system_deps_include_what_debian_needs_for_a_venv() -> None:
    assert "python3-venv" in (ROOT / "scripts" / "install-system-deps.sh").read_text().split()


def test_readme_shows_the_tool_installs_the_library_install_and_an_offline_install() -> None:
    text = (ROOT / "README.md").read_text()
    install = text[text.index("\n## Install") : text.index("\n## Set up")]
    for wanted in ("pipx install mrosd", "uv tool install mrosd", "python3 -m venv", "python3 -m pip install mrosd"):
        assert wanted in install
    assert "pip download -d wheelhouse" in install and "--no-index --find-links wheelhouse" in install


def test_the_systemd_unit_starts_the_mrosd_the_install_steps_put_there() -> None:
    """docs/daemon.md and README install into /opt/mrosd (a venv); the unit's ExecStart is that mrosd."""
    unit = (ROOT / "packaging" / "mrosd.service").read_text()
    (exec_start,) = [line for line in unit.splitlines() if line.startswith("ExecStart=")]
    binary = exec_start.removeprefix("ExecStart=").split()[0]
    venv = binary.removesuffix("/bin/mrosd")
    assert venv != binary
    for doc in ("README.md", "docs/daemon.md"):
        text = (ROOT / doc).read_text()
        assert f"python3 -m venv {venv}" in text, doc
        assert not re.search(r"^\s*sudo pip install", text, re.M), doc  # PEP 668 refuses it on Debian


def test_ci_tests_the_other_pythons_before_the_whole_suite() -> None:
    commands = ci_commands()
    (other,) = [c for c in commands if c.startswith("./scripts/test-other-pythons.sh")]
    assert other.split()[1:] == ["3.10", "3.12", "3.13"]
    assert commands.index(other) < len(commands) - 1


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
