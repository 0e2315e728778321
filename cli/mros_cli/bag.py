"""``mros bag``: record, play and summarize bags as rosbag does, with no ROS install.

The command line follows ``rosbag record/play/info`` (same option letters where they exist); the work is
done by ``mrosd.bag``.
"""

from __future__ import annotations

import asyncio
import contextlib
import os
import sys
import time
from typing import TYPE_CHECKING, Any

import click

from mros_cli.main import error_text, master_uri, run
from mrosd.app import on_stop_signal
from mrosd.bag.model import DEFAULT_BUFFER_MB, DEFAULT_CLOCK_HZ, BagError, SplitPolicy, parse_duration
from mrosd.errors import MrosError

if TYPE_CHECKING:
    from mrosd.bag.files import BagReader
    from mrosd.bag.recorder import RecordSink

MB = 1024 * 1024
#: How often the live status line of record is refreshed.
STATUS_PERIOD = 0.5


def _anonymous(name: str) -> str:
    return f"mros_{name}_{os.getpid()}_{int(time.time() * 1000)}"


@click.group(name="bag")
def group() -> None:
    """Record, play and inspect bags (like rosbag), as rosbag v2 (.bag) or MCAP files.

    \b
    Examples:
      mros bag record -a -O run1
      mros bag record /camera/image /odom --split --size 1024
      mros bag play run1.bag -r 2 --clock /odom:=/odom_replay
      mros bag info run1.bag
      mros topic echo -b run1.bag /odom
    """


def _status_enabled(flag: bool | None) -> bool:
    return sys.stderr.isatty() if flag is None else flag


# --- record -------------------------------------------------------------------------------------------


def _status_line(sink: RecordSink) -> None:
    stats = sink.stats
    path = stats.files[-1] if stats.files else ""
    sys.stderr.write(
        f"\rRecording to {path}: {stats.received} msgs, {stats.received_bytes / MB:.1f} MB, {stats.dropped} dropped   "
    )
    sys.stderr.flush()


async def _show_status(sink: RecordSink) -> None:
    while True:
        await asyncio.sleep(STATUS_PERIOD)
        _status_line(sink)


@group.command()
@click.argument("topics", nargs=-1)
@click.option("-a", "--all", "all_topics", is_flag=True, help="Record all topics, also those that appear later.")
@click.option("-e", "--regex", is_flag=True, help="TOPICS are regular expressions (matched as new topics appear).")
@click.option("-x", "--exclude", metavar="REGEX", help="Do not record topics matching REGEX.")
@click.option("-O", "--output-name", metavar="NAME", help="Record to NAME.bag.")
@click.option("-o", "--output-prefix", metavar="PREFIX", help="Record to PREFIX_<date>.bag.")
@click.option("--split", is_flag=True, help="Start a new file (NAME_1.bag, ...) when --size or --duration is reached.")
@click.option("--size", type=click.IntRange(min=1), metavar="MB", help="Maximum file size in MB.")
@click.option("--duration", metavar="DURATION", help="Maximum duration: 30, 30s, 5m, 2h.")
@click.option("--max-splits", type=click.IntRange(min=1), metavar="N", help="Keep only the N newest split files.")
@click.option(
    "-b", "--buffsize", type=click.IntRange(min=0), default=DEFAULT_BUFFER_MB, show_default=True, metavar="MB",
    help="Buffer between receiving and writing (0: unbounded); when full the oldest messages are dropped.",
)  # fmt: skip
@click.option("-j", "--bz2", is_flag=True, help="Compress chunks with bz2.")
@click.option("--lz4", is_flag=True, help="Compress chunks with lz4.")
@click.option("--format", "fmt", type=click.Choice(["bag", "mcap"]), default="bag", show_default=True)
@click.option("-l", "--limit", type=click.IntRange(min=1), metavar="N", help="Record only N messages per topic.")
@click.option("--status/--no-status", default=None, help="Live count on stderr (default: when stderr is a TTY).")
@click.option(
    "--poll-interval", type=click.FloatRange(min=0.05, max=60.0), default=1.0, show_default=True, metavar="SECONDS",
    help="With -a or -e: how often to ask the master for new topics.",
)  # fmt: skip
@click.option("-q", "--quiet", is_flag=True, help="No summary at the end (drops are still reported).")
def record(  # noqa: PLR0917  (one parameter per click option)
    topics: tuple[str, ...],
    all_topics: bool,
    regex: bool,
    exclude: str | None,
    output_name: str | None,
    output_prefix: str | None,
    split: bool,
    size: int | None,
    duration: str | None,
    max_splits: int | None,
    buffsize: int,
    bz2: bool,
    lz4: bool,
    fmt: str,
    limit: int | None,
    status: bool | None,
    poll_interval: float,
    quiet: bool,
) -> None:
    """Record topics to a bag until Ctrl-C (or --duration/--size): the bytes as received, untouched.

    \b
    Examples:
      mros bag record /chatter /odom
      mros bag record -a -x "/camera/.*" -O run1
      mros bag record -a --split --size 1024 -o logs/robot
      mros bag record /scan --duration 30s --format mcap
    """
    from mrosd.bag.files import EXTENSIONS, open_writer
    from mrosd.bag.model import output_stem, split_path
    from mrosd.bag.recorder import Recorder, RecordSink

    if not topics and not all_topics:
        raise click.UsageError("give topics to record, or -a for all topics")
    if bz2 and lz4:
        raise click.UsageError("choose one of -j/--bz2 and --lz4")
    if split and size is None and duration is None:
        raise click.UsageError("--split needs --size or --duration")
    seconds = parse_duration(duration) if duration is not None else None
    compression = "bz2" if bz2 else "lz4" if lz4 else "none"
    ext = EXTENSIONS[fmt]
    stem = output_stem(output_name, output_prefix, ext)

    def opener(index: int) -> Any:
        return open_writer(split_path(stem, ext, index if split else None), fmt, compression)

    async def main() -> RecordSink | None:
        from mrosd.tcpros import Node

        loop = asyncio.get_running_loop()
        stop = asyncio.Event()

        def on_full() -> None:
            with contextlib.suppress(RuntimeError):  # the loop may be gone already
                loop.call_soon_threadsafe(stop.set)

        sink: RecordSink | None = None
        status_task = None
        try:
            with on_stop_signal(stop.set):
                async with Node(_anonymous("record"), master_uri=master_uri(), argv=[]) as node:
                    # After the master answered (no empty file when it is down), before subscribing.
                    sink = RecordSink(
                        opener,
                        buffer_bytes=buffsize * MB,
                        split=SplitPolicy(
                            max_bytes=size * MB if size else None, max_seconds=seconds if split else None
                        ),
                        splitting=split,
                        max_splits=max_splits,
                        on_full=on_full,
                    )
                    recorder = Recorder(
                        node,
                        sink,
                        topics,
                        all_topics=all_topics,
                        regex=regex,
                        exclude=exclude,
                        poll_interval=poll_interval,
                        limit=limit,
                    )
                    if _status_enabled(status):
                        status_task = loop.create_task(_show_status(sink))
                    await recorder.run(stop, None if split else seconds)
        finally:
            if status_task is not None and sink is not None:
                status_task.cancel()
                _status_line(sink)  # the final counts
                sys.stderr.write("\n")
            if sink is not None:
                await asyncio.to_thread(sink.close)
        return sink

    sink = run(main())
    assert sink is not None  # main() raised otherwise
    stats = sink.stats
    if not quiet:
        where = ", ".join(stats.files)
        click.echo(f"Recorded {stats.written} messages ({stats.written_bytes / MB:.1f} MB) to {where}", err=True)
    if stats.dropped:
        click.echo(
            f"mros: warning: dropped {stats.dropped} of {stats.received} messages "
            f"(the writer fell behind; raise -b/--buffsize or write to a faster disk)",
            err=True,
        )


# --- play ---------------------------------------------------------------------------------------------


def _open_all(paths: list[str]) -> list[BagReader]:
    from mrosd.bag.files import open_bag

    readers: list[BagReader] = []
    try:
        for path in paths:
            readers.append(open_bag(path))
    except BaseException:
        for r in readers:
            r.close()
        raise
    return readers


@group.command(context_settings={"ignore_unknown_options": False})
@click.argument("args", nargs=-1, required=True, metavar="BAG... [/from:=/to ...]")
@click.option("-r", "--rate", type=click.FloatRange(min=0, min_open=True), default=1.0, show_default=True,
              help="Speed factor.")  # fmt: skip
@click.option("-l", "--loop", is_flag=True, help="Play again and again.")
@click.option("--clock", is_flag=True, help="Publish the bag time on /clock (rosgraph_msgs/Clock).")
@click.option("--hz", type=click.FloatRange(min=0, min_open=True), default=DEFAULT_CLOCK_HZ, show_default=True,
              help="Rate of /clock messages.")  # fmt: skip
@click.option("-s", "--start", type=click.FloatRange(min=0), default=0.0, metavar="SEC", help="Start SEC seconds in.")
@click.option("-u", "--duration", "play_duration", type=click.FloatRange(min=0, min_open=True), metavar="SEC",
              help="Play only SEC seconds of the bag.")  # fmt: skip
@click.option("-d", "--delay", type=click.FloatRange(min=0), default=0.2, show_default=True, metavar="SEC",
              help="Wait SEC seconds after advertising, for subscribers to connect.")  # fmt: skip
@click.option("--wait-for-subscribers", is_flag=True, help="Wait until every topic has a subscriber.")
@click.option("--topics", "only", multiple=True, metavar="TOPIC", help="Play only this topic (repeatable).")
@click.option("-q", "--quiet", is_flag=True, help="No progress line.")
def play(  # noqa: PLR0917
    args: tuple[str, ...],
    rate: float,
    loop: bool,
    clock: bool,
    hz: float,
    start: float,
    play_duration: float | None,
    delay: float,
    wait_for_subscribers: bool,
    only: tuple[str, ...],
    quiet: bool,
) -> None:
    """Publish the messages of one or more bags at their recorded pace, the stored bytes unchanged.

    Topics stored as latched are published latched. ``/from:=/to`` arguments rename topics.

    \b
    Examples:
      mros bag play run1.bag
      mros bag play run1.bag -r 0.5 -s 10 --clock
      mros bag play run1.bag -l /scan:=/scan_old
    """
    from mrosd.bag.model import parse_play_args
    from mrosd.bag.player import Player

    files, remaps = parse_play_args(args)
    if not files:
        raise click.UsageError("give at least one bag file")

    async def main() -> int:
        from mrosd.tcpros import Node

        readers = _open_all(files)
        loop_ = asyncio.get_running_loop()
        stop = asyncio.Event()
        try:
            with on_stop_signal(stop.set):
                async with Node(_anonymous("play"), master_uri=master_uri(), argv=[]) as node:
                    player = Player(
                        node,
                        readers,
                        rate=rate,
                        loop=loop,
                        start_offset=start,
                        duration=play_duration,
                        remaps=remaps,
                        clock=clock,
                        clock_hz=hz,
                        delay=delay,
                        wait_for_subscribers=wait_for_subscribers,
                        status=None if quiet else (sys.stderr if sys.stderr.isatty() else None),
                        topics=only,
                    )
                    task = loop_.create_task(player.run())
                    stopper = loop_.create_task(stop.wait())
                    await asyncio.wait({task, stopper}, return_when=asyncio.FIRST_COMPLETED)
                    stopper.cancel()
                    if not task.done():
                        task.cancel()
                        with contextlib.suppress(asyncio.CancelledError):
                            await task
                        return player.stats.published
                    return task.result().published
        finally:
            for r in readers:
                r.close()

    run(main())


# --- info ---------------------------------------------------------------------------------------------


@group.command()
@click.argument("bags", nargs=-1, required=True, metavar="BAG...")
def info(bags: tuple[str, ...]) -> None:
    """Summarize bags as rosbag info does: times, size, compression, types with md5, topics with counts.

    \b
    Examples:
      mros bag info run1.bag
      mros bag info logs/*.bag
    """
    from mrosd.bag.files import open_bag
    from mrosd.bag.info import format_info

    failed = False
    for i, path in enumerate(bags):
        try:
            reader = open_bag(path)
        except BagError as exc:
            click.echo(error_text(str(exc)), err=True)
            failed = True
            continue
        try:
            click.echo(format_info(reader.summary()))
        finally:
            reader.close()
        if i < len(bags) - 1:
            click.echo("---")
    if failed:
        sys.exit(1)


@group.command()
@click.argument("src", metavar="IN")
@click.argument("dst", metavar="OUT")
@click.option("--to", "to", type=click.Choice(["ros2", "ros1"]), required=True, help="the ROS of OUT")
@click.option(
    "--storage", type=click.Choice(["mcap", "sqlite3"]), default="mcap", show_default=True, help="rosbag2 storage"
)
@click.option("--mapping-rules", multiple=True, help="ros1_bridge mapping-rule YAML (repeatable)")
@click.option("--ros2-share", multiple=True, help="ROS 2 share tree with <pkg>/msg/*.msg (repeatable)")
@click.option("--progress/--no-progress", default=None, help="progress on stderr [default: on a terminal]")
def convert(  # noqa: PLR0917
    src: str,
    dst: str,
    to: str,
    storage: str,
    mapping_rules: tuple[str, ...],
    ros2_share: tuple[str, ...],
    progress: bool | None,
) -> None:
    """Convert a rosbag v2 into a rosbag2 (MCAP or sqlite3) with ROS 2 types, or back, as the ros2 bridge does.

    \b
    Examples:
      mros bag convert run1.bag run1_ros2 --to ros2
      mros bag convert run1_ros2 run1_back.bag --to ros1
    """
    from mrosd.ros2.bagconvert import convert_bag
    from mrosd.ros2.mapping import load_mapping_rules

    def show(done: int, total: int) -> None:
        sys.stderr.write(f"\rconverting {src}: {done}/{total} messages ({100 * done // max(total, 1)}%)   ")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()

    try:
        report = convert_bag(
            src,
            dst,
            to="ros2" if to == "ros2" else "ros1",
            storage="sqlite3" if storage == "sqlite3" else "mcap",
            progress=show if _status_enabled(progress) else None,
            rules=load_mapping_rules(mapping_rules),
            ros2_share=ros2_share,
        )
    except MrosError as exc:
        click.echo(error_text(str(exc)), err=True)
        sys.exit(1)
    for line in report.problems[:50]:
        click.echo(error_text(line), err=True)
    click.echo(f"{dst}: {report.written} messages written, {report.skipped} skipped")
