"""tf2_web_republisher's rules as plain data: request checks, thresholds, per-subscription state, rate, timeouts.

No I/O here; ``mrosd.tf.republish_node`` runs it on a Node. The rules are tf2_web_republisher's
(``tf_web_republisher.cpp`` and ``tf_pair.h``, RobotWebTools, 0.3.2), restated:

- each subscription is a list of source frames, one target frame, an angular and a translational threshold
  and a rate; frame ids lose one leading ``/``;
- every ``1 / rate`` seconds each source frame is looked up in the target frame at time 0 (the latest common
  time); a frame is sent when this is its first transmission, or either threshold is 0, or its origin moved
  more than ``trans_thres`` (Euclidean distance) or its rotation more than ``angular_thres`` since the
  transform last *sent* (tf's ``Quaternion::angle``: the half angle, ``acos(dot / |a||b|)``, no shortest path);
- a lookup that fails sends nothing for that frame; the failure is reported once, and the recovery once
  (tf2_web_republisher logs both); unlike tf2_web_republisher, a frame never looked up successfully is never
  sent (it sends an uninitialised transform on its first tick);
- a service subscription's topic is dropped once it has had no subscriber for ``timeout`` (its one-shot timer is
  started at creation and on a tick without subscribers, stopped on a tick with some).

What tf2_web_republisher leaves unbounded is bounded here (``Limits``): frames per subscription, name length,
subscriptions in all, rate and timeout (clamped); rate 0, NaN or negative thresholds are refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from mrosd.errors import RequestRefused
from mrosd.tf.core import Pose, TransformError

#: Source frames one subscription may ask for (a big URDF has a few hundred links).
MAX_FRAMES = 1000
#: Bytes of one frame id (tf2 has no bound; real ids are tens of bytes).
MAX_FRAME_NAME = 1024
#: Subscriptions (service topics and action goals) held at once, for all clients.
MAX_SUBSCRIPTIONS = 100
#: Source frames looked up per tick over all subscriptions together.
MAX_TOTAL_FRAMES = 10_000
#: Rates are clamped into this range (Hz): a browser draws at most 60 frames a second.
MIN_RATE = 0.01
MAX_RATE = 100.0
#: A service topic's unused timeout is clamped into this range (s); tf2_web_republisher takes any, and 0
#: unadvertises the topic before the client can subscribe.
MIN_TOPIC_TIMEOUT = 1.0
MAX_TOPIC_TIMEOUT = 60.0
#: An action goal whose feedback topic has had no subscriber this long ends (its client is gone; tf2_web_
#: republisher keeps such a goal for ever).
GOAL_IDLE_TIMEOUT = 10.0


@dataclass(frozen=True)
class Limits:
    """The bounds a ``Republisher`` applies; the defaults are the module's constants."""

    max_frames: int = MAX_FRAMES
    max_frame_name: int = MAX_FRAME_NAME
    max_subscriptions: int = MAX_SUBSCRIPTIONS
    max_total_frames: int = MAX_TOTAL_FRAMES
    min_rate: float = MIN_RATE
    max_rate: float = MAX_RATE
    min_topic_timeout: float = MIN_TOPIC_TIMEOUT
    max_topic_timeout: float = MAX_TOPIC_TIMEOUT


@dataclass(frozen=True)
class Request:
    """One checked request: cleaned frame ids (in order, each once) and the clamped rate."""

    source_frames: tuple[str, ...]
    target_frame: str
    angular_thres: float
    trans_thres: float
    rate: float

    @property
    def period(self) -> float:
        return 1.0 / self.rate


def clean_frame(frame: str) -> str:
    """tf2_web_republisher's ``cleanTfFrame``: one leading ``/`` removed."""
    return frame[1:] if frame.startswith("/") else frame


def _finite(value: float, what: str) -> float:
    value = float(value)
    if not math.isfinite(value):
        raise RequestRefused(f"tf2_web_republisher: {what} must be a finite number, not {value}")
    return value


def check_request(
    source_frames: Sequence[str],
    target_frame: str,
    angular_thres: float,
    trans_thres: float,
    rate: float,
    *,
    limits: Limits = Limits(),
) -> Request:
    """A client's request -> ``Request``, or a refusal saying what to fix.

    Raises:
        RequestRefused: too many frames, an empty or too long frame id, a threshold that is NaN, infinite or
            negative, a rate that is not a positive finite number.
    """
    if len(source_frames) > limits.max_frames:
        raise RequestRefused(
            f"tf2_web_republisher: {len(source_frames)} source frames asked; at most {limits.max_frames}"
        )
    frames: dict[str, None] = {}
    for raw in (*source_frames, target_frame):
        if len(raw) > limits.max_frame_name:
            raise RequestRefused(
                f"tf2_web_republisher: a frame id of {len(raw)} characters; at most {limits.max_frame_name}"
            )
        if not clean_frame(raw):
            raise RequestRefused("tf2_web_republisher: empty frame id")
    for raw in source_frames:
        frames.setdefault(clean_frame(raw))
    angular = _finite(angular_thres, "angular_thres")
    trans = _finite(trans_thres, "trans_thres")
    if angular < 0 or trans < 0:
        raise RequestRefused("tf2_web_republisher: thresholds must not be negative")
    hz = _finite(rate, "rate")
    if hz <= 0:
        raise RequestRefused(f"tf2_web_republisher: rate must be above 0 Hz, not {hz}")
    hz = min(max(hz, limits.min_rate), limits.max_rate)
    return Request(tuple(frames), clean_frame(target_frame), angular, trans, hz)


def clamp_timeout(seconds: float, limits: Limits = Limits()) -> float:
    """A service topic's unused timeout, clamped; a NaN or negative one is the minimum."""
    if not math.isfinite(seconds):
        return limits.max_topic_timeout if seconds > 0 else limits.min_topic_timeout
    return min(max(seconds, limits.min_topic_timeout), limits.max_topic_timeout)


def distance(a: Pose, b: Pose) -> float:
    return math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)


def half_angle(a: Pose, b: Pose) -> float:
    """tf's ``Quaternion::angle``: acos of the normalised dot product (the *half* angle, no shortest path)."""
    dot = a[3] * b[3] + a[4] * b[4] + a[5] * b[5] + a[6] * b[6]
    norms = math.sqrt((a[3] ** 2 + a[4] ** 2 + a[5] ** 2 + a[6] ** 2) * (b[3] ** 2 + b[4] ** 2 + b[5] ** 2 + b[6] ** 2))
    if norms == 0.0:
        return 0.0  # tf divides by zero here; the NaN it gets compares false, as 0 does
    return math.acos(min(1.0, max(-1.0, dot / norms)))


@dataclass
class FramePair:
    """One source frame of a subscription (tf2_web_republisher's ``TFPair``)."""

    source: str
    sent: Pose | None = None
    ok: bool = True

    def update_needed(self, pose: Pose, angular_thres: float, trans_thres: float) -> bool:
        """After a successful lookup: send ``pose``? (``TFPair::updateNeeded``.)"""
        return (
            self.sent is None
            or trans_thres == 0.0
            or angular_thres == 0.0
            or distance(self.sent, pose) > trans_thres
            or half_angle(self.sent, pose) > angular_thres
        )


@dataclass
class Tick:
    """What one tick of a subscription yields: the transforms to send (source frame, target <- source), and
    the frames whose lookup broke or works again since the last tick (each logged once)."""

    transforms: list[tuple[str, Pose]] = field(default_factory=list)
    broke: list[tuple[str, str]] = field(default_factory=list)
    recovered: list[str] = field(default_factory=list)


Lookup = Callable[[str, str], Pose]


@dataclass
class Subscription:
    """One client subscription: its request, its frames' state, its next tick and (service topics) its unused
    timer. Times are the caller's monotonic seconds."""

    id: int
    request: Request
    created: float
    #: a service topic's unused timeout (None: an action goal, whose idle rule the caller applies)
    timeout: float | None = None
    pairs: list[FramePair] = field(default_factory=list)
    next_tick: float = 0.0
    idle_since: float | None = None

    def __post_init__(self) -> None:
        self.pairs = [FramePair(source) for source in self.request.source_frames]
        self.next_tick = self.created + self.request.period
        self.idle_since = self.created  # tf2_web_republisher's unsub timer starts with the topic

    def tick(self, lookup: Lookup, now: float) -> Tick:
        """Look every frame up (``lookup(target, source)``, raising ``TransformError``) and choose what to send;
        the next tick is one period after the one due (or after ``now`` when a whole period was missed)."""
        out = Tick()
        request = self.request
        for pair in self.pairs:
            try:
                pose = lookup(request.target_frame, pair.source)
            except TransformError as exc:
                if pair.ok:
                    pair.ok = False
                    out.broke.append((pair.source, str(exc)))
                continue
            if not pair.ok:
                pair.ok = True
                out.recovered.append(pair.source)
            if pair.update_needed(pose, request.angular_thres, request.trans_thres):
                pair.sent = pose
                out.transforms.append((pair.source, pose))
        self.next_tick += request.period
        if self.next_tick <= now:
            self.next_tick = now + request.period
        return out

    def observe_subscribers(self, count: int, now: float, timeout: float) -> bool:
        """The topic's subscriber count at ``now``: True when it has had none for ``timeout`` seconds."""
        if count > 0:
            self.idle_since = None
            return False
        if self.idle_since is None:
            self.idle_since = now
        return now - self.idle_since >= timeout

    def next_wake(self) -> float:
        """When the caller should come back: the next tick, or the unused timer's expiry if sooner."""
        if self.timeout is not None and self.idle_since is not None:
            return min(self.next_tick, self.idle_since + self.timeout)
        return self.next_tick


@dataclass
class Republisher:
    """Every subscription, with the global bounds; ids count up for service topics and goals together, as
    tf2_web_republisher's ``client_ID_count_`` (a service topic is ``~tf_repub_<id>``)."""

    limits: Limits = field(default_factory=Limits)
    subscriptions: dict[int, Subscription] = field(default_factory=dict)
    next_id: int = 0

    @property
    def total_frames(self) -> int:
        return sum(len(s.pairs) for s in self.subscriptions.values())

    def add(self, request: Request, now: float, timeout: float | None = None) -> Subscription:
        """Hold a new subscription.

        Raises:
            RequestRefused: ``max_subscriptions`` are held, or its frames would pass ``max_total_frames``.
        """
        if len(self.subscriptions) >= self.limits.max_subscriptions:
            raise RequestRefused(
                f"tf2_web_republisher: {len(self.subscriptions)} subscriptions are held, the most there may be; "
                "an unused topic is dropped after its timeout, a goal when it is cancelled"
            )
        if self.total_frames + len(request.source_frames) > self.limits.max_total_frames:
            raise RequestRefused(
                f"tf2_web_republisher: {self.total_frames} frames are republished; {len(request.source_frames)} more "
                f"would pass the bound of {self.limits.max_total_frames}"
            )
        sub = Subscription(self.next_id, request, now, timeout)
        self.next_id += 1
        self.subscriptions[sub.id] = sub
        return sub

    def remove(self, sub_id: int) -> None:
        self.subscriptions.pop(sub_id, None)


def topic_name(node_name: str, sub_id: int) -> str:
    """The service's topic: ``~tf_repub_<id>`` of the republisher node."""
    return f"{node_name.rstrip('/')}/tf_repub_{sub_id}"
