"""The emitter state shared by the encoder and decoder: lines, temporaries, precompiled structs."""

from __future__ import annotations

from dataclasses import dataclass, field

from mrosd.msg.bounds import Measure
from mrosd.msg.codegen.sizes import Lookup
from mrosd.msg.spec import MsgSpec

#: A nested message type with at most this many fields (expanded) is inlined into the code of the types
#: that hold it; a bigger one is called (its ``serialize``, its ``_decode_at``), so generated code grows
#: with the definition, not with the expansion. Every type shipped with Debian's ROS (98 at most) inlines.
INLINE_MAX_FIELDS = 128


@dataclass
class Writer:
    """Accumulates indented lines, temporaries and precompiled struct formats for one generated class."""

    type_name: str
    lookup: Lookup
    lines: list[str] = field(default_factory=list)
    structs: dict[str, int] = field(default_factory=dict)
    helpers: dict[str, str] = field(default_factory=dict)
    counter: int = 0
    tag: str = ""  #: distinguishes the structs of several classes generated into one module
    measure: Measure | None = None

    def _measure(self) -> Measure:
        if self.measure is None:
            self.measure = Measure(self.lookup)
        return self.measure

    def inline(self, base: str) -> bool:
        """Whether the nested message type ``base`` is inlined (else called): see ``INLINE_MAX_FIELDS``."""
        return self._measure().fields(base) <= INLINE_MAX_FIELDS

    def inline_spec(self, spec: MsgSpec) -> bool:
        """``inline`` for the type being generated (which ``lookup`` need not know)."""
        measure = self._measure()
        total = sum(1 + (0 if f.is_builtin else measure.fields(f.base)) for f in spec.fields)
        return total <= INLINE_MAX_FIELDS

    def emit(self, indent: int, text: str) -> None:
        self.lines.append("    " * indent + text)

    def tmp(self, prefix: str = "v") -> str:
        self.counter += 1
        return f"_{prefix}{self.counter}"

    def _index(self, fmt: str) -> int:
        index = self.structs.get(fmt)
        if index is None:
            index = self.structs[fmt] = len(self.structs)
        return index

    def struct(self, fmt: str) -> str:
        """The module-level ``struct.Struct`` for ``fmt`` (little-endian)."""
        return f"_S{self.tag}{self._index(fmt)}"

    def pack(self, fmt: str) -> str:
        """The prebound ``pack`` of that struct (saves an attribute lookup per call)."""
        return f"_P{self.tag}{self._index(fmt)}"

    def unpack(self, fmt: str) -> str:
        """The prebound ``unpack_from`` of that struct."""
        return f"_U{self.tag}{self._index(fmt)}"

    def helper(self, name: str, expr: str) -> str:
        self.helpers[name] = expr
        return name

    def prelude(self) -> list[str]:
        out = []
        for fmt in self.structs:
            out.append(f"{self.struct(fmt)} = _struct.Struct({'<' + fmt!r})")
            out.append(f"{self.pack(fmt)} = {self.struct(fmt)}.pack")
            out.append(f"{self.unpack(fmt)} = {self.struct(fmt)}.unpack_from")
        out += [f"{name} = {expr}" for name, expr in sorted(self.helpers.items())]
        return out
