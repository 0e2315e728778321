"""A ROS 1 service type as rmw_zenoh names and hashes it: ``pkg/X`` -> ``pkg/srv/X``, its RIHS01 (pure but for
rosbags' tables).

rmw_zenoh puts a service on the key and token of the *service* type (``pkg::srv::dds_::X_``, its hash), not of
its request or response. ROS 2 hashes a service as a type of three fields, ``request_message``
(``pkg/srv/X_Request``), ``response_message`` (``pkg/srv/X_Response``) and ``event_message``
(``pkg/srv/X_Event``: ``service_msgs/ServiceEventInfo info``, ``X_Request[<=1] request``,
``X_Response[<=1] response``); rosbags' Jazzy store knows ``service_msgs`` but no ``srv`` type, so the request
and response are derived from the ROS 1 definitions (as custom messages are) and the two wrappers registered
beside them. Checked against rmw_zenoh's design document (``example_interfaces/srv/AddTwoInts`` is
``RIHS01_e118de6b...``) and zenoh-ros2-sdk's own hashing.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import msgspec

from mrosd.ros2.types import UnmappableTypeError

if TYPE_CHECKING:
    from mrosd.ros2.types import TypeMapper

__all__ = [
    "ServiceMapping",
    "ros1_service_for",
    "ros1_service_name",
    "ros2_service_for",
    "ros2_service_name",
    "service_mapping",
]

#: what ROS 2 Humble puts where a type hash goes (rmw_zenoh's humble branch: keys and tokens)
HUMBLE_TYPE_HASH = "TypeHashNotSupported"


class ServiceMapping(msgspec.Struct, frozen=True):
    """How one ROS 1 service type crosses: the ROS 2 service, request and response names and the hash."""

    ros1_type: str
    ros2_type: str
    type_hash: str
    request_type: str
    response_type: str


def ros2_service_name(ros1_type: str) -> str:
    """``pkg/X`` -> ``pkg/srv/X``.

    Raises:
        UnmappableTypeError: not a ``pkg/X`` name.
    """
    parts = ros1_type.split("/")
    if len(parts) != 2 or not all(parts):
        raise UnmappableTypeError(f"ros2: {ros1_type!r} is not a ROS 1 service type name (pkg/Type)")
    return f"{parts[0]}/srv/{parts[1]}"


def ros1_service_name(ros2_type: str) -> str:
    """``pkg/srv/X`` -> ``pkg/X``.

    Raises:
        ValueError: not a ``pkg/srv/X`` name.
    """
    parts = ros2_type.split("/")
    if len(parts) != 3 or parts[1] != "srv" or not parts[0] or not parts[2]:
        raise ValueError(f"not a ROS 2 service type: {ros2_type!r}")
    return f"{parts[0]}/{parts[2]}"


def ros2_service_for(mapper: TypeMapper, ros1_type: str) -> str:
    """The ROS 2 service type of ROS 1's ``pkg/X``: by a service or package mapping rule, else ``pkg/srv/X``.

    Raises:
        UnmappableTypeError: not a ``pkg/X`` name.
    """
    ruled = mapper.rules.ros2_service(ros1_type) if mapper.rules else None
    return ruled or ros2_service_name(ros1_type)


def ros1_service_for(mapper: TypeMapper, ros2_type: str) -> str:
    """The ROS 1 service type of ROS 2's ``pkg/srv/X``: by a service or package mapping rule, else ``pkg/X``.

    Raises:
        ValueError: not a ``pkg/srv/X`` name.
    """
    ruled = mapper.rules.ros1_service(ros2_type) if mapper.rules else None
    return ruled or ros1_service_name(ros2_type)


def _message(mapper: TypeMapper, ros1_name: str, ros2_name: str, definition: str) -> None:
    store = mapper.store
    if ros2_name in store.types:
        return
    if definition.strip():
        mapper.mapping(ros1_name, definition, ros2_type=ros2_name)
    else:  # an empty request (std_srvs/Trigger): no definition to parse
        store.register({ros2_name: ([], [])})


#: the ROS 2 type every service's event message holds
EVENT_INFO = "service_msgs/msg/ServiceEventInfo"


def _fix_event_info(store: Any) -> None:
    """rosidl turns the ``char[16] client_gid`` of ``ServiceEventInfo.msg`` into ``uint8[16]`` (the .msg ``char``
    is IDL ``uint8``), and hashes it so; rosbags keeps ``char``, whose type id gives every service another
    hash. Same bytes on the wire, so this store (one per ``TypeMapper``) is corrected in place."""
    from rosbags.interfaces import Nodetype

    consts, fields = store.fielddefs[EVENT_INFO]
    fixed = [
        (name, (Nodetype.ARRAY, ((Nodetype.BASE, ("uint8", 0)), desc[1][1])))
        if desc[0] == Nodetype.ARRAY and desc[1][0] == (Nodetype.BASE, ("char", 0))
        else (name, desc)
        for name, desc in fields
    ]
    store.fielddefs[EVENT_INFO] = (consts, fixed)


def service_mapping(
    mapper: TypeMapper, ros1_type: str, request_definition: str, response_definition: str
) -> ServiceMapping:
    """The ROS 2 form of service ``ros1_type`` whose request and response are the ROS 1 definitions given (full
    texts, nested ``MSG:`` sections included); registered in ``mapper``'s store so bodies convert. A service
    mapping rule renames the type (``ros2_service_for``) and the request's and response's fields.

    Raises:
        UnmappableTypeError: a field ROS 2 cannot have, or a definition that does not parse.
    """
    from rosbags.interfaces import Nodetype

    srv = ros2_service_for(mapper, ros1_type)
    request, response, event = srv + "_Request", srv + "_Response", srv + "_Event"
    _message(mapper, ros1_type + "Request", request, request_definition)
    _message(mapper, ros1_type + "Response", response, response_definition)
    store: Any = mapper.store
    _fix_event_info(store)
    fresh: dict[str, Any] = {}
    if event not in store.types:
        fresh[event] = (
            [],
            [
                ("info", (Nodetype.NAME, "service_msgs/msg/ServiceEventInfo")),
                ("request", (Nodetype.SEQUENCE, ((Nodetype.NAME, request), 1))),
                ("response", (Nodetype.SEQUENCE, ((Nodetype.NAME, response), 1))),
            ],
        )
    if srv not in store.types:
        fresh[srv] = (
            [],
            [
                ("request_message", (Nodetype.NAME, request)),
                ("response_message", (Nodetype.NAME, response)),
                ("event_message", (Nodetype.NAME, event)),
            ],
        )
    try:
        if fresh:
            store.register(fresh)
        type_hash = store.hash_rihs01(srv)
    except Exception as exc:  # rosbags' own errors
        raise UnmappableTypeError(f"ros2: service {ros1_type}: no RIHS01 hash: {exc}") from exc
    return ServiceMapping(ros1_type, srv, type_hash, request, response)
