"""rosapi's services, answered from the master, for rosbridge clients and (registered in the graph) for ROS.

rosbridge clients (roslibjs, roslibpy, Lichtblick, ros-mcp) find the graph through ``/rosapi/*``. ROS 1's
rosapi is a node of its own: each service is registered with the master under rosapi's own type
(``/rosapi/topics`` is a ``rosapi/Topics``), so ``rosservice info`` and a client's ``service_type`` see them
as they see rosapi's. ``register`` does the same on the web hub's node; ``answer`` is what both a rosbridge
``call_service`` and a ROS caller get. The values follow rosapi's ROS 1 code (rosbridge_suite, branch
``ros1``): the details services list typedefs depth-first with ``time``/``duration`` typedefs, each field's
example is ``str()`` of its default as rospy makes it, and constants come sorted by name; ``action_servers``
lists the namespaces that hold all five actionlib topics. ``get_ros_version`` (not in ROS 1's rosapi, asked by
newer clients) reads the master's ``/rosdistro``.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from collections.abc import Awaitable, Callable
from typing import TYPE_CHECKING, Any

import msgspec

from mrosd.errors import MasterError, MrosError
from mrosd.msg import get_service_class
from mrosd.web import rosbridge as rb

if TYPE_CHECKING:
    from mrosd.msg.spec import MsgSpec
    from mrosd.web.hub import WebHub

log = logging.getLogger(__name__)

__all__ = ["SERVICES", "answer", "register", "typedefs"]

#: The services rosapi's ROS 1 node registers, with their types (rosapi_node's register_services).
SERVICES = {
    "topics": "rosapi/Topics",
    "topics_for_type": "rosapi/TopicsForType",
    "services": "rosapi/Services",
    "services_for_type": "rosapi/ServicesForType",
    "nodes": "rosapi/Nodes",
    "node_details": "rosapi/NodeDetails",
    "action_servers": "rosapi/GetActionServers",
    "topic_type": "rosapi/TopicType",
    "service_type": "rosapi/ServiceType",
    "publishers": "rosapi/Publishers",
    "subscribers": "rosapi/Subscribers",
    "service_providers": "rosapi/ServiceProviders",
    "service_node": "rosapi/ServiceNode",
    "service_host": "rosapi/ServiceHost",
    "message_details": "rosapi/MessageDetails",
    "service_request_details": "rosapi/ServiceRequestDetails",
    "service_response_details": "rosapi/ServiceResponseDetails",
    "set_param": "rosapi/SetParam",
    "get_param": "rosapi/GetParam",
    "has_param": "rosapi/HasParam",
    "search_param": "rosapi/SearchParam",
    "delete_param": "rosapi/DeleteParam",
    "get_param_names": "rosapi/GetParamNames",
    "get_time": "rosapi/GetTime",
    "topics_and_raw_types": "rosapi/TopicsAndRawTypes",
}

#: The actionlib topics under an action server's namespace (rosapi's filter_action_servers).
ACTION_TOPICS = ("cancel", "feedback", "goal", "result", "status")

_ATOMICS = frozenset(
    ("bool", "byte", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64")
)
_SPECIALS = ("time", "duration")


async def register(hub: WebHub) -> list[Any]:
    """Advertise rosapi's services on ``hub``'s node, each under its rosapi type; returns the servers.

    The 25 classes are built in a worker thread (0.4 s of parsing and compiling, which the daemon's loop, the
    master's, must not spend), then registered with the master together. A service another node already
    provides (a real rosapi node) is left to it; a definition that does not load is logged and skipped.
    """
    classes = await asyncio.to_thread(_service_classes)
    found = await asyncio.gather(*(_register_one(hub, method, cls) for method, cls in classes.items()))
    return [server for server in found if server is not None]


def _service_classes() -> dict[str, Any]:
    classes = {}
    for method, srv_type in SERVICES.items():
        try:
            classes[method] = get_service_class(srv_type)
        except MrosError as exc:
            log.warning("web: /rosapi/%s is not registered in the graph: %s", method, exc)
    return classes


async def _register_one(hub: WebHub, method: str, srv_class: Any) -> Any:
    name = f"/rosapi/{method}"
    try:
        provider = await _provided(hub, name)
        if provider:
            log.info("web: %s is provided by %s; not registering mrosd's", name, provider)
            return None
        return await hub.node.advertise_service(name, srv_class, _ros_handler(hub, method, srv_class))
    except (MrosError, OSError, TimeoutError) as exc:
        log.warning("web: %s is not registered in the graph: %s", name, exc)
        return None


async def _provided(hub: WebHub, name: str) -> str:
    try:
        return await hub.node.master.lookup_service(name)
    except MasterError:
        return ""


def _ros_handler(hub: WebHub, method: str, srv_class: Any) -> Callable[[Any], Awaitable[Any]]:
    async def handle(request: Any) -> Any:
        values = await answer(hub, method, msgspec.to_builtins(request))
        return msgspec.convert(values, srv_class._response_class, strict=False)

    return handle


async def answer(hub: WebHub, method: str, args: dict[str, Any]) -> dict[str, Any]:
    """The response of ``/rosapi/<method>`` to ``args``, as a JSON-able dict (field names as rosapi's).

    Raises:
        MrosError: the method is not rosapi's, a name is not allowed, or the master refused.
    """
    handler = _HANDLERS.get(method)
    if handler is None:
        raise MrosError(f"/rosapi/{method} is not served by mrosd")
    return await handler(hub, args)


# --- the graph ------------------------------------------------------------------------------------------


async def _topics(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    topics = sorted((t, ty) for t, ty in hub.topic_types().items() if hub.policy.allows_topic(t))
    return {"topics": [t for t, _ in topics], "types": [ty for _, ty in topics]}


async def _topics_and_raw_types(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    out = await _topics(hub, args)
    pairs = zip(out["topics"], out["types"], strict=True)
    out["typedefs_full_text"] = [_full_text(hub, topic, ty) for topic, ty in pairs]
    return out


def _full_text(hub: WebHub, topic: str, msg_type: str) -> str:
    """The definition of a topic's type: its publisher's, else the type search path's (a topic that only has
    subscribers has no publisher to ask), else empty, as rosapi gives an unknown type."""
    info = hub.topics.get(topic)
    if info is not None and info.type == msg_type:
        return info.definition
    if "/" not in msg_type:
        return ""
    from mrosd.msg.loader import default_store

    try:
        return default_store().full_text(msg_type)
    except MrosError:
        return ""


async def _topic_type(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    topic = str(args.get("topic", ""))
    return {"type": hub.topic_types().get(topic, "") if hub.policy.allows_topic(topic) else ""}


async def _topics_for_type(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    wanted = str(args.get("type", ""))
    topics = hub.topic_types().items()
    return {"topics": sorted(t for t, ty in topics if ty == wanted and hub.policy.allows_topic(t))}


async def _action_servers(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    """The namespaces (at least one level deep) that hold all five actionlib topics, in name order."""
    found: dict[str, set[str]] = {}
    for topic in hub.graph.topics:
        namespace, _, leaf = topic.rpartition("/")
        if namespace and leaf in ACTION_TOPICS and hub.policy.allows_topic(topic):
            found.setdefault(namespace, set()).add(leaf)
    return {"action_servers": sorted(ns for ns, leaves in found.items() if len(leaves) == len(ACTION_TOPICS))}


async def _nodes(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return {"nodes": sorted(hub.graph.nodes)}


async def _node_details(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    node = str(args.get("node", ""))
    pubs, subs, srvs = await hub.node.master.get_system_state()
    return {
        "subscribing": sorted(t for t, ns in subs if node in ns),
        "publishing": sorted(t for t, ns in pubs if node in ns),
        "services": sorted(s for s, ns in srvs if node in ns),
    }


async def _publishers(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return await _members(hub, args, "publishers")


async def _subscribers(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return await _members(hub, args, "subscribers")


async def _members(hub: WebHub, args: dict[str, Any], kind: str) -> dict[str, Any]:
    pubs, subs, _ = await hub.node.master.get_system_state()
    topic = str(args.get("topic", ""))
    nodes = dict(pubs if kind == "publishers" else subs).get(topic, [])
    return {kind: sorted(nodes) if hub.policy.allows_topic(topic) else []}


# --- services ---------------------------------------------------------------------------------------------


async def _services(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return {"services": sorted(s for s in hub.graph.services if hub.policy.allows_service(s))}


async def _service_type_of(hub: WebHub, name: str) -> str:
    """The type the service's server gives (rosservice asks it with a probe), "" when unknown or hidden."""
    if not hub.policy.allows_service(name):
        return ""
    info = hub.services.get(name)
    if info is not None:
        return info.type
    if name not in hub.graph.services:
        return ""
    try:
        return await hub.probe_service_type(name)
    except (MrosError, OSError, TimeoutError):
        return ""


async def _service_type(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return {"type": await _service_type_of(hub, str(args.get("service", "")))}


async def _services_for_type(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    wanted = str(args.get("type", ""))
    return {"services": sorted(s.name for s in hub.services.values() if s.type == wanted)}


async def _service_providers(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    """rosapi's field is named ``service`` but holds a service *type*: the nodes providing a service of it."""
    wanted = str(args.get("service", ""))
    _, _, srvs = await hub.node.master.get_system_state()
    providers: list[str] = []
    for name, nodes in srvs:
        info = hub.services.get(name)
        if info is not None and info.type == wanted and hub.policy.allows_service(name):
            providers += nodes
    return {"providers": providers}


async def _service_node(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    _, _, srvs = await hub.node.master.get_system_state()
    service = str(args.get("service", ""))
    providers = sorted(dict(srvs).get(service, [])) if hub.policy.allows_service(service) else []
    return {"node": providers[0] if providers else ""}


async def _service_host(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    """The host part of the service's ``rosrpc://host:port`` URI, "" when the master does not know it."""
    service = str(args.get("service", ""))
    if not hub.policy.allows_service(service):
        return {"host": ""}
    try:
        uri = await hub.node.master.lookup_service(service)
    except MasterError:
        return {"host": ""}
    rest = uri.removeprefix("rosrpc://")
    return {"host": rest[: rest.find(":")] if ":" in rest else rest}


# --- types ------------------------------------------------------------------------------------------------


def typedefs(msg_type: str, half: str = "") -> list[dict[str, Any]]:
    """rosapi's typedefs of ``msg_type`` and every type it holds, depth first, each once (``half``:
    ``Request`` or ``Response`` of the service type ``msg_type``).

    Raises:
        MsgError: the type (or one it uses) is not on the type search path (the message says where it looked).
    """
    from mrosd.msg.loader import default_store

    store = default_store()
    seen: set[str] = set()
    if half:
        srv = store.srv_spec(msg_type)
        return _subtypedefs(store, _typedef(srv.request if half == "Request" else srv.response), seen)
    return _typedefs(store, msg_type, seen)


def _typedefs(store: Any, msg_type: str, seen: set[str]) -> list[dict[str, Any]]:
    if msg_type in seen:
        return []
    seen.add(msg_type)
    if msg_type in _ATOMICS or msg_type in ("string", "char"):
        return []
    if msg_type in _SPECIALS:
        typedef = {
            "type": msg_type,
            "fieldnames": ["secs", "nsecs"],
            "fieldtypes": ["int32", "int32"],
            "fieldarraylen": [-1, -1],
            "examples": ["0", "0"],
            "constnames": [],
            "constvalues": [],
        }
        return _subtypedefs(store, typedef, seen)
    return _subtypedefs(store, _typedef(store.msg_spec(msg_type)), seen)


def _subtypedefs(store: Any, typedef: dict[str, Any], seen: set[str]) -> list[dict[str, Any]]:
    out = [typedef]
    for field_type in typedef["fieldtypes"]:
        out += _typedefs(store, field_type, seen)
    return out


#: ``str()`` of a scalar field's default, as rospy makes it.
_EXAMPLES = {"bool": "False", "string": "", "float32": "0.0", "float64": "0.0"}


def _typedef(spec: MsgSpec) -> dict[str, Any]:
    examples = []
    for f in spec.fields:
        if f.is_array:
            examples.append("[]")
        elif f.base in _ATOMICS or f.base in _EXAMPLES or f.base == "char":
            examples.append(_EXAMPLES.get(f.base, "0"))
        else:
            examples.append("{}")
    constants = sorted(spec.constants, key=lambda c: c.name)
    return {
        "type": spec.full_name,
        "fieldnames": [f.name for f in spec.fields],
        "fieldtypes": [f.base for f in spec.fields],
        "fieldarraylen": [(-1 if not f.is_array else (f.length if f.length is not None else 0)) for f in spec.fields],
        "examples": examples,
        "constnames": [c.name for c in constants],
        "constvalues": [str(c.value) for c in constants],
    }


async def _message_details(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return {"typedefs": typedefs(str(args.get("type", "")))}


async def _request_details(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return {"typedefs": typedefs(str(args.get("type", "")), "Request")}


async def _response_details(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return {"typedefs": typedefs(str(args.get("type", "")), "Response")}


# --- parameters and time -----------------------------------------------------------------------------------


def _param_name(hub: WebHub, args: dict[str, Any]) -> str:
    text = str(args.get("name", ""))
    name = text if text.startswith("/") else "/" + text
    if not hub.policy.allows_param(name):
        raise MrosError(f"parameter {name} is not allowed by the [web] params allow-list")
    return name


async def _get_param(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    name = _param_name(hub, args)
    try:
        value = await hub.node.master.get_param(name)
    except MrosError:
        default = args.get("default", "")
        return {"value": default if default != "" else "null"}
    return {"value": json.dumps(value, default=_json_default)}


async def _set_param(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    name = _param_name(hub, args)
    try:
        value = rb.decode_value(str(args.get("value", "null")))  # depth-bounded: a client's text
    except ValueError as exc:
        raise MrosError(f"set_param {name}: value is not JSON: {exc}") from None
    await hub.node.master.set_param(name, value)
    return {}


async def _has_param(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return {"exists": await hub.node.master.has_param(_param_name(hub, args))}


async def _delete_param(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    await hub.node.master.delete_param(_param_name(hub, args))
    return {}


async def _search_param(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    text = str(args.get("name", ""))
    found = await hub.node.master.search_param(text if text.startswith("/") else "/" + text)
    return {"global_name": found or ""}


async def _get_param_names(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    return {"names": [n for n in await hub.node.master.get_param_names() if hub.policy.allows_param(n)]}


async def _get_time(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    now = hub.clock_ns if hub.sim_time else time.time_ns()
    return {"time": {"secs": now // 1_000_000_000, "nsecs": now % 1_000_000_000}}


async def _get_ros_version(hub: WebHub, args: dict[str, Any]) -> dict[str, Any]:
    """ROS 1 and the master's ``/rosdistro`` (roslaunch sets it, with a newline), "" when it is unset."""
    try:
        distro = await hub.node.master.get_param("/rosdistro")
    except MrosError:
        distro = ""
    return {"version": 1, "distro": str(distro).strip() if isinstance(distro, str) else ""}


def _json_default(value: Any) -> Any:
    if isinstance(value, bytes | bytearray):
        import base64

        return base64.b64encode(value).decode()
    raise TypeError(f"cannot encode {type(value).__name__}")


_HANDLERS: dict[str, Callable[[WebHub, dict[str, Any]], Awaitable[dict[str, Any]]]] = {
    "topics": _topics,
    "topics_and_raw_types": _topics_and_raw_types,
    "topic_type": _topic_type,
    "topics_for_type": _topics_for_type,
    "action_servers": _action_servers,
    "nodes": _nodes,
    "node_details": _node_details,
    "publishers": _publishers,
    "subscribers": _subscribers,
    "services": _services,
    "service_type": _service_type,
    "services_for_type": _services_for_type,
    "service_providers": _service_providers,
    "service_node": _service_node,
    "service_host": _service_host,
    "message_details": _message_details,
    "service_request_details": _request_details,
    "service_response_details": _response_details,
    "get_param": _get_param,
    "set_param": _set_param,
    "has_param": _has_param,
    "delete_param": _delete_param,
    "search_param": _search_param,
    "get_param_names": _get_param_names,
    "get_time": _get_time,
    "get_ros_version": _get_ros_version,
}
