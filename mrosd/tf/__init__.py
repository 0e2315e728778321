"""tf2 for asyncio: a ``Buffer`` fed by /tf and /tf_static, tf2's lookups and errors, and the broadcasters.

Re-exports only; see docs/tf.md.
"""

from mrosd.tf.buffer import Buffer, StaticTransformBroadcaster, TransformBroadcaster, transform_stamped
from mrosd.tf.core import (
    BufferCore,
    ConnectivityError,
    ExtrapolationError,
    FrameNotFoundError,
    InvalidArgumentError,
    TransformError,
)

__all__ = [
    "Buffer",
    "BufferCore",
    "ConnectivityError",
    "ExtrapolationError",
    "FrameNotFoundError",
    "InvalidArgumentError",
    "StaticTransformBroadcaster",
    "TransformBroadcaster",
    "TransformError",
    "transform_stamped",
]
