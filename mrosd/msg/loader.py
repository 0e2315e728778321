"""Message and service classes at run time: compile the codegen's source, cache by (type, md5).

``get_message_class`` resolves names through the default ``TypeStore``; ``load_type`` builds a class from
a message_definition as received in a TCPROS header, so a subscriber can decode types it has no files for.
Nested types whose md5 matches a known class reuse that class, so ``msg.header`` is always the same
``std_msgs/Header`` class whichever way the outer type was loaded.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Callable
from typing import Any

from mrosd.errors import MsgError, MsgNotFoundError
from mrosd.msg.codegen import PRELUDE, generate_class, generate_view_decoder, symbol
from mrosd.msg.md5 import compute_md5, full_text
from mrosd.msg.parser import parse_definition
from mrosd.msg.runtime import array_view_decoder, blob_view
from mrosd.msg.spec import MsgSpec
from mrosd.msg.typestore import TypeStore, normalize_type_name

#: (type, md5) -> class; shared by every store, so one type has one class per definition.
_CLASSES: dict[tuple[str, str], type[Any]] = {}
#: (type, message_definition) -> class, so a header's definition is parsed once.
_DEFINITIONS: dict[tuple[str, str], type[Any]] = {}
#: Bound on _DEFINITIONS: a peer sending endless distinct definitions must not grow memory forever.
MAX_CACHED_DEFINITIONS = 4096
_LOCK = threading.RLock()
_BASE_NAMESPACE: dict[str, Any] = {}
_default_store: TypeStore | None = None


def default_store() -> TypeStore:
    """The process-wide store (builtin definitions, then $ROS_PACKAGE_PATH, then system dirs)."""
    global _default_store
    if _default_store is None:
        _default_store = TypeStore()
    return _default_store


def _namespace() -> dict[str, Any]:
    if not _BASE_NAMESPACE:
        exec(compile(PRELUDE, "<mrosd.msg prelude>", "exec", dont_inherit=True), _BASE_NAMESPACE)
    return dict(_BASE_NAMESPACE)


def build_class(spec: MsgSpec, store: TypeStore, text: str | None = None) -> type[Any]:
    """The class for ``spec`` (nested types resolved through ``store``), built once per (type, md5)."""
    with _LOCK:
        md5 = compute_md5(spec, store.msg_spec, store._md5)
        key = (spec.full_name, md5)
        cls = _CLASSES.get(key)
        if cls is not None and (text is None or text == cls._full_text):
            return cls
        text = full_text(spec, store.msg_spec) if text is None else text
        generated = generate_class(spec, md5, text, store.msg_spec)
        namespace = _namespace()
        for dep in generated.dependencies:
            namespace[symbol(dep)] = build_class(store.msg_spec(dep), store)
        code = compile(generated.source, f"<mrosd.msg {spec.full_name}>", "exec", dont_inherit=True)
        exec(code, namespace)
        cls = namespace[generated.class_name]
        assert isinstance(cls, type)
        cls.__module__ = f"mrosd.msg.dynamic.{spec.package or 'nopkg'}"
        cls.__qualname__ = generated.class_name
        _CLASSES.setdefault(key, cls)  # a same-md5 class with other comments never displaces the first
        return cls


_VIEW_DECODERS: dict[type[Any], Callable[[memoryview, type[Any], list[memoryview]], Any]] = {}


def view_decoder(cls: type[Any]) -> Callable[[memoryview, type[Any], list[memoryview]], Any]:
    """``decode(data, leased_cls, views)`` for messages of ``cls`` read in place from memory that does not
    change while they live (``mrosd.msg.codegen.decode.view_decoder_source``); generated once per class,
    from the class's own full definition, so it reads exactly the layout ``cls.deserialize`` reads.

    Raises:
        MsgParseError: the class's definition does not parse (it was built from it, so it does).
    """
    got = _VIEW_DECODERS.get(cls)
    if got is not None:
        return got
    specs = parse_definition(cls._type, cls._full_text)
    store = _DefinitionStore(specs, default_store())
    generated = generate_view_decoder(specs[cls._type], store.msg_spec)
    namespace = _namespace()
    namespace["_blob_view"] = blob_view
    namespace["_array_view_decoder"] = array_view_decoder
    for dep in generated.dependencies:
        namespace[symbol(dep)] = build_class(store.msg_spec(dep), store)
    code = compile(generated.source, f"<mrosd.msg view {cls._type}>", "exec", dont_inherit=True)
    exec(code, namespace)
    got = namespace[generated.class_name]
    with _LOCK:
        _VIEW_DECODERS[cls] = got
    return got  # type: ignore[no-any-return]


def get_message_class(name: str, store: TypeStore | None = None) -> type[Any]:
    """The class of message type ``pkg/Type`` (``Header`` means std_msgs/Header).

    Raises:
        MsgNotFoundError: no definition on the search path.
        MsgParseError: the definition (or one it uses) is malformed.
    """
    store = store or default_store()
    return build_class(store.msg_spec(normalize_type_name(name)), store)


class ServiceClass:
    """Base of service type classes: only class attributes (``_type``, ``_md5sum``, request/response)."""

    _type: str
    _md5sum: str
    _request_class: type[Any]
    _response_class: type[Any]


_SERVICES: dict[tuple[str, str], type[ServiceClass]] = {}


def get_service_class(name: str, store: TypeStore | None = None) -> type[ServiceClass]:
    """The class of service type ``pkg/Type``, with ``_request_class`` and ``_response_class``.

    Raises:
        MsgNotFoundError: no definition on the search path.
        MsgParseError: the definition is malformed.
    """
    store = store or default_store()
    name = normalize_type_name(name, "srv")
    spec = store.srv_spec(name)
    md5 = store.srv_md5(name)
    with _LOCK:
        cls = _SERVICES.get((name, md5))
        if cls is None:
            request = build_class(spec.request, store)
            response = build_class(spec.response, store)
            attrs = {"_type": name, "_md5sum": md5, "_request_class": request, "_response_class": response}
            attrs["__module__"] = f"mrosd.msg.dynamic.{spec.package}"
            cls = type(spec.short_name, (ServiceClass,), attrs)
            _SERVICES[(name, md5)] = cls
            for half in (request, response):
                half._service_class = cls
        return cls


class _DefinitionStore(TypeStore):
    """A store whose specs come from one message_definition, falling back to the default store."""

    def __init__(self, specs: dict[str, MsgSpec], fallback: TypeStore) -> None:
        super().__init__(builtin=False, ros_package_path="", system_dirs=())
        self._msgs.update(specs)
        self._fallback = fallback

    def msg_spec(self, name: str) -> MsgSpec:
        spec = self._msgs.get(name)
        if spec is not None:
            return spec
        return self._fallback.msg_spec(name)


def load_type(name: str, definition: str, store: TypeStore | None = None) -> type[Any]:
    """A class for ``name`` built from ``definition`` (a TCPROS header's message_definition); cached.

    The class's ``_full_text`` is ``definition`` verbatim. Types the definition uses but does not include
    are looked up on the search path; an empty definition (some tools send none) means the search path's
    class for ``name``.

    Raises:
        MsgParseError: the definition is malformed (line numbers count from its first line).
        MsgNotFoundError: it uses a type that is neither included nor on the search path.
    """
    name = normalize_type_name(name)
    if not definition.strip():
        return get_message_class(name, store)
    key = (name, definition)
    cls = _DEFINITIONS.get(key)
    if cls is not None:
        return cls
    specs = parse_definition(name, definition)
    local = _DefinitionStore(specs, store or default_store())
    try:
        cls = build_class(specs[name], local, text=definition)
    except RecursionError:
        raise MsgError(f"{name}: message_definition has a recursive type") from None
    except KeyError as exc:  # pragma: no cover - parse_definition always returns the main type
        raise MsgNotFoundError(f"{name}: missing from its own definition") from exc
    with _LOCK:
        if len(_DEFINITIONS) >= MAX_CACHED_DEFINITIONS:
            _DEFINITIONS.clear()
        _DEFINITIONS[key] = cls
    return cls


async def load_type_async(name: str, definition: str, store: TypeStore | None = None) -> type[Any]:
    """``load_type`` for code on an event loop: a peer's definition is parsed and compiled in a worker thread,
    so a costly one never stalls the loop (the daemon's loop is the master's).

    Raises:
        MsgParseError: as ``load_type``.
        MsgNotFoundError: as ``load_type``.
    """
    cls = _DEFINITIONS.get((normalize_type_name(name), definition))
    if cls is not None:
        return cls
    return await asyncio.to_thread(load_type, name, definition, store)
