"""``mros bag info`` text: a bag's summary laid out as Debian's ``rosbag info`` prints it.

Pure: ``format_info`` turns a ``BagSummary`` (gathered by ``mrosd.bag.files``) into text. The layout is
rosbag's: a label column as wide as the longest label plus one, times as local time with two decimals and
the raw seconds in brackets, sizes in binary KB/MB/GB with one decimal, one row per type (md5 in brackets)
and per topic (count, ``msgs``/``msg ``, type, and the connection count when there are several).
"""

from __future__ import annotations

import time

import msgspec


class ChunkSummary(msgspec.Struct, frozen=True):
    """One chunk's compression and sizes (rosbag v2 chunk header)."""

    compression: str
    uncompressed: int
    compressed: int


class TopicSummary(msgspec.Struct, frozen=True):
    """A topic of the bag: its type (of the first connection), message count and number of connections."""

    topic: str
    type: str
    messages: int
    connections: int = 1


class BagSummary(msgspec.Struct, frozen=True):
    """What ``rosbag info`` shows about one bag; times in nanoseconds, sizes in bytes."""

    path: str
    version: str
    size: int
    start_ns: int | None
    end_ns: int | None
    messages: int
    chunks: list[ChunkSummary]
    types: dict[str, str]  # type -> md5sum
    topics: list[TopicSummary]


def human_size(size: float) -> str:
    """rosbag's size text: binary units from KB up, one decimal (``13.1 KB``)."""
    for suffix in ("KB", "MB", "GB", "TB", "PB", "EB", "ZB", "YB"):
        size /= 1024.0
        if size < 1024.0:
            return f"{size:.1f} {suffix}"
    return "-"


def time_text(secs: float) -> str:
    """rosbag's local date with two decimals of seconds: ``Nov 23 2026 12:57:31.06``."""
    frac = f"{secs - int(secs):.2f}"[1:]
    return time.strftime("%b %d %Y %H:%M:%S", time.localtime(secs)) + frac


def duration_text(duration: float) -> str:
    """``2.5s``, ``1:05s (65s)`` or ``1hr 0:05s (3605s)`` as rosbag prints a bag's length."""
    secs = duration % 60
    mins = int(duration / 60)
    hours = int(mins / 60)
    if hours > 0:
        return "%dhr %d:%02ds (%ds)" % (hours, mins % 60, secs, duration)  # noqa: UP031  (rosbag's %d rounding)
    if mins > 0:
        return "%d:%02ds (%ds)" % (mins, secs, duration)  # noqa: UP031
    return f"{duration:.1f}s"


def _compression_rows(chunks: list[ChunkSummary], duration: float) -> list[tuple[str, str]]:
    if not chunks:
        return [("compression", "none")]
    counts: dict[str, list[int]] = {}
    for chunk in chunks:
        entry = counts.setdefault(chunk.compression, [0, 0, 0])
        entry[0] += 1
        entry[1] += chunk.uncompressed
        entry[2] += chunk.compressed
    parts = []
    for name, (count, unc, comp) in sorted(counts.items(), key=lambda kv: (kv[1][0], kv[0]), reverse=True):
        if name == "none":
            parts.append(f"{name} [{count}/{len(chunks)} chunks]")
        else:
            parts.append(f"{name} [{count}/{len(chunks)} chunks; {100.0 * comp / unc if unc else 0.0:.2f}%]")
    rows = [("compression", ", ".join(parts))]
    if any(name != "none" for name in counts):
        total_unc = sum(c.uncompressed for c in chunks)
        total_comp = sum(c.compressed for c in chunks)
        unc_s, comp_s = human_size(total_unc), human_size(total_comp)
        width = max(len(unc_s), len(comp_s))
        if duration > 0:
            unc_r, comp_r = human_size(total_unc / duration), human_size(total_comp / duration)
            rwidth = max(len(unc_r), len(comp_r))
            ratio = 100.0 * total_comp / total_unc if total_unc else 0.0
            rows.append(("uncompressed", f"{unc_s:>{width}} @ {unc_r:>{rwidth}}/s"))
            rows.append(("compressed", f"{comp_s:>{width}} @ {comp_r:>{rwidth}}/s ({ratio:.2f}%)"))
        else:
            rows.append(("uncompressed", f"{unc_s:>{width}}"))
            rows.append(("compressed", f"{comp_s:>{width}}"))
    return rows


def format_info(summary: BagSummary) -> str:
    """The text ``rosbag info BAG`` prints for ``summary`` (no trailing newline)."""
    rows: list[tuple[str, str]] = [("path", summary.path), ("version", summary.version)]
    if summary.start_ns is None or summary.end_ns is None:
        rows.append(("size", human_size(summary.size)))
    else:
        start, end = summary.start_ns / 1e9, summary.end_ns / 1e9
        duration = end - start
        rows.append(("duration", duration_text(duration)))
        rows.append(("start", f"{time_text(start)} ({start:.2f})"))
        rows.append(("end", f"{time_text(end)} ({end:.2f})"))
        rows.append(("size", human_size(summary.size)))
        rows.append(("messages", str(summary.messages)))
        rows.extend(_compression_rows(summary.chunks, duration))
        type_width = max((len(t) for t in summary.types), default=0)
        for i, msg_type in enumerate(sorted(summary.types)):
            rows.append(("types" if i == 0 else "", f"{msg_type:<{type_width}} [{summary.types[msg_type]}]"))
        topics = sorted(summary.topics, key=lambda t: t.topic)
        topic_width = max((len(t.topic) for t in topics), default=0)
        count_width = max((len(str(t.messages)) for t in topics), default=0)
        for i, t in enumerate(topics):
            text = f"{t.topic:<{topic_width}}   {t.messages:>{count_width}} {'msgs' if t.messages > 1 else 'msg '}"
            text += f"    : {t.type:<{type_width}}"
            if t.connections > 1:
                text += f" ({t.connections} connections)"
            rows.append(("topics" if i == 0 else "", text))
    width = max(len(label) for label, _ in rows) + 1
    lines = [f"{(label + ':') if label else '':<{width}} {value}" for label, value in rows]
    return "\n".join(lines).rstrip()
