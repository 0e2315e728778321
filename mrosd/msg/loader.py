"""Message and service classes at run time: compile the codegen's source, cache by (type, md5).

``get_message_class`` resolves names through the default ``TypeStore``; ``load_type`` builds a class from
a message_definition as received in a TCPROS header, so a subscriber can decode types it has no files for.
Nested types whose md5 matches a known class reuse that class, so ``msg.header`` is always the same
``std_msgs/Header`` class whichever way the outer type was loaded.

Every definition is checked against ``mrosd.msg.bounds`` before any code is generated for it, whichever
route it came by. Classes of the search path's own types are kept for the process's life (their number is
bounded by the files); classes built from peers' definitions live in a bounded LRU, as do the parsed
definitions, so endless distinct definitions cannot grow memory without bound. ``load_type_async`` is the
route for code on an event loop (``mrosd.msg.loading``).
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from collections.abc import Callable
from typing import Any

from mrosd.errors import MsgError, MsgNotFoundError
from mrosd.msg import bounds
from mrosd.msg.codegen import PRELUDE, generate_class, generate_view_decoder, symbol
from mrosd.msg.md5 import compute_md5, full_text
from mrosd.msg.parser import parse_definition
from mrosd.msg.runtime import array_view_decoder, blob_view
from mrosd.msg.spec import MsgSpec
from mrosd.msg.typestore import TypeStore, normalize_type_name

#: (type, md5) -> class for the search path's types; shared by every store, so one type has one class.
_CLASSES: dict[tuple[str, str], type[Any]] = {}
#: (type, md5) -> class built from a peer's definition, least recently used first (bounded).
_PEER_CLASSES: OrderedDict[tuple[str, str], type[Any]] = OrderedDict()
#: Bound on _PEER_CLASSES.
MAX_CACHED_CLASSES = 1024
#: (type, message_definition) -> class, so a header's definition is parsed once; least recently used first.
_DEFINITIONS: OrderedDict[tuple[str, str], type[Any]] = OrderedDict()
#: Bound on _DEFINITIONS: a peer sending endless distinct definitions must not grow memory forever.
MAX_CACHED_DEFINITIONS = 1024
#: Held while generating and compiling (so one definition compiles once); never for a cache hit.
_LOCK = threading.RLock()
#: Held only for the few instructions of an LRU update.
_CACHE_LOCK = threading.Lock()
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


def _cached(key: tuple[str, str]) -> type[Any] | None:
    cls = _CLASSES.get(key)
    if cls is None:
        cls = _PEER_CLASSES.get(key)
    return cls


def build_class(spec: MsgSpec, store: TypeStore, text: str | None = None) -> type[Any]:
    """The class for ``spec`` (nested types resolved through ``store``), built once per (type, md5).

    Raises:
        MsgTooComplexError: the type is over a bound of ``mrosd.msg.bounds``.
        MsgError: it contains itself.
    """
    md5 = compute_md5(spec, store.msg_spec, store._md5)
    key = (spec.full_name, md5)
    cls = _cached(key)  # lock-free: a loop asking for a known class never waits for another thread's compile
    if cls is not None and (text is None or text == cls._full_text):
        return cls
    with _LOCK:
        cls = _cached(key)
        if cls is not None and (text is None or text == cls._full_text):
            return cls
        bounds.check(spec, store.msg_spec)
        text = full_text(spec, store.msg_spec) if text is None else text
        generated = generate_class(spec, md5, text, store.msg_spec)
        bounds.check_source(spec.full_name, generated.source)
        namespace = _namespace()
        for dep in generated.dependencies:
            namespace[symbol(dep)] = build_class(store.msg_spec(dep), store)
        code = compile(generated.source, f"<mrosd.msg {spec.full_name}>", "exec", dont_inherit=True)
        exec(code, namespace)
        cls = namespace[generated.class_name]
        assert isinstance(cls, type)
        cls.__module__ = f"mrosd.msg.dynamic.{spec.package or 'nopkg'}"
        cls.__qualname__ = generated.class_name
        # a same-md5 class with other comments never displaces the first
        if isinstance(store, _DefinitionStore) and store.defines(spec.full_name):
            with _CACHE_LOCK:
                _PEER_CLASSES.setdefault(key, cls)
                _PEER_CLASSES.move_to_end(key)
                while len(_PEER_CLASSES) > MAX_CACHED_CLASSES:
                    _PEER_CLASSES.popitem(last=False)
        else:
            _CLASSES.setdefault(key, cls)
        return cls


#: Weak: a peer's class evicted from the caches takes its view decoder with it.
_VIEW_DECODERS: weakref.WeakKeyDictionary[type[Any], Callable[[memoryview, type[Any], list[memoryview]], Any]] = (
    weakref.WeakKeyDictionary()
)


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
    bounds.check_source(cls._type, generated.source)
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

    def defines(self, name: str) -> bool:
        """Whether ``name`` came from the definition (not from the fallback's files)."""
        return name in self._msgs


def load_type(name: str, definition: str, store: TypeStore | None = None) -> type[Any]:
    """A class for ``name`` built from ``definition`` (a TCPROS header's message_definition); cached.

    The class's ``_full_text`` is ``definition`` verbatim. Types the definition uses but does not include
    are looked up on the search path; an empty definition (some tools send none) means the search path's
    class for ``name``. Code on an event loop calls ``load_type_async`` instead.

    Raises:
        MsgParseError: the definition is malformed (line numbers count from its first line).
        MsgNotFoundError: it uses a type that is neither included nor on the search path.
        MsgTooComplexError: it is over a bound of ``mrosd.msg.bounds`` (too long, too deep, too many fields).
    """
    name = normalize_type_name(name)
    if not definition.strip():
        return get_message_class(name, store)
    key = (name, definition)
    cls = cached_definition(key)
    if cls is not None:
        return cls
    bounds.check_definition(name, definition)
    specs = parse_definition(name, definition)
    local = _DefinitionStore(specs, store or default_store())
    try:
        spec = specs[name]
    except KeyError as exc:  # pragma: no cover - parse_definition always returns the main type
        raise MsgNotFoundError(f"{name}: missing from its own definition") from exc
    try:
        bounds.check(spec, local.msg_spec)
        cls = build_class(spec, local, text=definition)
    except RecursionError:  # pragma: no cover - bounds.check refuses the depth first
        raise MsgError(f"{name}: message_definition nests too deep") from None
    with _CACHE_LOCK:
        _DEFINITIONS[key] = cls
        while len(_DEFINITIONS) > MAX_CACHED_DEFINITIONS:
            _DEFINITIONS.popitem(last=False)
    return cls


def cached_definition(key: tuple[str, str]) -> type[Any] | None:
    """The class ``load_type`` built for (type, definition), if it is still cached."""
    cls = _DEFINITIONS.get(key)
    if cls is not None:
        with _CACHE_LOCK:
            if key in _DEFINITIONS:  # not evicted meanwhile by another thread
                _DEFINITIONS.move_to_end(key)
    return cls
