"""Per-robot tf frame names: ``/tf`` and ``/tf_static`` from another robot get its name before their frames.

Two robots both publish ``odom -> base_link``; merged into one tf tree they fight over the same frames.
Renaming the topic (``/robot1/tf``) keeps them apart on the wire, and prefixing the frames
(``robot1/odom -> robot1/base_link``) lets an operator remap both into one ``/tf`` and see two robots. Pure.
"""

from __future__ import annotations

from typing import Any

from mrosd.fleet.keys import topic_chunks

#: The remote topics whose frames are prefixed (their type must be tf2_msgs/TFMessage).
TF_TOPICS = frozenset({"/tf", "/tf_static"})
TF_TYPE = "tf2_msgs/TFMessage"


def prefixed_frame(robot: str, frame: str) -> str:
    """``robot/frame`` (a leading ``/`` of the old tf convention dropped); an empty frame stays empty."""
    frame = frame.lstrip("/")
    if not frame or frame.startswith(robot + "/"):
        return frame
    return f"{robot}/{frame}"


def _tf_class() -> Any:
    from mrosd.msg import get_message_class

    return get_message_class(TF_TYPE)


def prefix_tf_frames(body: bytes, robot: str) -> bytes:
    """The TFMessage ``body`` with every ``header.frame_id`` and ``child_frame_id`` under ``robot/``.

    Raises:
        DeserializationError: ``body`` is not a TFMessage (the caller drops it and counts it).
    """
    cls = _tf_class()
    msg = cls.deserialize(body)
    for t in msg.transforms:
        t.header.frame_id = prefixed_frame(robot, t.header.frame_id)
        t.child_frame_id = prefixed_frame(robot, t.child_frame_id)
    return bytes(msg.serialize())


def wants_tf_prefix(remote_topic: str, msg_type: str) -> bool:
    """True for a remote robot's /tf or /tf_static of type tf2_msgs/TFMessage."""
    return msg_type == TF_TYPE and "/" + topic_chunks(remote_topic) in TF_TOPICS
