"""Bounds on what a message definition may cost before any code is generated for it.

A definition is text from a peer (a TCPROS header, a Foxglove schema, a bag, a Zenoh announcement), and a
few lines can describe a type whose expansion is exponential: ``d`` types each holding two fields of the
next expand to ``2**d`` leaves, so 1.5 KB of text described 16,000 fields. Every route that turns a
definition into a class goes through ``mrosd.msg.loader``, which calls ``check`` first; a type over a bound
is refused with ``MsgTooComplexError`` naming it.

The numbers come from real types (``python -m mrosd.msg.bounds`` prints the largest ones on this machine):
the 180 message and service types of Debian's ROS packages and mrosd's shipped definitions peak at 98
expanded fields (visualization_msgs/InteractiveMarkerUpdate), nesting depth 7 (nav_msgs/GetMapAction) and a
10.6 KB full definition (InteractiveMarkerUpdate). Larger public types exist (MoveIt's planning scene and
motion-plan requests are the usual examples), so the bounds leave a margin of about 20x on each number,
and ``MAX_SOURCE_CHARS`` bounds the worst single compile (one class with thousands of fields of its own).
"""

from __future__ import annotations

from collections.abc import Callable

from mrosd.errors import MsgError, MsgTooComplexError
from mrosd.msg.spec import MsgSpec

Lookup = Callable[[str], MsgSpec]

#: Fields of a type with every nested message expanded (an array of messages counts its element once, as
#: the generated code holds one copy of the element's fields in its loop). Debian's largest: 98.
MAX_FIELDS = 2048
#: Message types nested in one another (a type of builtin fields only has depth 1). Debian's deepest: 7.
MAX_DEPTH = 32
#: Characters of the generated source of one class. ``compile()`` holds the GIL for a whole class, at 0.6 to
#: 1.9 us a character here (strings and time fields cost most), so this bounds how long a worker thread's
#: compile can keep the event loop waiting: about 0.5 s at worst. Debian's largest class is 28.6 K characters
#: (InteractiveMarkerUpdate, fully inlined).
MAX_SOURCE_CHARS = 256_000
#: Characters of one message_definition (the type and every type it includes). Debian's longest: 10.6 KB.
MAX_DEFINITION_CHARS = 256 * 1024


class Measure:
    """Expanded field count and depth of types resolved through one lookup, each type measured once."""

    def __init__(self, lookup: Lookup) -> None:
        self.lookup = lookup
        self._sizes: dict[str, tuple[int, int]] = {}

    def size(self, name: str, _active: tuple[str, ...] = ()) -> tuple[int, int]:
        """(expanded field count, depth) of the type ``name``; stops counting past the bounds.

        Raises:
            MsgError: the type contains itself.
            MsgTooComplexError: nested deeper than ``MAX_DEPTH``.
        """
        got = self._sizes.get(name)
        if got is not None:
            return got
        if name in _active:
            chain = " -> ".join([*_active, name])
            raise MsgError(f"recursive message type: {chain} (a message cannot contain itself)")
        if len(_active) >= MAX_DEPTH:
            raise MsgTooComplexError(f"{_active[0]}: message types nested deeper than {MAX_DEPTH} (at {name})")
        fields, depth = 0, 0
        for f in self.lookup(name).fields:
            fields += 1
            if not f.is_builtin:
                sub_fields, sub_depth = self.size(f.base, (*_active, name))
                fields += sub_fields
                depth = max(depth, sub_depth)
            fields = min(fields, MAX_FIELDS + 1)  # past the bound the exact count no longer matters
        got = self._sizes[name] = (fields, depth + 1)
        return got

    def fields(self, name: str) -> int:
        """The expanded field count of ``name`` (capped at ``MAX_FIELDS + 1``)."""
        return self.size(name)[0]


def check(spec: MsgSpec, lookup: Lookup, measure: Measure | None = None) -> None:
    """Refuse ``spec`` if its expansion is over ``MAX_FIELDS`` fields or ``MAX_DEPTH`` levels.

    Raises:
        MsgTooComplexError: over a bound (the message names the type and the bound).
        MsgError: the type contains itself.
        MsgNotFoundError: it uses a type ``lookup`` does not know.
    """
    measure = measure or Measure(lookup)
    fields, depth = measure.size(spec.full_name)
    if fields > MAX_FIELDS:
        raise MsgTooComplexError(
            f"{spec.full_name}: more than {MAX_FIELDS} fields once its nested types are expanded (refused)"
        )
    if depth > MAX_DEPTH:  # a type measured before through a shorter chain
        raise MsgTooComplexError(f"{spec.full_name}: message types nested deeper than {MAX_DEPTH}")


def check_source(name: str, source: str) -> None:
    """Refuse generated source longer than ``MAX_SOURCE_CHARS`` before it is compiled.

    Raises:
        MsgTooComplexError: it is longer (a type of thousands of strings or arrays of its own).
    """
    if len(source) > MAX_SOURCE_CHARS:
        raise MsgTooComplexError(
            f"{name}: its generated code ({len(source)} characters) exceeds {MAX_SOURCE_CHARS} (refused)"
        )


def check_definition(name: str, definition: str) -> None:
    """Refuse a message_definition longer than ``MAX_DEFINITION_CHARS`` before it is parsed.

    Raises:
        MsgTooComplexError: it is longer.
    """
    if len(definition) > MAX_DEFINITION_CHARS:
        raise MsgTooComplexError(
            f"{name}: message_definition of {len(definition)} characters exceeds {MAX_DEFINITION_CHARS}"
        )


def _largest() -> None:  # pragma: no cover - a report for choosing the bounds, not used at run time
    from mrosd.msg.typestore import TypeStore

    store = TypeStore()
    measure = Measure(store.msg_spec)
    rows = []
    names = store.list_types("msg")
    names += [f"{s}{half}" for s in store.list_types("srv") for half in ("Request", "Response")]
    for name in names:
        try:
            fields, depth = measure.size(name)
            rows.append((fields, depth, len(store.full_text(name)), name))
        except MsgError as exc:
            print(f"{name}: {exc}")
    print(f"{len(rows)} types")
    for label, index in (("expanded fields", 0), ("depth", 1), ("full text chars", 2)):
        top = sorted(rows, key=lambda r: r[index])[-3:]
        print(f"largest by {label}: " + ", ".join(f"{r[3]} ({r[index]})" for r in reversed(top)))


if __name__ == "__main__":  # pragma: no cover
    _largest()
