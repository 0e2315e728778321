"""genmsg-exact md5sums and genpy-exact full definition texts (``message_definition``).

Rules (checked against Debian's genmsg for every shipped .msg/.srv, see tests/unit/msg):
- md5 text: each constant as ``type name=text`` (in definition order), then each field as ``type name``
  for builtins (the type exactly as stored, array suffix included) or ``<md5 of element type> name`` for
  messages (the array suffix is dropped); lines joined by newlines, surrounding whitespace stripped.
- service md5: one md5 over the request text followed directly by the response text.
- full text: the type's own text, then for every dependency (depth-first in field order, first occurrence
  wins) a line of 80 '=', ``MSG: pkg/Type`` and that type's text; the final newline is dropped.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable

from mrosd.errors import MsgError
from mrosd.msg.parser import DEFINITION_SEPARATOR
from mrosd.msg.spec import MsgSpec, SrvSpec

#: Resolves a fully-qualified type name to its spec (raises MsgNotFoundError when unknown).
Lookup = Callable[[str], MsgSpec]


def md5_text(spec: MsgSpec, lookup: Lookup, cache: dict[str, str] | None = None, _active: tuple[str, ...] = ()) -> str:
    """The canonical text genmsg hashes for ``spec``.

    Raises:
        MsgError: the type contains itself (directly or through other types).
    """
    lines = [f"{c.type} {c.name}={c.text}" for c in spec.constants]
    for field in spec.fields:
        if field.is_builtin:
            lines.append(f"{field.type} {field.name}")
        else:
            lines.append(f"{compute_md5(lookup(field.base), lookup, cache, _active)} {field.name}")
    return "\n".join(lines).strip()


def compute_md5(
    spec: MsgSpec, lookup: Lookup, cache: dict[str, str] | None = None, _active: tuple[str, ...] = ()
) -> str:
    """The md5sum of a message type, as genmsg computes it (``cache`` maps type name -> md5).

    Raises:
        MsgError: the type contains itself (directly or through other types).
    """
    if cache is not None:
        hit = cache.get(spec.full_name)
        if hit is not None:
            return hit
    if spec.full_name in _active:
        chain = " -> ".join([*_active, spec.full_name])
        raise MsgError(f"recursive message type: {chain} (a message cannot contain itself)")
    digest = hashlib.md5(md5_text(spec, lookup, cache, (*_active, spec.full_name)).encode()).hexdigest()
    if cache is not None:
        cache[spec.full_name] = digest
    return digest


def compute_srv_md5(spec: SrvSpec, lookup: Lookup, cache: dict[str, str] | None = None) -> str:
    """The md5sum of a service type: request text and response text hashed together."""
    hasher = hashlib.md5()
    hasher.update(md5_text(spec.request, lookup, cache).encode())
    hasher.update(md5_text(spec.response, lookup, cache).encode())
    return hasher.hexdigest()


def all_dependencies(spec: MsgSpec, lookup: Lookup) -> list[str]:
    """Every message type ``spec`` uses, depth-first in field order, each once (genpy's order)."""
    ordered: list[str] = []
    seen: set[str] = set()

    def walk(current: MsgSpec) -> None:
        for name in current.dependencies():
            # A type seen before had its own dependencies listed right after it: skipping it keeps genpy's order.
            if name not in seen:
                seen.add(name)
                ordered.append(name)
                walk(lookup(name))

    walk(spec)
    return ordered


def full_text(spec: MsgSpec, lookup: Lookup) -> str:
    """The message_definition genpy generates (``_full_text``) and TCPROS headers carry."""
    parts = [spec.text, "\n"]
    for name in all_dependencies(spec, lookup):
        parts += [DEFINITION_SEPARATOR, "\n", f"MSG: {name}\n", lookup(name).text, "\n"]
    return "".join(parts)[:-1]
