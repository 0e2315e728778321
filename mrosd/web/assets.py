"""Foxglove ``fetchAsset``: a ``package://<pkg>/<path>`` URI read from that ROS package, and from nowhere else.

What a client may read is what RViz loads to draw a robot (meshes, textures, URDFs), never the daemon's file
system, whatever the client sends and whatever an operator writes in the allow-list:

- only ``package://`` URIs. ``file://`` would serve any file the daemon can read (it often runs as root) and
  ``http(s)://`` would make it a proxy into the robot's network; foxglove_bridge serves both when its
  allow-list matches them, mrosd never does;
- the URI matches a ``[web] assets`` glob (``AccessPolicy.allows_asset``) and holds no ``..`` anywhere (as
  foxglove_bridge refuses it); the package is a plain name and each path segment a plain, non-empty name
  (no ``.``, backslash, control character, or empty segment that would make the path absolute);
- the package is looked up where the type search looks (``TypeStore.package_roots``: ``ROS_PACKAGE_PATH``,
  then ``/usr/share/<pkg>`` and ``/opt/ros/*/share/<pkg>``), and only a directory holding a ``package.xml``
  counts (``/usr/share/doc`` is on that path but is no ROS package);
- the file, every symlink resolved, stays inside the package's directory, is a regular file (a FIFO would
  block its reader, ``/dev/zero`` never ends: checked before it is opened, and again on the descriptor,
  opened non-blocking) and holds at most ``max_bytes``. It is read into a buffer sized from its ``fstat``,
  never past it: a file that grows or shrinks meanwhile is an error, not a bigger buffer.

Nothing here runs on the event loop but the checks of the URI: stat, open and read run in a pool of
``MAX_READS`` threads of its own (a slow disk holds those, not the loop nor the loop's default executor). The
bytes read and not yet written to a client count against one budget for the server (``budget_bytes``); a
request that does not fit waits for room (``BUDGET_WAIT`` s at most, then it is refused as busy). Each client
has one asset in flight at a time and a bounded number of requests waiting (``FoxgloveSession``).
"""

from __future__ import annotations

import asyncio
import io
import os
import re
import stat
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Final

from mrosd import backports
from mrosd.errors import RequestRefused
from mrosd.msg.typestore import TypeStore

__all__ = ["AssetReader", "AssetRef", "AssetRefused", "HeldAsset", "parse_asset_uri"]

#: Largest asset served (bytes); a bigger file is refused after its stat, before any of it is read.
MAX_ASSET_BYTES: Final = 64 * 1024 * 1024
#: Threads reading assets at once (their own pool).
MAX_READS: Final = 4
#: Seconds a request waits for room in the server's asset budget before it is refused as busy.
BUDGET_WAIT: Final = 10.0
#: Most path segments below the package (real meshes are a few levels deep).
MAX_SEGMENTS: Final = 64

SCHEME: Final = "package://"
#: A ROS package name as catkin accepts one (no dot, no slash: it becomes one directory name).
_PACKAGE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]*")
#: What no segment may hold: path separators other than "/", and control characters (NUL included).
_BAD_SEGMENT_CHAR = re.compile(r"[\\\x00-\x1f\x7f]")


class AssetRefused(RequestRefused):
    """A fetchAsset the server does not serve; the text goes back to the client in the error response."""


@dataclass(frozen=True, slots=True)
class AssetRef:
    """A checked ``package://`` URI: the package's name and the path below it, one plain name per segment."""

    package: str
    path: tuple[str, ...]


def parse_asset_uri(uri: str) -> AssetRef:
    """Split a ``package://<pkg>/<path>`` URI into names that cannot leave the package directory.

    Raises:
        AssetRefused: another scheme, ``..`` anywhere, an invalid package name, or an empty, ``.`` or
            unsafe path segment.
    """
    if not uri.startswith(SCHEME):
        scheme = uri.partition("://")[0] if "://" in uri else ""
        what = f"{scheme}:// URIs are" if scheme else "URIs without a scheme are"
        raise AssetRefused(f"{what} not served: only package://<package>/<path>")
    if ".." in uri:
        raise AssetRefused("'..' is not allowed in an asset URI")
    package, sep, rest = uri[len(SCHEME) :].partition("/")
    if not _PACKAGE.fullmatch(package):
        raise AssetRefused(f"invalid package name {package[:100]!r}")
    segments = tuple(rest.split("/")) if sep else ()
    if not segments or segments == ("",):
        raise AssetRefused("no path below the package")
    if len(segments) > MAX_SEGMENTS:
        raise AssetRefused(f"more than {MAX_SEGMENTS} path segments")
    for segment in segments:
        if segment in ("", ".") or _BAD_SEGMENT_CHAR.search(segment):
            raise AssetRefused(f"invalid path segment {segment[:100]!r}")
    return AssetRef(package, segments)


# --- blocking work, run in the reader's threads ---------------------------------------------------------


def _check_file(mode: int, size: int, max_bytes: int) -> None:
    if not stat.S_ISREG(mode):
        raise AssetRefused("not a regular file")
    if size > max_bytes:
        raise AssetRefused(f"larger than {max_bytes} bytes ({size} bytes)")


def _open_asset(store: TypeStore, ref: AssetRef, max_bytes: int) -> tuple[int, int]:
    """``(descriptor, size)`` of the asset's file in the first directory of the package that holds it."""
    packages = 0
    for root in store.package_roots(ref.package):
        if not (root / "package.xml").is_file():
            continue
        packages += 1
        try:
            real = os.path.realpath(root.joinpath(*ref.path), strict=True)
            base = os.path.realpath(root, strict=True)
        except OSError:
            continue  # not in this directory of the package (or a symlink loop): look in the next one
        if os.path.commonpath([real, base]) != base:
            raise AssetRefused("leaves its package (a symlink points outside it)")
        try:
            st = os.stat(real)
            _check_file(st.st_mode, st.st_size, max_bytes)  # before open: opening a FIFO or a device acts
            fd = os.open(real, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_NOCTTY | os.O_CLOEXEC)
        except OSError as exc:
            raise AssetRefused(f"cannot be read: {exc.strerror}") from None
        try:
            st = os.fstat(fd)  # what was opened, whatever the path points to now
            _check_file(st.st_mode, st.st_size, max_bytes)
        except BaseException:
            os.close(fd)
            raise
        return fd, st.st_size
    if not packages:
        raise AssetRefused(f"unknown package {ref.package!r}")
    raise AssetRefused(f"not found in package {ref.package}")


def _read_frame(fd: int, size: int, head: bytes) -> bytearray:
    """``head`` then the file's ``size`` bytes, in one buffer allocated once (the frame sent as is)."""
    frame = bytearray(len(head) + size)
    frame[: len(head)] = head
    with io.FileIO(fd, closefd=False) as f, memoryview(frame) as view:
        got = 0
        while got < size:
            n = f.readinto(view[len(head) + got :])
            if not n:
                raise AssetRefused("changed while it was read (shorter than its size)")
            got += n
        if f.read(1):
            raise AssetRefused("changed while it was read (longer than its size)")
    return frame


def _close_opened(opened: tuple[int, int] | None) -> None:
    if opened is not None:
        os.close(opened[0])


# --- the loop's side ------------------------------------------------------------------------------------


class _Budget:
    """Bytes of assets read and not yet written; ``acquire`` waits for room, bounded."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self.held = 0
        self._freed = asyncio.Event()

    async def acquire(self, size: int, timeout: float) -> None:
        try:
            async with backports.timeout(timeout):
                while self.held + size > self.limit:
                    self._freed.clear()
                    await self._freed.wait()
        except TimeoutError:
            raise AssetRefused(
                f"the server is busy sending other assets ({self.held} of {self.limit} bytes in flight); try again"
            ) from None
        self.held += size

    def release(self, size: int) -> None:
        self.held -= size
        self._freed.set()


@dataclass(slots=True)
class HeldAsset:
    """A response frame read into memory, counted in the reader's budget until ``release``."""

    frame: bytearray
    _budget: _Budget
    _size: int

    def release(self) -> None:
        if self._size:
            self._budget.release(self._size)
            self._size = 0


class AssetReader:
    """Resolves and reads ``package://`` assets for every client of one server (see the module docstring)."""

    def __init__(
        self,
        store: TypeStore | None = None,
        *,
        allows: Callable[[str], bool] = lambda _uri: True,
        max_bytes: int = MAX_ASSET_BYTES,
        budget_bytes: int | None = None,
        max_reads: int = MAX_READS,
        budget_wait: float = BUDGET_WAIT,
    ) -> None:
        self._store = store
        self.allows = allows
        self.max_bytes = max_bytes
        #: at least two of the largest assets fit: one client's big mesh never stops everyone else's
        self.budget = _Budget(max(budget_bytes or 0, 2 * max_bytes))
        self.budget_wait = budget_wait
        self._pool = ThreadPoolExecutor(max_workers=max_reads, thread_name_prefix="mrosd-assets")

    @property
    def store(self) -> TypeStore:
        if self._store is None:
            from mrosd.msg.loader import default_store

            self._store = default_store()
        return self._store

    async def read(self, uri: str, head: bytes) -> HeldAsset:
        """The asset of ``uri`` as one frame: ``head``, then the file's bytes; ``release()`` it once written.

        Raises:
            AssetRefused: not served, not found, not a regular file, too big, or the budget stayed full.
        """
        ref = parse_asset_uri(uri)
        if not self.allows(uri):
            raise AssetRefused("not allowed by the [web] assets allow-list")
        fd, size = await self._in_thread(_open_asset, (self.store, ref, self.max_bytes), _close_opened)
        try:
            await self.budget.acquire(len(head) + size, self.budget_wait)
        except BaseException:
            os.close(fd)
            raise
        held = HeldAsset(bytearray(), self.budget, len(head) + size)

        def give_back(_frame: object) -> None:
            os.close(fd)
            held.release()

        try:
            held.frame = await self._in_thread(_read_frame, (fd, size, head), give_back)
        except asyncio.CancelledError:
            raise  # give_back runs once the thread is done with the descriptor
        except BaseException:
            give_back(None)
            raise
        os.close(fd)
        return held

    async def _in_thread(self, fn: Callable[..., Any], args: tuple[Any, ...], late: Callable[[Any], None]) -> Any:
        """``fn(*args)`` in the pool. A caller cancelled meanwhile (its client left) does not wait for the
        thread: ``late`` gets what the thread returns once it is done (None if it failed or never ran), to
        give back what it holds (a descriptor, budget)."""
        future = asyncio.get_running_loop().run_in_executor(self._pool, fn, *args)
        try:
            return await asyncio.shield(future)
        except asyncio.CancelledError:

            def done(f: asyncio.Future[Any]) -> None:
                late(None if f.cancelled() or f.exception() is not None else f.result())

            future.add_done_callback(done)
            raise

    def close(self) -> None:
        """Stop the pool's threads once their current reads end; queued reads are dropped."""
        self._pool.shutdown(wait=False, cancel_futures=True)
