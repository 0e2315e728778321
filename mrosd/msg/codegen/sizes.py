"""Names, type tables and wire sizes of message specs: the facts every emitter consults."""

from __future__ import annotations

import keyword
import struct
from collections.abc import Callable

from mrosd.msg.layout import Layouts, builtin_size
from mrosd.msg.spec import PRIMITIVE_FORMATS, MsgSpec

Lookup = Callable[[str], MsgSpec]

BYTE_TYPES = ("uint8", "char")
TIME_FORMATS = {"time": "I", "duration": "i"}
PY_SCALARS = {"bool": "bool", "float32": "float", "float64": "float", "string": "str"}


def symbol(type_name: str) -> str:
    """The identifier generated code uses for a message class (``pkg/Type`` -> ``_T_pkg__Type``)."""
    return "_T_" + type_name.replace("/", "__")


def attribute_name(field_name: str) -> str:
    """The Python attribute of a field: genpy's rule appends ``_`` to keywords and ``self``."""
    return field_name + "_" if keyword.iskeyword(field_name) or field_name == "self" else field_name


def class_name(spec: MsgSpec) -> str:
    """The Python class name of a message (its short name)."""
    return spec.short_name


def min_size(spec: MsgSpec, lookup: Lookup) -> int:
    """The smallest number of bytes a serialized ``spec`` can take."""
    total = 0
    for f in spec.fields:
        item = element_min_size(f.base, lookup)
        if not f.is_array:
            total += item
        elif f.length is None:
            total += 4
        else:
            total += item * f.length
    return total


def element_min_size(base: str, lookup: Lookup) -> int:
    size = builtin_size(base)
    if size is not None:
        return size
    if base == "string":
        return 4
    return min_size(lookup(base), lookup)


def fixed_size(spec: MsgSpec, lookup: Lookup) -> int | None:
    """The serialized size if every field has a fixed size, else None (from the type's one layout walk)."""
    return Layouts(lookup).of(spec).fixed


def is_flat(spec: MsgSpec) -> bool:
    """True if every field is a primitive scalar (so ``Struct.iter_unpack`` yields constructor arguments)."""
    return bool(spec.fields) and all(not f.is_array and f.base in PRIMITIVE_FORMATS for f in spec.fields)


def fmt_size(fmt: str) -> int:
    return struct.calcsize("<" + fmt)
