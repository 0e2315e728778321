"""YAML values -> ROS messages, as ``rostopic pub`` and ``rosservice call`` read their arguments.

One dictionary by field name, or one value per field in order; every value is checked against the field's ROS
type and a wrong one is an error naming the field (``field linear.y: expected float64, got str 'fast'``).
``now`` fills a time with the current time and ``auto`` a Header. Used by ``mros topic pub``, ``mros service
call`` and ``mros ixm``; no I/O beyond reading a ``-f`` file.
"""

from __future__ import annotations

from typing import Any

import yaml

from mrosd.errors import MrosError
from mrosd.msg import Duration, Time, get_message_class
from mrosd.msg.spec import INT_RANGES

__all__ = [
    "build_message",
    "build_message_or_hint",
    "file_documents",
    "load_document",
    "message_class",
    "parse_pub_args",
    "printable_args",
]


def message_class(rostype: str) -> Any:
    """The class of a ROS message type; ``Header`` is ``std_msgs/Header`` as in .msg files."""
    return get_message_class("std_msgs/Header" if rostype == "Header" else rostype)


def _time_value(rostype: str, value: Any, where: str) -> Any:
    kind = Time if rostype == "time" else Duration
    if value == "now" and rostype == "time":
        return Time.now()
    if isinstance(value, dict):
        unknown = set(value) - {"secs", "nsecs"}
        if unknown:
            raise MrosError(f"field {where}: unknown key {sorted(unknown)[0]!r} (a {rostype} has secs and nsecs)")
        return kind(int(value.get("secs", 0)), int(value.get("nsecs", 0)))
    if isinstance(value, int | float) and not isinstance(value, bool):
        return kind.from_sec(float(value)) if hasattr(kind, "from_sec") else kind(int(value), 0)
    raise MrosError(f"field {where}: expected {rostype} ({{secs: S, nsecs: N}}, seconds or 'now'), got {value!r}")


def _scalar(rostype: str, value: Any, where: str) -> Any:
    if rostype in INT_RANGES:
        if isinstance(value, bool) or not isinstance(value, int):
            raise MrosError(f"field {where}: expected {rostype}, got {type(value).__name__} {value!r}")
        low, high = INT_RANGES[rostype]
        if not low <= value <= high:
            raise MrosError(f"field {where}: {value} is out of range for {rostype} ({low}..{high})")
        return value
    if rostype in ("float32", "float64"):
        if isinstance(value, bool) or not isinstance(value, int | float):
            if isinstance(value, str) and value.strip().lower() in ("nan", "inf", "-inf", ".nan", ".inf", "-.inf"):
                return float(value.strip().lower().replace(".", ""))
            raise MrosError(f"field {where}: expected {rostype}, got {type(value).__name__} {value!r}")
        return float(value)
    if rostype == "bool":
        if isinstance(value, bool) or value in (0, 1):
            return bool(value)
        raise MrosError(f"field {where}: expected bool, got {type(value).__name__} {value!r}")
    if rostype == "string":
        if isinstance(value, bool | int | float):
            return str(value)
        if not isinstance(value, str):
            raise MrosError(f"field {where}: expected string, got {type(value).__name__} {value!r}")
        return value
    if rostype in ("time", "duration"):
        return _time_value(rostype, value, where)
    return build_message(message_class(rostype), value, where)


def _field_value(rostype: str, value: Any, where: str) -> Any:
    if "[" not in rostype:
        return _scalar(rostype, value, where)
    element, _, size = rostype.partition("[")
    size = size.rstrip("]")
    if element in ("uint8", "char") and isinstance(value, str | bytes):
        data = value.encode("latin-1") if isinstance(value, str) else value
        items: list[Any] = list(data)
    elif isinstance(value, list | tuple):
        items = list(value)
    else:
        raise MrosError(f"field {where}: expected a list for {rostype}, got {type(value).__name__} {value!r}")
    if size and len(items) != int(size):
        raise MrosError(f"field {where}: {rostype} needs exactly {size} items, got {len(items)}")
    converted = [_scalar(element, item, f"{where}[{i}]") for i, item in enumerate(items)]
    if element in ("uint8", "char"):
        return bytes(converted)
    return converted


def build_message(cls: Any, value: Any, where: str = "") -> Any:
    """A message of class ``cls`` from a YAML value: a dict by field name, or a list of fields in order.

    ``'now'`` fills a time with the current time and ``'auto'`` a Header with a stamp of now, as rostopic.

    Raises:
        MrosError: a field is unknown, missing from a positional list, or has the wrong type or range;
            the message names the field (``pose.position.x``).
    """
    names: tuple[str, ...] = cls.__struct_fields__
    types: tuple[str, ...] = tuple(cls._field_types)
    prefix = f"{where}." if where else ""
    if value == "auto" and getattr(cls, "_type", "") == "std_msgs/Header":
        value = {"stamp": "now"}
    if value is None:
        value = {}
    if isinstance(value, list | tuple):
        if len(value) != len(names):
            raise MrosError(
                f"{where or cls._type}: got {len(value)} values for {len(names)} fields ({', '.join(names)})"
            )
        value = dict(zip(names, value, strict=True))
    if not isinstance(value, dict):
        if len(names) == 1:
            value = {names[0]: value}
        else:
            fields = ", ".join(names)
            raise MrosError(f"{where or cls._type}: expected a dictionary of fields ({fields}), got {value!r}")
    table = dict(zip(names, types, strict=True))
    kwargs: dict[str, Any] = {}
    for key, item in value.items():
        if key not in table:
            raise MrosError(f"field {prefix}{key}: {cls._type} has no such field; its fields are: {', '.join(names)}")
        kwargs[key] = _field_value(table[key], item, f"{prefix}{key}")
    try:
        return cls(**kwargs)
    except (TypeError, ValueError, MrosError) as exc:
        raise MrosError(f"{where or cls._type}: {exc}") from exc


def printable_args(cls: Any, prefix: str = "") -> list[str]:
    """The field names as genpy prints them for rostopic pub's and rosservice's hints (nested messages
    flattened: ``a.x a.y``; arrays of messages stay one name)."""
    names: list[str] = []
    for name, rostype in zip(cls.__struct_fields__, cls._field_types, strict=True):
        if "[" not in rostype and ("/" in rostype or rostype == "Header"):
            names += printable_args(message_class(rostype), f"{prefix}{name}.")
        else:
            names.append(prefix + name)
    return names


def build_message_or_hint(cls: Any, value: Any) -> Any:
    """``build_message``, with rostopic pub's hint on error: ``Args are: [x y z]``.

    Raises:
        HintedError: the value does not fit ``cls``.
    """
    from mros_cli.main import HintedError

    try:
        return build_message(cls, value)
    except MrosError as exc:
        raise HintedError(str(exc), f"Args are: [{' '.join(printable_args(cls))}]") from exc


def parse_pub_args(args: tuple[str, ...]) -> Any:
    """rostopic pub's argument rules: one YAML dict, or one YAML value per field."""
    values: list[Any] = []
    for arg in args:
        try:
            values.append(yaml.safe_load(arg))
        except yaml.YAMLError as exc:
            raise MrosError(f"argument {arg!r} is not valid YAML: {' '.join(str(exc).split())}") from exc
    if len(values) == 1 and (isinstance(values[0], dict) or values[0] is None):
        return values[0]
    return values


def file_documents(path: str) -> list[Any]:
    """Every YAML document in ``path`` (``---``-separated, like a rostopic -f file); empty ones are skipped.

    Raises:
        MrosError: the file cannot be read or is not valid YAML (nothing is published then).
    """
    try:
        with open(path, encoding="utf-8") as stream:
            docs = list(yaml.safe_load_all(stream))
    except OSError as exc:
        raise MrosError(f"cannot read {path}: {exc.strerror or exc}") from exc
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise MrosError(f"invalid YAML in {path}: {' '.join(str(exc).split())}") from exc
    return [d for d in docs if d is not None]


def load_document(text: str, where: str) -> Any:
    """One YAML document from stdin; ``None`` when it is empty."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise MrosError(f"invalid YAML in {where}: {' '.join(str(exc).split())}") from exc
