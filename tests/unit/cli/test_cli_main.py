"""The `mros` surface: every command has --help with examples, completion works, exit codes are stable."""

from __future__ import annotations

import os
import subprocess
import sys

import click
import pytest
from click.testing import CliRunner
from mros_cli.main import SUBCOMMANDS, cli

OURS = ["topic", "param", "node", "service", "daemon"]


def _commands() -> list[list[str]]:
    out: list[list[str]] = []
    ctx = click.Context(cli)
    for noun in OURS:
        group = cli.get_command(ctx, noun)
        assert isinstance(group, click.Group)
        out.append([noun])
        out.extend([noun, verb] for verb in group.list_commands(ctx))
    return out


@pytest.mark.parametrize("argv", _commands(), ids=" ".join)
def test_every_command_has_help_with_an_example(argv: list[str]) -> None:
    result = CliRunner().invoke(cli, [*argv, "--help"])
    assert result.exit_code == 0, result.output
    assert "Example" in result.output


def test_the_root_help_lists_the_nouns_and_the_exit_codes() -> None:
    result = CliRunner().invoke(cli, ["--help"])
    assert result.exit_code == 0
    for noun in OURS:
        assert noun in result.output
    assert "Exit codes" in result.output


def test_every_noun_module_exposes_a_click_group_named_group() -> None:
    for noun in OURS:
        assert SUBCOMMANDS[noun] == f"mros_cli.{noun}"


def test_unknown_commands_and_missing_arguments_exit_with_code_2() -> None:
    assert CliRunner().invoke(cli, ["frobnicate"]).exit_code == 2
    assert CliRunner().invoke(cli, ["param", "get"]).exit_code == 2
    assert CliRunner().invoke(cli, ["topic", "pub", "/x"]).exit_code == 2


def test_an_unreachable_master_is_rosparams_error_plus_the_uri_and_exit_code_1() -> None:
    out = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", "http://127.0.0.1:9/", "param", "list"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert out.returncode == 1
    assert out.stdout == ""
    # rosparam list prints "ERROR: Unable to communicate with master!"; mros adds the URI and the reason
    first, blank, detail = out.stderr.splitlines()
    assert (first, blank) == ("ERROR: Unable to communicate with master!", "")
    assert detail.startswith("cannot reach the ROS master at http://127.0.0.1:9/")


def bash_complete(words: str, cword: int) -> list[str]:
    """What click's bash completion of ``mros`` answers for the command line ``words``."""
    env = dict(os.environ, _MROS_COMPLETE="bash_complete", COMP_WORDS=words, COMP_CWORD=str(cword))
    out = subprocess.run(
        [sys.executable, "-c", "from mros_cli.main import cli; cli(prog_name='mros')"],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    return out.stdout.splitlines()


def test_bash_completion_completes_nouns_and_verbs() -> None:
    assert "plain,topic" in bash_complete("mros to", 1)
    assert {"plain,get", "plain,set", "plain,dump"} <= set(bash_complete("mros param ", 2))
