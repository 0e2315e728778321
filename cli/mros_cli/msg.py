"""``mros msg``: show, md5, list and generate message types (``rosmsg`` and ``genpy`` in one place).

``show`` prints what ``rosmsg show`` prints (constants first, nested types indented by two spaces,
``-r`` for the raw definition); ``md5`` the genmsg md5sum; ``list`` every type on the search path;
``gen`` writes importable Python packages (``OUT/<pkg>/msg``, ``OUT/<pkg>/srv``) from the same codegen
the runtime uses. The search path is mrosd's shipped definitions, then ``-I pkg:dir``, then
``$ROS_PACKAGE_PATH``, then the system share directories. No protocol logic lives here.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import click

from mrosd.errors import MsgNotFoundError
from mrosd.msg.spec import MsgSpec
from mrosd.msg.typestore import TypeStore, parse_include

INCLUDE_HELP = "Search PACKAGE:DIR for definitions (DIR is the package or its msg/ directory); repeatable."


def make_store(includes: Sequence[str]) -> TypeStore:
    """A type store with the command line's ``-I`` includes."""
    return TypeStore([parse_include(item) for item in includes])


def show_lines(spec: MsgSpec, store: TypeStore, indent: str = "") -> list[str]:
    """``rosmsg show``'s tree: constants, then fields, nested message fields indented by two spaces."""
    lines = [f"{indent}{c.type} {c.name}={c.text}" for c in spec.constants]
    for f in spec.fields:
        lines.append(f"{indent}{f.type} {f.name}")
        if not f.is_builtin:
            lines += show_lines(store.msg_spec(f.base), store, indent + "  ")
    return lines


include_option = click.option("-I", "--include", "includes", multiple=True, metavar="PACKAGE:DIR", help=INCLUDE_HELP)


@click.group(name="msg")
def group() -> None:
    """Message types: show, md5, list, gen.

    \b
    Examples:
      mros msg show geometry_msgs/PoseStamped
      mros msg md5 std_msgs/String
      mros msg list | grep sensor_msgs
      mros msg gen -I my_msgs:src/my_msgs -o build/py
    """


@group.command()
@click.argument("type_name", metavar="TYPE")
@click.option("-r", "--raw", is_flag=True, help="Print the definition text as written (comments included).")
@click.option("--full", is_flag=True, help="Print the full message_definition sent in TCPROS headers.")
@include_option
def show(type_name: str, raw: bool, full: bool, includes: tuple[str, ...]) -> None:
    """Show the fields of a message type (as rosmsg show).

    \b
    Example:
      mros msg show sensor_msgs/Image
      mros msg show -I my_msgs:src/my_msgs my_msgs/Coordinate
    """
    store = make_store(includes)
    spec = store.msg_spec(type_name)
    if full:
        click.echo(store.full_text(spec.full_name))
    elif raw:
        click.echo(spec.text, nl=not spec.text.endswith("\n"))
    else:
        click.echo("\n".join(show_lines(spec, store)))


@group.command()
@click.argument("type_names", metavar="TYPE...", nargs=-1, required=True)
@include_option
def md5(type_names: tuple[str, ...], includes: tuple[str, ...]) -> None:
    """Print the md5sum of message types (one per line, as rosmsg md5).

    \b
    Example:
      mros msg md5 std_msgs/String
    """
    store = make_store(includes)
    for name in type_names:
        click.echo(store.md5(name))


@group.command(name="list")
@click.argument("package", required=False)
@include_option
def list_(package: str | None, includes: tuple[str, ...]) -> None:
    """List every message type on the search path (optionally only PACKAGE's).

    \b
    Example:
      mros msg list geometry_msgs
    """
    for name in make_store(includes).list_types("msg"):
        if package is None or name.startswith(package + "/"):
            click.echo(name)


@group.command()
@click.argument("targets", metavar="[PACKAGE|TYPE]...", nargs=-1)
@include_option
@click.option(
    "-o",
    "--out",
    "out",
    type=click.Path(file_okay=False, path_type=Path),
    required=True,
    help="Directory to write the Python packages into.",
)
def gen(targets: tuple[str, ...], includes: tuple[str, ...], out: Path) -> None:
    """Generate importable Python modules (OUT/<pkg>/msg, OUT/<pkg>/srv).

    With no TARGETS, every message and service of every -I package is generated. Types from other
    packages that they use are embedded by definition, so OUT needs nothing else at import time.

    \b
    Example:
      mros msg gen -I my_msgs:src/my_msgs -o build/py
      PYTHONPATH=build/py python3 -c "from my_msgs.msg import Coordinate"
    """
    from mrosd.msg.generate import generate_packages

    store = make_store(includes)
    selected = list(targets) or sorted({pkg for pkg, _ in (parse_include(i) for i in includes)})
    if not selected:
        raise MsgNotFoundError("nothing to generate: give -I PACKAGE:DIR or PACKAGE/TYPE arguments")
    written = generate_packages(store, selected, out)
    for path in written:
        click.echo(str(path))
