"""The root click group `mros`; each noun lives in its own module and is added here."""

from __future__ import annotations

import importlib
import importlib.util
import sys
from typing import Any

import click

from mrosd.errors import MrosError

#: noun -> module that defines a click group named ``group`` (imported lazily so `mros msg` never pays for
#: aiohttp and `mros topic` never pays for the codegen until it needs it).
SUBCOMMANDS = {
    "topic": "mros_cli.topic",
    "msg": "mros_cli.msg",
    "srv": "mros_cli.srv",
    "param": "mros_cli.param",
    "node": "mros_cli.node",
    "service": "mros_cli.service",
    "ixm": "mros_cli.ixm",
    "daemon": "mros_cli.daemon",
}


class LazyGroup(click.Group):
    """Imports each subcommand module only when it is used."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return sorted(name for name, mod in SUBCOMMANDS.items() if importlib.util.find_spec(mod) is not None)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        module_name = SUBCOMMANDS.get(cmd_name)
        if module_name is None or importlib.util.find_spec(module_name) is None:
            return None
        module = importlib.import_module(module_name)
        command: click.Command = module.group
        return command

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except MrosError as exc:
            click.echo(f"mros: error: {exc}", err=True)
            sys.exit(1)


@click.group(cls=LazyGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="mrosd")
def cli() -> None:
    """mros: talk to a ROS 1 graph (topics, messages, parameters, nodes, services, IXM).

    \b
    Examples:
      mros topic list -v
      mros topic echo /chatter -n 1
      mros msg show geometry_msgs/PoseStamped
      mros param get /robot_description
    """
