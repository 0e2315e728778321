"""ROS 1 messages: parse .msg/.srv, genmsg-exact md5s, fast msgspec classes, runtime types from headers.

Re-exports only; see docs/messages.md for the API and the ROS -> Python type mapping.
"""

from mrosd.msg.loader import ServiceClass, get_message_class, get_service_class, load_type
from mrosd.msg.loading import load_type_async
from mrosd.msg.time import Duration, Time
from mrosd.msg.typestore import TypeStore

__all__ = [
    "Duration",
    "ServiceClass",
    "Time",
    "TypeStore",
    "get_message_class",
    "get_service_class",
    "load_type",
    "load_type_async",
]
