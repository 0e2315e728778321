"""``mros srv``: show, md5 and list service types (as ``rossrv``), through the same search path as ``mros msg``."""

from __future__ import annotations

import click

from mros_cli.msg import include_option, make_store, show_type


@click.group(name="srv")
def group() -> None:
    """Service types: show, md5, list.

    \b
    Examples:
      mros srv show std_srvs/SetBool
      mros srv md5 std_srvs/Trigger
      mros srv list std_srvs
    """


@group.command()
@click.argument("type_name", metavar="TYPE")
@click.option("-r", "--raw", is_flag=True, help="Print the definition text as written (comments included).")
@include_option
def show(type_name: str, raw: bool, includes: tuple[str, ...]) -> None:
    """Show the request and response fields of a service type, byte for byte as rossrv show (short names too).

    \b
    Example:
      mros srv show std_srvs/SetBool
    """
    show_type(type_name, make_store(includes), "srv", raw)


@group.command()
@click.argument("type_names", metavar="TYPE...", nargs=-1, required=True)
@include_option
def md5(type_names: tuple[str, ...], includes: tuple[str, ...]) -> None:
    """Print the md5sum of service types (one per line, as rossrv md5).

    \b
    Example:
      mros srv md5 std_srvs/Trigger
    """
    store = make_store(includes)
    for name in type_names:
        click.echo(store.srv_md5(name))


@group.command(name="list")
@click.argument("package", required=False)
@include_option
def list_(package: str | None, includes: tuple[str, ...]) -> None:
    """List every service type on the search path (optionally only PACKAGE's).

    \b
    Example:
      mros srv list std_srvs
    """
    for name in make_store(includes).list_types("srv"):
        if package is None or name.startswith(package + "/"):
            click.echo(name)
