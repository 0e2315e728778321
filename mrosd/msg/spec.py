"""The intermediate representation of .msg and .srv definitions, as frozen data.

The parser produces these, md5/full-text and codegen consume them; nothing here parses or does I/O.
Type names are stored the way genmsg stores them after loading: package-relative names are made
fully qualified (``Point`` in geometry_msgs -> ``geometry_msgs/Point``) and ``Header`` becomes
``std_msgs/Header``, while primitive names (including the deprecated ``byte``/``char``) stay as written,
because the md5 text repeats them verbatim.
"""

from __future__ import annotations

import msgspec

#: Primitive type -> (struct format character, size in bytes). ``string`` is not here (variable size);
#: ``time``/``duration`` are two 32-bit fields each. ``char`` is unsigned and ``byte`` signed, as in genpy.
PRIMITIVE_FORMATS: dict[str, tuple[str, int]] = {
    "bool": ("?", 1),
    "int8": ("b", 1),
    "uint8": ("B", 1),
    "byte": ("b", 1),
    "char": ("B", 1),
    "int16": ("h", 2),
    "uint16": ("H", 2),
    "int32": ("i", 4),
    "uint32": ("I", 4),
    "int64": ("q", 8),
    "uint64": ("Q", 8),
    "float32": ("f", 4),
    "float64": ("d", 8),
}

#: Integer type -> (lowest, highest) value, derived from the struct formats (lower case = signed).
INT_RANGES: dict[str, tuple[int, int]] = {
    name: ((-(2 ** (8 * size - 1)), 2 ** (8 * size - 1) - 1) if fmt.islower() else (0, 2 ** (8 * size) - 1))
    for name, (fmt, size) in PRIMITIVE_FORMATS.items()
    if fmt in "bBhHiIqQ"
}

#: Types allowed for constants (genmsg's PRIMITIVE_TYPES).
CONSTANT_TYPES = frozenset([*PRIMITIVE_FORMATS, "string"])

#: Every builtin type name: primitives, string, time and duration.
BUILTIN_TYPES = frozenset([*PRIMITIVE_FORMATS, "string", "time", "duration"])

HEADER = "Header"
HEADER_FULL_NAME = "std_msgs/Header"


class Field(msgspec.Struct, frozen=True, gc=False):
    """One field: ``type`` as genmsg stores it (``float64[9]``, ``geometry_msgs/Point[]``), split into parts."""

    name: str
    type: str
    base: str  #: the element type, resolved (``float64``, ``std_msgs/Header``)
    is_array: bool = False
    length: int | None = None  #: fixed array length, None for variable arrays and scalars
    line: int = 0  #: 1-based line of the definition, for error messages

    @property
    def is_builtin(self) -> bool:
        """True if the element type is a primitive, string, time or duration."""
        return self.base in BUILTIN_TYPES


class Constant(msgspec.Struct, frozen=True, gc=False):
    """A constant: ``value`` converted to Python, ``text`` as genmsg keeps it for the md5 text."""

    type: str
    name: str
    value: bool | int | float | str
    text: str


class MsgSpec(msgspec.Struct, frozen=True, gc=False):
    """A parsed message: fields and constants in definition order, and the definition text verbatim."""

    full_name: str  #: ``pkg/Type`` (or ``Type`` when there is no package context)
    fields: tuple[Field, ...]
    constants: tuple[Constant, ...]
    text: str
    file: str = "<string>"

    @property
    def package(self) -> str:
        """The package part of the name ('' when there is none)."""
        return self.full_name.rpartition("/")[0]

    @property
    def short_name(self) -> str:
        """The type name without its package."""
        return self.full_name.rpartition("/")[2]

    @property
    def has_header(self) -> bool:
        """genmsg's rule: the first field is ``std_msgs/Header header``."""
        return bool(self.fields) and self.fields[0].type == HEADER_FULL_NAME and self.fields[0].name == "header"

    def dependencies(self) -> list[str]:
        """Names of the message types used directly by fields, one per field (genmsg keeps duplicates)."""
        return [f.base for f in self.fields if not f.is_builtin]


class SrvSpec(msgspec.Struct, frozen=True, gc=False):
    """A parsed service: request and response messages (``pkg/TypeRequest``, ``pkg/TypeResponse``)."""

    full_name: str
    request: MsgSpec
    response: MsgSpec
    text: str
    file: str = "<string>"

    @property
    def package(self) -> str:
        """The package part of the name."""
        return self.full_name.rpartition("/")[0]

    @property
    def short_name(self) -> str:
        """The service name without its package."""
        return self.full_name.rpartition("/")[2]
