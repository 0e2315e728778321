"""``mros param``: the parameter server, printed and parsed as ``rosparam`` does.

Values are YAML on the command line and on output (``rosparam get`` prints ``yaml.dump`` of the value without
the ``...`` end marker); ``set`` of a dictionary updates key by key; ``list`` prints sorted names under a
namespace; ``dump``/``load`` read and write YAML files (``-`` is stdin/stdout), honouring ``_ns`` in loaded
documents. Names are resolved against ``$ROS_NAMESPACE`` as rosparam does.
"""

from __future__ import annotations

import re
import sys
from typing import TYPE_CHECKING, Any

import click
import yaml

from mros_cli.main import master_client, resolve_name, run
from mrosd.errors import MrosError
from mrosd.names import join

if TYPE_CHECKING:
    from mrosd.master.client import MasterClient

#: rosparam's key for a document's namespace in a loaded file.
NS_KEY = "_ns"
#: XML-RPC's int is 32-bit signed; rosparam refuses larger values the same way.
MAX_XMLRPC_INT = 2**31 - 1


def yaml_text(value: Any) -> str:
    """rosparam's output for a value: ``yaml.dump`` without the ``...`` document end marker."""
    dump = yaml.dump(_plain(value))
    if dump.endswith("\n...\n"):
        dump = dump[:-5]
    return dump


def _plain(value: Any) -> Any:
    # xmlrpc.client.Binary and DateTime are what rosparam sees too; keep the bytes readable.
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_plain(v) for v in value]
    data = getattr(value, "data", None)
    if isinstance(data, bytes):
        return data
    return value


def _check(value: Any, where: str) -> Any:
    """Values the XML-RPC parameter server can hold; a clear error naming the bad key otherwise."""
    if isinstance(value, bool) or value is None:
        if value is None:
            raise MrosError(f"parameter {where} has no value (YAML null cannot be stored)")
        return value
    if isinstance(value, int) and not -MAX_XMLRPC_INT - 1 <= value <= MAX_XMLRPC_INT:
        raise MrosError(f"parameter {where}: {value} does not fit the parameter server's 32-bit integers")
    if isinstance(value, dict):
        for key in value:
            if not isinstance(key, str):
                raise MrosError(f"parameter {where}: dictionary keys must be strings, got {key!r}")
            _check(value[key], join(where, key))
    if isinstance(value, list):
        for i, item in enumerate(value):
            _check(item, f"{where}[{i}]")
    return value


async def set_value(master: MasterClient, name: str, value: Any) -> None:
    """Set a value; a dictionary is an update of its keys, as rosparam set/load do."""
    if isinstance(value, dict) and name != "/":
        for key, item in value.items():
            await set_value(master, join(name, key), item)
        return
    await master.set_param(name, value)


@click.group(name="param")
def group() -> None:
    """Get, set, list, delete, dump and load parameters (like rosparam).

    \b
    Examples:
      mros param set /rate 10
      mros param set /pid "{p: 1.0, i: 0.1}"
      mros param get /pid
      mros param list /pid
      mros param dump params.yaml /pid
      mros param load params.yaml /robot
      mros param delete /pid
    """


def pretty_text(value: Any, indent: str = "") -> str:
    """``rosparam get -p``'s text for a dictionary: sorted keys, nested dicts indented, multi-line strings as
    ``key: |`` blocks, other values as YAML after the key (readable, and like rosparam's, not YAML-safe)."""
    out: list[str] = []
    for key in sorted(value):
        item = value[key]
        if type(item) is dict:
            out.append(f"{indent}{key}:\n{pretty_text(item, indent + '  ')}")
        elif type(item) is str:
            if "\n" in item:
                out.append(f"{indent}{key}: |\n" + "".join(f"{indent}  {line}\n" for line in item.split("\n")))
            else:
                out.append(f"{indent}{key}: {item}\n")
        else:
            dump = yaml.dump(_plain(item))
            if dump.endswith("\n...\n"):
                dump = dump[:-4]
            out.append(f"{indent}{key}: {dump}")
    return "".join(out)


@group.command()
@click.argument("name")
@click.option("-p", "pretty", is_flag=True, help="Pretty-print a dictionary or string (readable, not YAML-safe).")
def get(name: str, pretty: bool) -> None:
    """Print a parameter (or a namespace as a dictionary) as YAML.

    \b
    Examples:
      mros param get /robot_description
      mros param get -p /robot
    """

    async def main() -> Any:
        async with master_client() as master:
            return await master.get_param(resolve_name(name))

    value = run(main())
    if pretty and type(value) is dict:
        sys.stdout.write(pretty_text(value))
    elif pretty and type(value) is str:
        sys.stdout.write(value + "\n")
    else:
        sys.stdout.write(yaml_text(value) + "\n")


class NegativeNumbersCommand(click.Command):
    """Lets ``mros param set /x -7`` pass ``-7`` as the value, as rosparam does, instead of an option."""

    VALUE_OPTIONS = frozenset({"-t", "--textfile", "-b", "--binfile"})

    def parse_args(self, ctx: click.Context, args: list[str]) -> list[str]:
        options: list[str] = []
        positional: list[str] = []
        it = iter(args)
        for arg in it:
            if arg == "--":
                positional.extend(it)
                break
            if NEGATIVE_NUMBER.match(arg) or not arg.startswith("-") or arg == "-":
                positional.append(arg)
            else:
                options.append(arg)
                if arg in self.VALUE_OPTIONS:
                    options.append(next(it, ""))
        return super().parse_args(ctx, [*options, "--", *positional] if positional else options)


NEGATIVE_NUMBER = re.compile(r"^-(\d|\.\d|inf|\.inf)", re.IGNORECASE)


@group.command(name="set", cls=NegativeNumbersCommand)
@click.argument("name")
@click.argument("value", required=False)
@click.option("-t", "--textfile", type=click.File("r"), help="Use the text of this file as the string value.")
@click.option("-b", "--binfile", type=click.File("rb"), help="Use the bytes of this file as a binary value.")
def set_(name: str, value: str | None, textfile: Any, binfile: Any) -> None:
    """Set a parameter from a YAML value (a dictionary updates its keys).

    \b
    Examples:
      mros param set /rate 10
      mros param set /name "'42'"        # the string 42
      mros param set /gains "[1.0, 2.5]"
      mros param set -t robot.urdf /robot_description
    """
    import xmlrpc.client

    if textfile is not None and binfile is not None:
        raise click.UsageError("give only one of --textfile and --binfile")
    parsed: Any
    if textfile is not None:
        parsed = textfile.read()
    elif binfile is not None:
        parsed = xmlrpc.client.Binary(binfile.read())
    elif value is None:
        raise click.UsageError("missing VALUE (or --textfile/--binfile)")
    else:
        try:
            parsed = yaml.safe_load(value) if value != "" else ""
        except yaml.YAMLError as exc:
            raise MrosError(f"value is not valid YAML: {' '.join(str(exc).split())}") from exc
    resolved = resolve_name(name)
    if not isinstance(parsed, xmlrpc.client.Binary):
        _check(parsed, resolved)

    async def main() -> None:
        async with master_client() as master:
            await set_value(master, resolved, parsed)

    run(main())


@group.command(name="list")
@click.argument("namespace", required=False, default="/")
def list_(namespace: str) -> None:
    """List parameter names under a namespace (all by default), sorted.

    \b
    Example:
      mros param list /robot
    """
    ns = resolve_name(namespace)
    prefix = ns if ns.endswith("/") else ns + "/"

    async def main() -> list[str]:
        async with master_client() as master:
            names: list[str] = await master.get_param_names()
            return names

    names = sorted(n for n in run(main()) if n.startswith(prefix))
    click.echo("\n".join(names))


@group.command()
@click.argument("name")
def delete(name: str) -> None:
    """Delete a parameter or a whole namespace (``/`` empties the server).

    \b
    Example:
      mros param delete /pid
    """
    resolved = resolve_name(name)

    async def main() -> None:
        async with master_client() as master:
            if resolved == "/":
                await master.set_param("/", {})
            else:
                await master.delete_param(resolved)

    run(main())


@group.command()
@click.argument("file", type=click.Path(dir_okay=False, allow_dash=True))
@click.argument("namespace", required=False, default="/")
def dump(file: str, namespace: str) -> None:
    """Write a namespace (default: everything) to a YAML file, ``-`` for stdout.

    \b
    Example:
      mros param dump params.yaml /robot
    """

    async def main() -> Any:
        async with master_client() as master:
            return await master.get_param(resolve_name(namespace))

    tree = _plain(run(main()))
    if file == "-":
        yaml.dump(tree, sys.stdout)
    else:
        try:
            with open(file, "w", encoding="utf-8") as out:
                yaml.dump(tree, out)
        except OSError as exc:
            raise MrosError(f"cannot write {file}: {exc.strerror or exc}") from exc


@group.command()
@click.argument("file", type=click.Path(dir_okay=False, allow_dash=True))
@click.argument("namespace", required=False)
def load(file: str, namespace: str | None) -> None:
    """Load parameters from a YAML file (``-`` for stdin) into a namespace.

    Each YAML document may name its own namespace with ``_ns``.

    \b
    Example:
      mros param load params.yaml /robot
    """
    try:
        if file == "-":
            text = sys.stdin.read()
        else:
            with open(file, encoding="utf-8") as src:
                text = src.read()
    except OSError as exc:
        raise MrosError(f"cannot read {file}: {exc.strerror or exc}") from exc
    try:
        docs = [d for d in yaml.safe_load_all(text) if d is not None]
    except yaml.YAMLError as exc:
        raise MrosError(f"{file} is not valid YAML: {' '.join(str(exc).split())}") from exc
    default_ns = resolve_name(namespace) if namespace else resolve_name("")
    plan: list[tuple[str, Any]] = []
    for raw in docs:
        ns = default_ns
        doc = raw
        if isinstance(raw, dict) and NS_KEY in raw:
            doc = dict(raw)
            ns = join(default_ns, str(doc.pop(NS_KEY)))
        if ns == "/" and not isinstance(doc, dict):
            raise MrosError(f"{file}: the global namespace / can only be set to a dictionary")
        plan.append((ns, _check(doc, ns)))

    async def main() -> None:
        async with master_client() as master:
            for ns, doc in plan:
                if ns == "/" and isinstance(doc, dict):
                    for key, item in doc.items():
                        await set_value(master, join("/", key), item)
                else:
                    await set_value(master, ns, doc)

    run(main())
