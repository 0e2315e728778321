"""``mros msg``: show, md5, list and generate message types (``rosmsg`` and ``genpy`` in one place).

``show`` prints what ``rosmsg show`` prints, byte for byte (constants first, nested types indented by two
spaces, a blank line at the end, ``-r`` for the raw definition, short names searched in every package);
``md5`` the genmsg md5sum; ``list`` every type on the search path; ``gen`` writes importable Python packages
(``OUT/<pkg>/msg``, ``OUT/<pkg>/srv``) from the same codegen the runtime uses. The search path is mrosd's
shipped definitions, then ``-I pkg:dir``, then ``$ROS_PACKAGE_PATH``, then the system share directories.
No protocol logic lives here.
"""

from __future__ import annotations

import glob
import os
import re
import sys
from collections.abc import Sequence
from pathlib import Path

import click

from mrosd.errors import MsgNotFoundError
from mrosd.msg.spec import MsgSpec
from mrosd.msg.typestore import BUILTIN_DIR, MAX_PACKAGE_DEPTH, TypeStore, parse_include

#: A package.xml's name, as the type store reads it.
_PACKAGE_NAME = re.compile(r"<name>\s*([^<\s]+)\s*</name>")

INCLUDE_HELP = "Search PACKAGE:DIR for definitions (DIR is the package or its msg/ directory); repeatable."


def make_store(includes: Sequence[str]) -> TypeStore:
    """A type store with the command line's ``-I`` includes."""
    return TypeStore([parse_include(item) for item in includes])


def package_order(store: TypeStore) -> list[str]:
    """Package names in the order rosmsg searches them for a short type name (rospack's crawl order).

    rospack crawls ``/usr/share`` first, then ``$ROS_PACKAGE_PATH`` from its last entry to its first, each
    in directory order, so that is the order here too; mrosd's own definitions and ``-I`` packages that no
    crawl found come after, sorted.
    """
    order: dict[str, None] = {}
    roots: list[tuple[Path, int]] = []
    for pattern in store.system_dirs:
        roots += [(Path(root), 1) for root in sorted(glob.glob(pattern))]
    roots += [(Path(root), MAX_PACKAGE_DEPTH) for root in reversed(store.ros_package_path.split(os.pathsep)) if root]
    for root, depth in roots:
        for name in _crawl(root, depth):
            order[name] = None
    extra = {pkg for pkg, _dir in store.includes}
    if store.builtin and BUILTIN_DIR.is_dir():
        extra |= {p.name for p in BUILTIN_DIR.iterdir() if p.is_dir()}
    for name in sorted(extra - order.keys()):
        order[name] = None
    return list(order)


def _crawl(root: Path, depth: int) -> list[str]:
    """Package names under ``root`` in directory order, not below another package or a CATKIN_IGNORE."""
    try:
        entries = list(os.scandir(root))
    except OSError:
        return []
    names: list[str] = []
    for entry in entries:
        try:
            if not entry.is_dir() or entry.name.startswith("."):
                continue
            manifest = Path(entry.path) / "package.xml"
            if manifest.is_file():
                match = _PACKAGE_NAME.search(manifest.read_text(encoding="utf-8", errors="replace"))
                names.append(match.group(1) if match else entry.name)
            elif depth > 1 and not (Path(entry.path) / "CATKIN_IGNORE").exists():
                names += _crawl(Path(entry.path), depth - 1)
        except OSError:
            continue
    return names


def find_short(store: TypeStore, short: str, kind: str) -> list[str]:
    """Every ``pkg/short`` of ``kind`` on the search path, in rosmsg's order (``Twist`` -> geometry_msgs/Twist)."""
    return [
        f"{pkg}/{short}"
        for pkg in package_order(store)
        if any((d / f"{short}.{kind}").is_file() for d in store.package_dirs(pkg, kind))
    ]


def show_text(name: str, store: TypeStore, kind: str, raw: bool) -> str:
    """What ``rosmsg show``/``rossrv show`` print for a full name (the final blank line included)."""
    if kind == "srv":
        srv = store.srv_spec(name)
        if raw:
            return srv.text + "\n"
        return _tree(srv.request, store) + "---\n" + _tree(srv.response, store) + "\n"
    spec = store.msg_spec(name)
    return (spec.text if raw else _tree(spec, store)) + "\n"


def _tree(spec: MsgSpec, store: TypeStore) -> str:
    return "".join(line + "\n" for line in show_lines(spec, store))


def show_type(type_name: str, store: TypeStore, kind: str, raw: bool) -> None:
    """Print a type as rosmsg/rossrv show: a short name prints every match under a ``[pkg/Type]:`` line."""
    name = type_name.strip()
    if name.endswith("." + kind):
        name = name[: -len(kind) - 1]
    if "/" in name:
        click.echo(show_text(name, store, kind, raw), nl=False)
        return
    found = find_short(store, name, kind)
    if not found:
        click.echo(f"Could not find {kind} '{name}'", err=True)
        sys.exit(1)
    for full in found:
        click.echo(f"[{full}]:\n" + show_text(full, store, kind, raw), nl=False)


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
    """Show the fields of a message type, byte for byte as rosmsg show.

    A name without a package (``Twist``) is looked up in every package, and each match is shown under a
    ``[package/Type]:`` line, as rosmsg does.

    \b
    Example:
      mros msg show sensor_msgs/Image
      mros msg show Twist
      mros msg show -I my_msgs:src/my_msgs my_msgs/Coordinate
    """
    store = make_store(includes)
    if full:
        click.echo(store.full_text(store.msg_spec(type_name).full_name))
    else:
        show_type(type_name, store, "msg", raw)


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
