"""The one generator: a MsgSpec becomes Python source for a msgspec Struct with inlined (de)serializers.

Used two ways: ``loader.py`` compiles the source for runtime classes, and ``mros msg gen`` writes it to
files. The source refers to other message classes by symbol (``_T_std_msgs__Header``); the caller binds
those symbols (a namespace at runtime, imports in files).

Speed comes from flattening: nested messages are inlined, consecutive fixed-size fields (through nested
messages, time/duration, and the uint32 length prefix of the next string or array) are packed or unpacked
with one precompiled ``struct.Struct``; uint8[] is copied as bytes (or viewed when large), numeric
variable arrays go through ``array.array`` without per-element objects, flat fixed-size message arrays
through ``Struct.iter_unpack``. Decoders check every untrusted length against the bytes that remain
before they allocate or loop. Fast paths are decided while generating, from what the emitter recorded
(never by rewriting emitted text). Types with a variable uint8[] also get ``serialize_parts()``: the
encoder without its final join, so a publisher can write a large payload without copying it.

Modules, by concern: ``sizes`` (names, type tables, wire sizes), ``writer`` (the emitter state), ``encode``
(``serialize``/``serialize_parts``), ``decode`` (``deserialize``), ``classes`` (the class and ``PRELUDE``).
"""

from mrosd.msg.codegen.classes import PRELUDE, GeneratedClass, generate_class, generate_view_decoder
from mrosd.msg.codegen.decode import MAX_TAIL_STRUCTS
from mrosd.msg.codegen.sizes import attribute_name, class_name, fixed_size, min_size, symbol
from mrosd.msg.layout import MAX_EMPTY_ITEMS

__all__ = [
    "MAX_EMPTY_ITEMS",
    "MAX_TAIL_STRUCTS",
    "PRELUDE",
    "GeneratedClass",
    "attribute_name",
    "class_name",
    "fixed_size",
    "generate_class",
    "generate_view_decoder",
    "min_size",
    "symbol",
]
