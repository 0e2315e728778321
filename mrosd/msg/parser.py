"""Parse .msg/.srv text and concatenated message_definition text into the IR of ``spec.py``.

Follows genmsg's rules exactly where they decide md5sums (comment stripping, string constants keeping
everything after ``=``, package-relative names, ``Header``), and is stricter than genmsg only where genmsg
would crash later. Every error is a ``MsgParseError`` carrying the file and 1-based line.
"""

from __future__ import annotations

import ast
import re

from mrosd.errors import MsgParseError
from mrosd.msg.spec import (
    BUILTIN_TYPES,
    CONSTANT_TYPES,
    HEADER,
    HEADER_FULL_NAME,
    INT_RANGES,
    Constant,
    Field,
    MsgSpec,
    SrvSpec,
)

#: genmsg's legal names: a resource (type) name may contain '/', a base (field) name may not.
_RESOURCE_NAME = re.compile(r"[A-Za-z][\w/]*\Z")
_BASE_NAME = re.compile(r"[A-Za-z]\w*\Z")
_ARRAY = re.compile(r"\[(\d*)\]\Z")


#: The separator genpy writes between the definitions of a message_definition (80 '=').
DEFINITION_SEPARATOR = "=" * 80

#: Bound on a fixed array length in a definition (a typo like float64[100000000000] must not allocate).
MAX_FIXED_ARRAY_LENGTH = 1 << 24


def is_valid_type_name(name: str) -> bool:
    """True for a syntactically legal ``pkg/Type`` or ``Type`` (no array suffix)."""
    return bool(_RESOURCE_NAME.match(name)) and "//" not in name and not name.endswith("/")


def split_array(type_text: str) -> tuple[str, bool, int | None]:
    """Split ``base[N]``/``base[]``/``base`` into (base, is_array, fixed length or None)."""
    idx = type_text.find("[")
    if idx < 0:
        return type_text, False, None
    m = _ARRAY.match(type_text, idx)
    if m is None:
        raise ValueError(f"invalid array type {type_text!r} (only one dimension, [] or [N])")
    digits = m.group(1)
    return type_text[:idx], True, (int(digits) if digits else None)


def resolve_type_name(base: str, package: str) -> str:
    """genmsg's resolution of an element type: builtins stay, ``Header`` -> std_msgs/Header, else pkg-relative."""
    if base in BUILTIN_TYPES or "/" in base:
        return base
    if base == HEADER:
        return HEADER_FULL_NAME
    return f"{package}/{base}" if package else base


def _convert_constant(type_: str, text: str) -> bool | int | float | str:
    if type_ in ("float32", "float64"):
        return float(text)
    if type_ == "string":
        return text
    if type_ == "bool":
        return bool(ast.literal_eval(text))
    value = int(text)
    low, high = INT_RANGES[type_]
    if not low <= value <= high:
        raise ValueError(f"{value} is out of bounds for {type_} [{low}, {high}]")
    return value


def _parse_constant(orig: str, clean: str, where: tuple[str, int]) -> Constant:
    tokens = clean.split()
    type_ = tokens[0]
    if type_ not in CONSTANT_TYPES:
        raise MsgParseError(f"{type_!r} is not a legal constant type (only primitives and string)", *where)
    if type_ == "string":
        # genmsg: a string constant is everything right of '=', comments included, then stripped.
        body = orig.lstrip()
        eq = body.find("=")
        head = body[:eq].split()
        if len(head) != 2:
            raise MsgParseError(f"invalid constant declaration {orig.strip()!r}", *where)
        name = head[1]
        text = body[eq + 1 :].strip()
    else:
        parts = [p.strip() for p in " ".join(tokens[1:]).split("=")]
        if len(parts) != 2 or not parts[0] or not parts[1]:
            raise MsgParseError(f"invalid constant declaration {orig.strip()!r}", *where)
        name, text = parts
    if not _BASE_NAME.match(name):
        raise MsgParseError(f"{name!r} is not a legal constant name", *where)
    try:
        value = _convert_constant(type_, text)
    except (ValueError, SyntaxError) as exc:
        raise MsgParseError(f"invalid value {text!r} for constant {name} of type {type_}: {exc}", *where) from None
    return Constant(type_, name, value, text)


def _parse_field(clean: str, package: str, where: tuple[str, int]) -> Field:
    tokens = clean.split()
    if len(tokens) != 2:
        raise MsgParseError(f"invalid declaration {clean!r}: expected 'type name'", *where)
    type_text, name = tokens
    if not _BASE_NAME.match(name):
        raise MsgParseError(f"{name!r} is not a legal field name", *where)
    try:
        base, is_array, length = split_array(type_text)
    except ValueError as exc:
        raise MsgParseError(str(exc), *where) from None
    if not is_valid_type_name(base) or base.count("/") > 1:
        raise MsgParseError(f"{type_text!r} is not a legal field type", *where)
    if length is not None and length > MAX_FIXED_ARRAY_LENGTH:
        raise MsgParseError(f"fixed array length {length} exceeds {MAX_FIXED_ARRAY_LENGTH}", *where)
    resolved = resolve_type_name(base, package)
    suffix = type_text[len(base) :]
    return Field(name=name, type=resolved + suffix, base=resolved, is_array=is_array, length=length, line=where[1])


def parse_msg(text: str, full_name: str, file: str = "<string>", first_line: int = 1) -> MsgSpec:
    """Parse .msg text for type ``full_name`` (``pkg/Type``); ``first_line`` offsets reported line numbers.

    Raises:
        MsgParseError: a malformed line (with file and line), or duplicate field names.
    """
    package = full_name.rpartition("/")[0]
    fields: list[Field] = []
    constants: list[Constant] = []
    seen: dict[str, int] = {}
    for index, orig in enumerate(text.split("\n")):
        clean = orig.split("#", 1)[0].strip()
        if not clean:
            continue
        where = (file, first_line + index)
        if "=" in clean:
            constants.append(_parse_constant(orig, clean, where))
            continue
        field = _parse_field(clean, package, where)
        if field.name in seen:
            raise MsgParseError(f"duplicate field name {field.name!r} (first on line {seen[field.name]})", *where)
        seen[field.name] = where[1]
        fields.append(field)
    return MsgSpec(full_name=full_name, fields=tuple(fields), constants=tuple(constants), text=text, file=file)


def parse_srv(text: str, full_name: str, file: str = "<string>") -> SrvSpec:
    """Parse .srv text; the request ends at the first line starting with ``---`` (genmsg is as lenient).

    Raises:
        MsgParseError: a malformed line in either half.
    """
    request_lines: list[str] = []
    response_lines: list[str] = []
    response_start = 0
    target = request_lines
    for index, line in enumerate(text.split("\n")):
        if line.startswith("---"):
            if target is request_lines:
                response_start = index + 2
            target = response_lines
            continue
        target.append(line + "\n")
    request = parse_msg("".join(request_lines), full_name + "Request", file)
    response = parse_msg("".join(response_lines), full_name + "Response", file, first_line=response_start or 1)
    return SrvSpec(full_name=full_name, request=request, response=response, text=text, file=file)


def parse_definition(full_name: str, definition: str, file: str = "<message_definition>") -> dict[str, MsgSpec]:
    """Parse a concatenated message_definition (as in a TCPROS header) into ``{type: MsgSpec}``.

    The first section defines ``full_name``; each later one starts with ``MSG: pkg/Type``.

    Raises:
        MsgParseError: a malformed section or definition line (line numbers count from the whole text).
    """
    sections: list[tuple[int, list[str]]] = [(1, [])]
    lines = definition.split("\n")
    for index, line in enumerate(lines):
        if line.rstrip() == DEFINITION_SEPARATOR:
            sections.append((index + 2, []))
        else:
            sections[-1][1].append(line)
    specs: dict[str, MsgSpec] = {}
    for number, (start, section) in enumerate(sections):
        body = section
        if number == 0:
            name, first = full_name, start
        else:
            header = body[0].strip() if body else ""
            if not header.startswith("MSG:"):
                raise MsgParseError("expected 'MSG: pkg/Type' after the separator line", file, start)
            name = header[4:].strip()
            if not is_valid_type_name(name):
                raise MsgParseError(f"{name!r} is not a legal message type name", file, start)
            body = body[1:]
            first = start + 1
        if name == "Header":
            name = HEADER_FULL_NAME
        if name not in specs:
            specs[name] = parse_msg("\n".join(body), name, file, first_line=first)
    return specs
