"""ROS graph names: validation, resolution and command-line remapping.

Pure functions plus ``NodeNames``, the one place that reads ``__name:=``, ``__ns:=``, ``from:=to`` remaps and
``ROS_NAMESPACE``. Rules follow the ROS 1 wiki (Names): ``/a`` is global, ``a`` is relative to the node's
namespace, ``~a`` is private to the node; remapping keys and values are resolved the same way, in the node's
namespace, before they are compared with resolved names.

Two rule sets live here, named apart:

- **strict** (``is_valid_name``, ``resolve``, ``namespace_of``, ``NodeNames``): a node's own names; an
  illegal name raises ``InvalidNameError``. ``script_resolve`` resolves a tool's command-line argument as
  rostopic does (relative to ``ROS_NAMESPACE``; the argument may carry a field path, checked where used).
- **lenient** (``lenient_resolve``, ``lenient_namespace_of``): rosgraph's resolution as rosmaster applies it
  to the names callers send (no validation, a relative caller id lives in ``/``). Only the master uses them;
  it checks characters itself, so its answers match rosmaster's.

``canonicalize`` is shared by both.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

from mrosd.errors import InvalidNameError

SEP = "/"
PRIV = "~"
_BASE = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_NAME = re.compile(r"^[~/]?([A-Za-z][A-Za-z0-9_]*)?(/[A-Za-z][A-Za-z0-9_]*)*/?$")


def is_valid_name(name: str) -> bool:
    """True for a legal graph name (global, relative or private); the empty string is not legal."""
    if name == SEP:
        return True
    return bool(name) and name != PRIV and bool(_NAME.match(name)) and "//" not in name


def canonicalize(name: str) -> str:
    """Collapse repeated slashes and drop a trailing one (the root stays ``/``)."""
    if not name or name == SEP or ("//" not in name and name[-1] != SEP):
        return name  # already canonical: the common case, answered without splitting
    parts = SEP.join(p for p in name.split(SEP) if p)
    return SEP + parts if name[0] == SEP else parts


def namespace_of(name: str) -> str:
    """The namespace a global name lives in: ``/a/b`` -> ``/a/``, ``/a`` -> ``/``."""
    name = canonicalize(name)
    if name in ("", SEP):
        return SEP
    head = name.rsplit(SEP, 1)[0]
    return head + SEP if head else SEP


def join(namespace: str, name: str) -> str:
    """Join a namespace and a relative name into one canonical name."""
    if name.startswith(SEP):
        return canonicalize(name)
    return canonicalize(namespace.rstrip(SEP) + SEP + name)


def resolve(name: str, node_name: str, remappings: Mapping[str, str] | None = None) -> str:
    """Resolve ``name`` for the node ``node_name`` (a global name such as ``/ns/talker``), then remap.

    Raises:
        InvalidNameError: the name is not a legal graph name.
    """
    if not is_valid_name(name):
        raise InvalidNameError(
            f"{name!r} is not a valid ROS name (letters, digits, '_' and '/'; parts start with a letter)"
        )
    if name.startswith(PRIV):
        resolved = canonicalize(node_name.rstrip(SEP) + SEP + name[1:])
    elif name.startswith(SEP):
        resolved = canonicalize(name)
    else:
        resolved = join(namespace_of(node_name), name)
    if remappings:
        return remappings.get(resolved, resolved)
    return resolved


# --- lenient rules: rosgraph's, as rosmaster applies them to callers' names ---------------------------


def lenient_namespace_of(name: str) -> str:
    """The namespace of a caller id as rosgraph computes it: ``/a/b`` -> ``/a/``; a relative or empty name
    lives in ``/``. No canonicalization (``/a//b`` -> ``/a//``), unlike the strict ``namespace_of``."""
    if not name:
        return SEP
    if name.endswith(SEP):
        name = name[:-1]
    return name[: name.rfind(SEP) + 1] or SEP


def lenient_resolve(name: str, caller_id: str) -> str:
    """Resolve ``name`` sent by the node ``caller_id`` as rosmaster does: global, ``~private`` or relative.

    Never raises: the empty name is the caller's namespace, and nothing is validated (the master checks
    characters before it resolves). The strict rule for a node's own names is ``resolve``.
    """
    if not name:
        return lenient_namespace_of(caller_id)
    name = canonicalize(name)
    if name[0] == SEP:
        return name
    if name[0] == PRIV:
        return canonicalize(caller_id + SEP + name[1:])
    return lenient_namespace_of(caller_id) + name


# --- strict rules for command-line tools --------------------------------------------------------------


def script_resolve(name: str, script: str, environ: Mapping[str, str] | None = None) -> str:
    """A name typed on a command-line tool's command line, resolved as rostopic/rosparam/rosservice do.

    Relative names are relative to ``ROS_NAMESPACE`` (default ``/``), ``~name`` is private to the tool
    (``/<namespace>/<script>/name``), the empty name is the namespace itself. No validation: a tool's
    argument may carry a field path (``/odom/pose/points[0]``) that is checked where it is used.
    """
    env = os.environ if environ is None else environ
    namespace = canonicalize(SEP + (env.get("ROS_NAMESPACE") or SEP).lstrip(SEP)) or SEP
    if not name:
        return namespace
    if name.startswith(PRIV):
        return join(join(namespace, script), name[1:]) if name != PRIV else join(namespace, script)
    return join(namespace, name)


def parse_argv(argv: Sequence[str]) -> tuple[dict[str, str], dict[str, str], list[str]]:
    """Split ``argv`` into (special ``__key`` args, ``from:=to`` remaps, everything else).

    ``_param:=value`` private-parameter arguments are neither remaps nor special; they are ignored here.
    """
    special: dict[str, str] = {}
    remaps: dict[str, str] = {}
    rest: list[str] = []
    for arg in argv:
        if ":=" not in arg:
            rest.append(arg)
            continue
        src, _, dst = arg.partition(":=")
        if src.startswith("__"):
            special[src] = dst
        elif src.startswith("_"):
            continue
        elif src and dst:
            remaps[src] = dst
    return special, remaps, rest


@dataclass(frozen=True)
class NodeNames:
    """A node's resolved identity: full name, namespace and resolved remappings."""

    name: str
    namespace: str
    remappings: dict[str, str] = field(default_factory=dict)

    @classmethod
    def from_argv(
        cls, name: str, argv: Sequence[str] | None = None, environ: Mapping[str, str] | None = None
    ) -> NodeNames:
        """Resolve a node's name from its base name, ``__name:=``, ``__ns:=`` and ``ROS_NAMESPACE``.

        Raises:
            InvalidNameError: the node name, namespace or a remapping is not a legal name.
        """
        env = os.environ if environ is None else environ
        special, remaps, _ = parse_argv(argv or ())
        name = special.get("__name", name)
        ns = special.get("__ns", env.get("ROS_NAMESPACE", SEP)) or SEP
        if not is_valid_name(ns) or ns.startswith(PRIV):
            raise InvalidNameError(f"namespace {ns!r} is not a valid ROS namespace")
        if not ns.startswith(SEP):
            ns = SEP + ns
        ns = canonicalize(ns)
        if not name or name.startswith(PRIV) or not is_valid_name(name):
            raise InvalidNameError(f"node name {name!r} is not a valid ROS name")
        full = canonicalize(name) if name.startswith(SEP) else join(ns, name)
        resolved: dict[str, str] = {}
        for src, dst in remaps.items():
            resolved[resolve(src, full)] = resolve(dst, full)
        return cls(name=full, namespace=namespace_of(full), remappings=resolved)

    def resolve(self, name: str) -> str:
        """Resolve a topic/service/param name for this node, remappings applied."""
        return resolve(name, self.name, self.remappings)
