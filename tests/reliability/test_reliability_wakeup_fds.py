"""Wake-up descriptors shared with a peer of another uid cannot stop our loops (issue 24, items 1 and 2).

The attack: a peer does to every wake-up descriptor it holds what the kernel lets it do: clear
``O_NONBLOCK`` (file status flags belong to the open file description, shared with everyone holding it),
fill it (an eventfd's counter to 0xfffffffffffffffe, a pipe shrunk to a page and filled, a socket's buffer),
and race us to drain what it can read. With eventfds shared with the peer, a writer's next wake-up
``write`` blocked forever: an IXM writer of a third uid made 0 writes in 3 s, the daemon's loop stopped in
its topic bridge (getPid unanswered), a shared-memory publisher went from 100 Hz to 0.

Needs root: the peer runs as ``nobody``, the IXM writer as a third user created here.
"""

from __future__ import annotations

import asyncio
import contextlib
import fcntl
import os
import pwd
import socket
import subprocess
import sys
import textwrap
import threading
import time
import xmlrpc.client
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import pytest

from mrosd.errors import IxmError
from mrosd.ixm.client import IxmClient
from tests.integration.daemon.daemonproc import DaemonRun, daemon_env
from tests.integration.ixm.conftest import start_daemon
from tests.integration.ixm.hostile import Child, nobody, shared_dir
from tests.rosenv import Processes, iter_lines_until

pytestmark = pytest.mark.root

FULL = (0xFFFFFFFFFFFFFFFE).to_bytes(8, sys.byteorder)
THIRD_USER = "trustfd-writer"


def third_user() -> pwd.struct_passwd:
    """A user that is neither root nor the attacker (created once with useradd)."""
    nobody()  # skips unless root
    try:
        return pwd.getpwnam(THIRD_USER)
    except KeyError:
        pass
    made = subprocess.run(
        ["useradd", "--system", "--no-create-home", "--shell", "/usr/sbin/nologin", THIRD_USER],
        capture_output=True,
        check=False,
    )
    if made.returncode != 0:
        pytest.skip(f"cannot create a third user: {made.stderr.decode().strip()}")
    return pwd.getpwnam(THIRD_USER)


def kind(fd: int) -> str:
    try:
        return os.readlink(f"/proc/self/fd/{fd}")
    except OSError:
        return ""


def open_fds() -> set[int]:
    return {int(n) for n in os.listdir("/proc/self/fd")}


def sabotage(keep: Iterable[int]) -> list[str]:
    """What a hostile holder can do to the wake-up descriptors it holds (all but ``keep``): fill each
    (an eventfd's counter to its maximum, a pipe shrunk to a page and filled, a socket's buffers), then make
    it blocking, which every other holder of the open file description sees."""
    done = []
    for fd in sorted(open_fds() - set(keep)):
        what = kind(fd)
        if fd <= 2 or not (what == "anon_inode:[eventfd]" or what.startswith(("pipe:", "socket:"))):
            continue
        with contextlib.suppress(OSError):
            os.set_blocking(fd, False)
            if what == "anon_inode:[eventfd]":
                with contextlib.suppress(BlockingIOError):
                    os.write(fd, FULL)
            elif what.startswith("pipe:"):
                with contextlib.suppress(OSError):
                    fcntl.fcntl(fd, 1031, 4096)  # F_SETPIPE_SZ: one page
                if fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE == os.O_WRONLY:
                    with contextlib.suppress(BlockingIOError):
                        while os.write(fd, b"x" * 4096):
                            pass
            else:
                s = socket.socket(fileno=os.dup(fd))
                with contextlib.suppress(OSError):
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
                    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
                with contextlib.suppress(OSError):
                    while s.send(b"x" * 4096, socket.MSG_DONTWAIT):
                        pass
                s.close()
            os.set_blocking(fd, True)
            done.append(what.split(":")[0] + ":" + what.rsplit("[", 1)[-1].rstrip("]"))
    return done


def race_to_drain(fds: Iterable[int], seconds: float) -> list[str]:
    """The reverse direction: on each descriptor we were given to wake our peer with, made blocking, wake the
    peer and drain what we wrote ourselves before it reads, again and again, then stop: a peer that reads
    such a descriptor after its loop saw it readable blocks if it shares our file description. (Threads:
    our own read may block too, when the peer wins.)"""
    done = []
    for fd in fds:
        what = kind(fd)
        if not (what == "anon_inode:[eventfd]" or what.startswith(("pipe:", "socket:"))):
            continue
        done.append(what.split(":")[0])
        os.set_blocking(fd, True)
        threading.Thread(target=_wake_and_steal, args=(fd, time.monotonic() + seconds), daemon=True).start()
    return done


def _wake_and_steal(fd: int, end: float) -> None:
    with contextlib.suppress(OSError):
        while time.monotonic() < end:
            os.write(fd, (1).to_bytes(8, sys.byteorder))
            os.read(fd, 8)


def keep_sent_fds(module: Any) -> list[int]:
    """Patch ``module.send_frame`` so that the caller keeps a copy of every descriptor it hands over (the
    list holds the copies and the originals)."""
    kept: list[int] = []
    original = module.send_frame

    def send_frame(sock: socket.socket, frame: Any, fds: Any = ()) -> int:
        kept.extend(fds)
        kept.extend(os.dup(fd) for fd in fds)
        return int(original(sock, frame, fds))

    module.send_frame = send_frame
    return kept


# IXM ----------------------------------------------------------------------------------------------------


def hostile_reader(path: str, key: str) -> Callable[[Any], dict[str, Any]]:
    def run(report: Any) -> dict[str, Any]:
        import mrosd.ixm.client as client_module

        before = open_fds()
        keep_sent_fds(client_module)
        with IxmClient(path, name="hostile-reader") as ixm:
            k = ixm.open(key)
            done = sabotage({ixm._sock.fileno(), k._state.fd, *before})
            report({"sabotaged": done})
            return {"ok": True}

    return run


def hostile_writer(path: str, key: str) -> Callable[[Any], dict[str, Any]]:
    """A writer (the rules let anyone write) that does the same to the readers' wake-up descriptors it is
    handed: the write end the other writers share."""

    def run(report: Any) -> dict[str, Any]:
        before = open_fds()
        with IxmClient(path, name="hostile-writer") as ixm:
            k = ixm.open(key, "float64", mode="w")
            done = sabotage({ixm._sock.fileno(), k._state.fd, k._state.lock_fd, *before})
            report({"sabotaged": done})
            return {"ok": True}

    return run


def counting_writer(path: str, key: str, seconds: float) -> Callable[[Any], dict[str, Any]]:
    def run(report: Any) -> dict[str, Any]:
        with IxmClient(path, name="writer") as ixm:
            k = ixm.open(key, "float64", mode="w")
            report({"open": True})
            writes = 0
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                k.write(float(writes))
                writes += 1
                time.sleep(0.001)
            return {"writes": writes}

    return run


@pytest.mark.parametrize("attack", [hostile_reader, hostile_writer], ids=["reader", "writer"])
def test_a_peer_that_blocks_and_fills_a_wakeup_cannot_stop_a_writer_of_a_third_uid(
    procs: Processes, attack: Any
) -> None:
    attacker, writer_user = nobody(), third_user()
    with shared_dir() as tmp:
        config = Path(tmp) / "mrosd.toml"
        config.write_text('[ixm.rules]\ndefault = "allow"\n')
        path = os.path.join(tmp, "ixm.sock")
        start_daemon(procs, path, str(config))
        with IxmClient(path, name="creator") as ixm, IxmClient(path, name="legit") as reader:
            ixm.open("/shared", "float64", mode="w").write(0.5)
            legit = reader.open("/shared", "float64", mode="r")
            legit.read()
            hostile = Child(attacker, attack(path, "/shared"))
            writer = Child(writer_user, counting_writer(path, "/shared", 3.0))
            try:
                sabotaged = hostile.line()
                writer.line()
                writer.go()
                got = legit.wait(timeout=3.0)  # a legitimate reader is still woken
                try:
                    result = writer.line(timeout=8.0)
                except AssertionError:
                    result = {"writes": 0, "blocked": True}
            finally:
                hostile.close()
                writer.close()
        print(f"attacker {sabotaged}; writer of a third uid: {result}; legit reader got {got}", file=sys.stderr)
        assert result.get("writes", 0) > 100, result
        assert isinstance(got, float)


def lock_holder(path: str, key: str) -> Callable[[Any], dict[str, Any]]:
    """A writer of the key (the rules let anyone write it) that takes the writers' lock and keeps it."""

    def run(report: Any) -> dict[str, Any]:
        with IxmClient(path, name="lock-holder") as ixm:
            k = ixm.open(key, "std_msgs/Float64", mode="w")
            fcntl.flock(k._state.lock_fd, fcntl.LOCK_EX)
            report({"sabotaged": ["writers' lock held"]})
            return {"ok": True}

    return run


BRIDGE_CONFIG = """
[rosout]
enabled = false
[ixm.rules]
default = "allow"
[ixm.rules.bridges."/arm/cmd"]
topic = "/arm_cmd"
type = "std_msgs/Float64"
direction = "from_topic"
"""


class _OneSecond(xmlrpc.client.Transport):
    def make_connection(self, host: Any) -> Any:
        conn = super().make_connection(host)
        conn.timeout = 1.0
        return conn


def get_pid_latencies(uri: str, calls: int) -> list[float]:
    """Seconds each getPid took (1.0 means no answer within a second)."""
    out = []
    for _ in range(calls):
        transport = _OneSecond()
        t0 = time.monotonic()
        try:
            with xmlrpc.client.ServerProxy(uri, transport=transport) as proxy:
                proxy.getPid("/probe")
            out.append(round(time.monotonic() - t0, 4))
        except OSError:
            out.append(1.0)
        time.sleep(0.05)
    return out


def read_next(path: str, key: str) -> Any:
    """The next value written to ``key``, or None (no daemon, or no write within 3 s)."""
    try:
        with IxmClient(path, name="legit", timeout=2.0) as ixm:
            return ixm.open(key).wait(3.0)
    except (IxmError, TimeoutError):
        return None


@pytest.mark.parametrize("attack", [hostile_reader, lock_holder], ids=["reader-fills-wakeup", "writer-holds-lock"])
async def test_a_peer_of_a_key_the_daemon_writes_cannot_stop_the_daemon(procs: Processes, attack: Any) -> None:
    from mrosd import Node
    from mrosd.msg import get_message_class

    attacker = nobody()
    with shared_dir() as tmp_str:
        tmp = Path(tmp_str)
        (tmp / "run").mkdir(mode=0o755)
        config = tmp / "mrosd.toml"
        config.write_text(BRIDGE_CONFIG)
        daemon = DaemonRun(procs, tmp, "--config", str(config), env=daemon_env(tmp))
        try:
            status = await asyncio.to_thread(daemon.ready)
            assert "1 ixm bridge(s)" in status, status
            Float64 = get_message_class("std_msgs/Float64")
            async with Node("cmd_source", master_uri=daemon.uri, host="127.0.0.1", argv=[]) as node:
                pub = await node.advertise("/arm_cmd", Float64)
                stop = asyncio.Event()

                async def publish() -> None:
                    n = 0
                    while not stop.is_set():
                        n += 1
                        await pub.publish(Float64(data=float(n)))
                        await asyncio.sleep(0.01)

                task = asyncio.create_task(publish())
                hostile = Child(attacker, attack(daemon.ixm_socket, "/arm/cmd"))
                try:
                    sabotaged = await asyncio.to_thread(hostile.line)
                    await asyncio.sleep(1.0)  # the bridge writes the key ~100 times meanwhile
                    latencies = await asyncio.to_thread(get_pid_latencies, daemon.uri, 8)
                    fresh = await asyncio.to_thread(read_next, daemon.ixm_socket, "/arm/cmd")
                finally:
                    stop.set()
                    await task
                    hostile.close()
        finally:
            daemon.close()
    print(f"attacker {sabotaged}; getPid latencies {latencies}; legit reader got {fresh}", file=sys.stderr)
    assert max(latencies) < 1.0, latencies
    assert sorted(latencies)[len(latencies) // 2] < 0.1, latencies
    if attack is hostile_reader:  # a writer holding the lock keeps the key from being written: that is all it can do
        assert fresh is not None and fresh.data > 0


# shared-memory topics -----------------------------------------------------------------------------------

PUBLISHER = textwrap.dedent(
    """
    import asyncio, sys
    from mrosd.shm import ShmPublisherEndpoint
    async def main():
        ep = ShmPublisherEndpoint("/cmd", queue_size=4, trusted=frozenset({0, int(sys.argv[1])}))
        await ep.start()
        print("addr", ep.address, ep.token, flush=True)
        n = 0
        while True:
            n += 1
            ep.publish(n.to_bytes(8, "little"))
            await asyncio.sleep(0.01)
    asyncio.run(main())
    """
)


def hostile_subscriber(address: str, token: str, reverse: bool = False) -> Callable[[Any], dict[str, Any]]:
    def run(report: Any) -> dict[str, Any]:
        import mrosd.shm.channel as channel_module
        from mrosd.shm import ShmSubscriberConnection, parse_answer
        from mrosd.shm.negotiate import PROTOCOL, VERSION
        from mrosd.wire.header import ConnectionHeader

        before = open_fds()
        sent = keep_sent_fds(channel_module)

        async def main() -> None:
            answer = parse_answer([PROTOCOL, VERSION, address, token])
            assert answer is not None
            header = ConnectionHeader(callerid="/hostile", topic="/cmd", md5sum="*", type="*")
            conn = await ShmSubscriberConnection.attach(answer, header, on_frame=lambda f: None)
            assert conn._channel is not None
            keep = {conn._channel.sock.fileno(), *before}
            for attr in ("_ring", "_ack"):
                mapped = getattr(conn, attr)
                keep.update(v for v in vars(mapped).values() if isinstance(v, int)) if mapped else None
            keep.update(int(n) for n in os.listdir("/proc/self/fd") if kind(int(n)).startswith("/memfd:"))
            loop = asyncio.get_running_loop()
            # stop our own loop from reading anything: only the sabotage threads touch the descriptors
            for n in os.listdir("/proc/self/fd"):
                with contextlib.suppress(Exception):
                    loop.remove_reader(int(n))
            if reverse:  # only what the publisher gave us to wake it with
                done = race_to_drain(sorted(open_fds() - keep - set(sent)), 2.0)
                await asyncio.sleep(2.0)
            else:
                done = sabotage(keep)
            report({"sabotaged": done})
            await asyncio.sleep(30)

        asyncio.run(main())
        return {"ok": True}

    return run


async def count_messages(address: str, token: str, seconds: float) -> int:
    from mrosd.shm import ShmSubscriberConnection, parse_answer
    from mrosd.shm.negotiate import PROTOCOL, VERSION
    from mrosd.wire.header import ConnectionHeader

    answer = parse_answer([PROTOCOL, VERSION, address, token])
    assert answer is not None
    got = 0

    def on_frame(frame: Any) -> None:
        nonlocal got
        got += 1

    header = ConnectionHeader(callerid="/legit", topic="/cmd", md5sum="*", type="*")
    conn = await ShmSubscriberConnection.attach(answer, header, on_frame=on_frame, timeout=3.0)
    try:
        await asyncio.sleep(seconds)
    finally:
        await conn.aclose()
    return got


@pytest.mark.parametrize("reverse", [False, True], ids=["fill-our-wakeup", "race-its-wakeup-of-us"])
async def test_a_subscriber_that_blocks_its_wakeups_cannot_stop_the_publisher(procs: Processes, reverse: bool) -> None:
    attacker = nobody()
    pub = procs.our_python(["-c", PUBLISHER, str(attacker.pw_uid)], dict(os.environ))
    words = next(iter_lines_until(pub, 1, 20.0)).split()
    assert words[0] == "addr", words
    address, token = words[1], words[2]
    before = await count_messages(address, token, 1.0)
    hostile = Child(attacker, hostile_subscriber(address, token, reverse))
    try:
        sabotaged = await asyncio.to_thread(hostile.line)
        await asyncio.sleep(0.5)
        try:
            after = await count_messages(address, token, 2.0)
        except (TimeoutError, OSError):
            after = 0  # the publisher's loop no longer accepts
    finally:
        hostile.close()
    alive = pub.poll() is None
    print(f"attacker {sabotaged}; legit subscriber: {before}/s before, {after / 2:.0f}/s after", file=sys.stderr)
    assert alive
    assert before > 30
    assert after > 60, after


# the shared-memory control socket: a peer that connects and closes in a loop (issue 24, item 7) ----------

LOGGING_PUBLISHER = PUBLISHER.replace(
    "import asyncio, sys\n", "import asyncio, logging, sys\nlogging.basicConfig(level='INFO', stream=sys.stderr)\n"
)


def connect_and_close(address: str, seconds: float) -> Callable[[Any], dict[str, Any]]:
    def run(report: Any) -> dict[str, Any]:
        report({"ready": True})
        n = 0
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            with contextlib.suppress(OSError):
                s.connect("\0" + address[1:])
                n += 1
            s.close()
        return {"connections": n}

    return run


def start_logging_publisher(procs: Processes, log_path: Path, trusted_uid: int) -> subprocess.Popen[bytes]:
    with open(log_path, "wb") as err:
        return procs.our_python(["-c", LOGGING_PUBLISHER, str(trusted_uid)], dict(os.environ), stderr=err.fileno())


@pytest.mark.parametrize("trusted", [False, True], ids=["untrusted-uid", "trusted-uid"])
async def test_a_peer_that_connects_and_closes_in_a_loop_cannot_flood_the_log(
    procs: Processes, tmp_path: Path, trusted: bool
) -> None:
    attacker = nobody()
    log_path = tmp_path / "publisher.log"
    pub = start_logging_publisher(procs, log_path, attacker.pw_uid if trusted else 0)
    words = next(iter_lines_until(pub, 1, 20.0)).split()
    address, token = words[1], words[2]
    hostile = Child(attacker, connect_and_close(address, 3.0))
    try:
        await asyncio.to_thread(hostile.line)
        hostile.go()
        during = await count_messages(address, token, 3.0)
        result = await asyncio.to_thread(hostile.line, 10.0)
    finally:
        hostile.close()
    alive = pub.poll() is None
    Processes.stop(pub)
    lines = log_path.read_text().splitlines()
    print(f"{result}; publisher log: {len(lines)} lines; legit subscriber {during / 3:.0f}/s", file=sys.stderr)
    assert alive
    assert result["connections"] > 1000, result
    assert len(lines) <= 50, lines[:10]  # 1000 lines per minute is 50 in 3 s
    assert during / 3 > 30, during  # keeps receiving; the attacker's own CPU use slows everyone on 2 cores


# woken-reader slots of an IXM key (issue 24, item 6) ------------------------------------------------------


def many_readers(path: str, key: str, count: int) -> Callable[[Any], dict[str, Any]]:
    def run(report: Any) -> dict[str, Any]:
        import resource

        hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
        resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, 8192), hard))
        clients, errors = [], []
        for _ in range(count):
            try:
                c = IxmClient(path, name="hog")
                clients.append(c)
                c.open(key)
            except IxmError as exc:
                errors.append(str(exc))
        report({"opened": count - len(errors), "errors": errors[-1:]})
        for c in clients:
            c.close()
        return {}

    return run


def test_one_uid_cannot_take_every_woken_reader_slot_of_a_key(procs: Processes) -> None:
    from mrosd.ixm.resources import MAX_WAKE_READERS

    attacker, other = nobody(), third_user()
    with shared_dir() as tmp:
        path = os.path.join(tmp, "ixm.sock")
        start_daemon(procs, path)
        with IxmClient(path, name="creator") as ixm:
            ixm.open("/popular", "float64", mode="w").write(1.0)
            hog = Child(attacker, many_readers(path, "/popular", MAX_WAKE_READERS))
            late = None
            try:
                taken = hog.line(timeout=120)  # it holds what it got until go()
                late = Child(other, many_readers(path, "/popular", 3))
                got = late.line()
                hog.go()
                late.go()
            finally:
                hog.close()
                if late is not None:
                    late.close()
    print(f"one uid: {taken['opened']} slots ({taken['errors']}); another uid: {got}", file=sys.stderr)
    assert got["opened"] == 3, got  # the other uid still gets readers woken
    assert taken["opened"] < MAX_WAKE_READERS // 2, taken
    assert "share" in taken["errors"][0], taken


def test_a_reader_whose_daemon_died_waits_without_spinning(procs: Processes) -> None:
    """The daemon keeps a write end of each reader's pipe: when it dies with no writer left, the pipe reads
    end-of-file, readable for ever; a reader must not spin on it, and still sees writes made through memory."""
    with shared_dir() as tmp:
        path = os.path.join(tmp, "ixm.sock")
        daemon = start_daemon(procs, path)
        with IxmClient(path, name="orphan") as ixm:
            key = ixm.open("/orphan", "float64", mode="rw")
            key.write(1.0)
            key.read()
            daemon.kill()
            daemon.wait(5)
            cpu = time.process_time()
            with pytest.raises(TimeoutError):
                key.wait(timeout=1.0)
            spent = time.process_time() - cpu
            key.write(2.0)  # through shared memory: the mapping outlives the daemon
            assert key.read() == 2.0
    print(f"CPU while waiting 1 s for an orphaned key: {spent:.3f} s", file=sys.stderr)
    assert spent < 0.3, spent


async def test_an_async_reader_whose_daemon_died_is_told_so_without_spinning(procs: Processes) -> None:
    """The asyncio client sees its socket close and closes its keys: a wait says the daemon is lost."""
    from mrosd.ixm import AsyncIxmClient

    with shared_dir() as tmp:
        path = os.path.join(tmp, "ixm.sock")
        daemon = start_daemon(procs, path)
        async with AsyncIxmClient(path, name="orphan") as ixm:
            key = await ixm.open("/orphan", "float64", mode="rw")
            key.write(1.0)
            key.read()
            daemon.kill()
            await asyncio.to_thread(daemon.wait, 5)
            cpu = time.process_time()
            with pytest.raises(IxmError, match="IXM daemon"):
                await key.wait(timeout=1.0)
            spent = time.process_time() - cpu
    print(f"CPU while waiting for a key whose daemon died (asyncio): {spent:.3f} s", file=sys.stderr)
    assert spent < 0.3, spent
