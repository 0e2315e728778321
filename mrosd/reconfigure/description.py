"""dynamic_reconfigure's description and config as plain data, and their messages.

A server describes its parameters in ``dynamic_reconfigure/ConfigDescription`` (groups of
``ParamDescription``, plus ``min``, ``max`` and ``dflt`` configs); a config travels as
``dynamic_reconfigure/Config`` (one array per type, plus group states). The rules restated here are those of
Debian's dynamic_reconfigure 1.7 ``encoding.py``, ``client.py`` and ``server.py``. No I/O.
"""

from __future__ import annotations

import ast
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

from mrosd.errors import MrosError
from mrosd.msg import get_message_class

Config = get_message_class("dynamic_reconfigure/Config")
ConfigDescription = get_message_class("dynamic_reconfigure/ConfigDescription")
Group = get_message_class("dynamic_reconfigure/Group")
GroupState = get_message_class("dynamic_reconfigure/GroupState")
ParamDescription = get_message_class("dynamic_reconfigure/ParamDescription")
BoolParameter = get_message_class("dynamic_reconfigure/BoolParameter")
IntParameter = get_message_class("dynamic_reconfigure/IntParameter")
StrParameter = get_message_class("dynamic_reconfigure/StrParameter")
DoubleParameter = get_message_class("dynamic_reconfigure/DoubleParameter")

#: Longest ``edit_method`` text parsed (a peer's enum description); dynamic_reconfigure's are a few hundred bytes.
MAX_EDIT_METHOD = 65_536
INT32_MIN, INT32_MAX = -(2**31), 2**31 - 1
#: dynamic_reconfigure's types and the Python type each value has.
TYPES: dict[str, type] = {"int": int, "double": float, "str": str, "bool": bool}


class ReconfigureError(MrosError):
    """A value does not fit the server's description (unknown name, wrong type, out of range, not an enum
    constant), or the server did not answer."""


@dataclass(frozen=True)
class EnumConstant:
    name: str
    value: Any
    description: str = ""


@dataclass(frozen=True)
class Param:
    """One parameter: its type (``int``, ``double``, ``str``, ``bool``), default and (numbers) range."""

    name: str
    type: str
    default: Any
    min: Any = None
    max: Any = None
    level: int = 0
    description: str = ""
    enum: tuple[EnumConstant, ...] = ()
    enum_description: str = ""
    #: the edit_method text as received (kept verbatim when a description is relayed)
    edit_method: str = ""

    def edit_method_text(self) -> str:
        if self.edit_method or not self.enum:
            return self.edit_method
        consts = [
            {
                "name": c.name,
                "type": self.type,
                "value": c.value,
                "srcline": 0,
                "srcfile": "",
                "cconsttype": "const "
                + {"double": "double", "str": "char * const", "bool": "bool"}.get(self.type, "int"),
                "ctype": {"double": "double", "str": "std::string", "bool": "bool"}.get(self.type, "int"),
                "description": c.description,
            }
            for c in self.enum
        ]
        return repr({"enum": consts, "enum_description": self.enum_description})


@dataclass
class GroupSpec:
    """A group of parameters; group 0 (``Default``) is the root, others name their parent's id."""

    name: str
    id: int
    parent: int = 0
    type: str = ""
    state: bool = True
    params: list[Param] = field(default_factory=list)


def parse_edit_method(text: str) -> tuple[tuple[EnumConstant, ...], str]:
    """The enum constants of an ``edit_method`` text (a Python literal; never evaluated as code)."""
    if not text or len(text) > MAX_EDIT_METHOD:
        return (), ""
    try:
        value = ast.literal_eval(text)
    except (ValueError, SyntaxError, MemoryError, RecursionError):
        return (), ""
    if not isinstance(value, dict) or not isinstance(value.get("enum"), list):
        return (), ""
    consts = tuple(
        EnumConstant(str(c.get("name", "")), c.get("value"), str(c.get("description", "")))
        for c in value["enum"]
        if isinstance(c, dict)
    )
    return consts, str(value.get("enum_description", ""))


def config_values(msg: Any) -> dict[str, Any]:
    """A ``Config`` message's parameters as {name: value} (groups left out)."""
    out: dict[str, Any] = {}
    for arr in (msg.bools, msg.ints, msg.strs, msg.doubles):
        for p in arr:
            out[p.name] = p.value
    return out


def encode_config(values: Mapping[str, Any], groups: list[GroupSpec] | None = None) -> Any:
    """{name: value} -> ``Config``, each value in the array of its Python type, as encoding.py does."""
    msg = Config()
    for name, value in values.items():
        if isinstance(value, bool):
            msg.bools.append(BoolParameter(name=name, value=value))
        elif isinstance(value, int):
            msg.ints.append(IntParameter(name=name, value=value))
        elif isinstance(value, str):
            msg.strs.append(StrParameter(name=name, value=value))
        elif isinstance(value, float):
            msg.doubles.append(DoubleParameter(name=name, value=value))
    for g in groups or ():
        msg.groups.append(GroupState(name=g.name, state=g.state, id=g.id, parent=g.parent))
    return msg


@dataclass
class Description:
    """A server's parameters, by group."""

    groups: list[GroupSpec]

    def params(self) -> Iterator[Param]:
        for g in self.groups:
            yield from g.params

    def param(self, name: str) -> Param | None:
        return next((p for p in self.params() if p.name == name), None)

    def defaults(self) -> dict[str, Any]:
        return {p.name: p.default for p in self.params()}

    def to_msg(self) -> Any:
        groups = [
            Group(
                name=g.name,
                type=g.type,
                parameters=[
                    ParamDescription(
                        name=p.name,
                        type=p.type,
                        level=p.level,
                        description=p.description,
                        edit_method=p.edit_method_text(),
                    )
                    for p in g.params
                ],
                parent=g.parent,
                id=g.id,
            )
            for g in self.groups
        ]
        params = list(self.params())
        return ConfigDescription(
            groups=groups,
            max=encode_config({p.name: _bound(p, p.max, "max") for p in params}, self.groups),
            min=encode_config({p.name: _bound(p, p.min, "min") for p in params}, self.groups),
            dflt=encode_config(self.defaults(), self.groups),
        )

    @classmethod
    def from_msg(cls, msg: Any) -> Description:
        mins, maxs, dflts = config_values(msg.min), config_values(msg.max), config_values(msg.dflt)
        groups = []
        for g in msg.groups:
            params = []
            for p in g.parameters:
                enum, enum_description = parse_edit_method(p.edit_method)
                params.append(
                    Param(
                        name=p.name,
                        type=p.type,
                        default=dflts.get(p.name),
                        min=mins.get(p.name),
                        max=maxs.get(p.name),
                        level=p.level,
                        description=p.description,
                        enum=enum,
                        enum_description=enum_description,
                        edit_method=p.edit_method,
                    )
                )
            groups.append(GroupSpec(name=g.name, id=g.id, parent=g.parent, type=g.type, params=params))
        return cls(groups)

    def check(self, name: str, value: Any, *, ranges: bool = True) -> Any:
        """``value`` converted to the parameter's type, as dynamic_reconfigure's client converts it, then
        checked against its range and enum constants (``ranges=False``: the server's side, which clamps
        numbers instead).

        Raises:
            ReconfigureError: unknown parameter, a value that does not convert, or one out of range.
        """
        param = self.param(name)
        if param is None:
            raise ReconfigureError(f"don't know parameter: {name}")
        kind = TYPES.get(param.type)
        if kind is None:
            raise ReconfigureError(f"parameter {name} has an unknown type {param.type!r}")
        if isinstance(value, str) and param.enum and kind is not str:
            match = next((c for c in param.enum if c.name.lower() == value.lower()), None)
            if match is not None:
                value = match.value
        try:
            if kind is bool and isinstance(value, str):
                value = value.lower() in ("yes", "true", "t", "1")
            elif kind is int and isinstance(value, float) and not value.is_integer():
                raise ValueError(f"{value!r} is not an integer")
            else:
                value = kind(value)
        except (ValueError, TypeError, OverflowError) as exc:
            raise ReconfigureError(f"can't set parameter '{name}' of type {param.type}: {exc}") from exc
        if kind in (int, float) and ranges:
            low, high = param.min, param.max
            if (low is not None and value < low) or (high is not None and value > high):
                raise ReconfigureError(f"{name} = {value!r} is out of its range [{low}, {high}]")
            if kind is int and not INT32_MIN <= value <= INT32_MAX:
                raise ReconfigureError(f"{name} = {value!r} does not fit an int32")
            if kind is float and math.isnan(value):
                raise ReconfigureError(f"{name} cannot be NaN")
        if ranges and param.enum and value not in [c.value for c in param.enum]:
            names = ", ".join(f"{c.name}={c.value!r}" for c in param.enum)
            raise ReconfigureError(f"{name} = {value!r} is not one of its constants: {names}")
        return value

    def clamp(self, config: dict[str, Any]) -> None:
        """Numbers outside [min, max] are moved to the bound, as dynamic_reconfigure's server does."""
        for p in self.params():
            value = config.get(p.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                continue
            if p.max is not None and value > p.max:
                config[p.name] = p.max
            elif p.min is not None and value < p.min:
                config[p.name] = p.min

    def level(self, new: Mapping[str, Any], old: Mapping[str, Any]) -> int:
        """OR of the levels of the parameters that changed."""
        level = 0
        for p in self.params():
            if new.get(p.name) != old.get(p.name):
                level |= p.level
        return level


def _bound(param: Param, value: Any, which: str) -> Any:
    """The min/max a description carries: numbers default to the type's limits, others to their default."""
    if value is not None:
        return value
    if param.type == "int":
        return INT32_MAX if which == "max" else INT32_MIN
    if param.type == "double":
        return math.inf if which == "max" else -math.inf
    if param.type == "bool":
        return which == "max"
    return ""
