"""Hostile IXM clients exhausting file descriptors: caps per uid and overall, EMFILE back-off, the master kept up.

The hostile clients run as another uid (``nobody``, a forked child) so that a normal client of root shows
what the caps protect; the daemons run with a low fd limit so that exhaustion takes a second, not minutes.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
import xmlrpc.client
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from mrosd.errors import IxmError
from mrosd.ixm.client import IxmClient
from tests.integration.ixm.hostile import (
    Child,
    cpu_seconds,
    fd_count,
    nobody,
    rss_kib,
    shared_dir,
    start_limited_daemon,
)
from tests.rosenv import Processes, free_port

pytestmark = pytest.mark.root


def flood(sock_path: str, connections: int, keys_per_connection: int) -> Callable[[Any], dict[str, Any]]:
    """A hostile child: as many connections and keys as it can get, held until the parent says go."""

    def run(report: Any) -> dict[str, Any]:
        clients: list[Any] = []
        raw: list[socket.socket] = []
        errors: dict[str, int] = {}
        keys = 0

        def note(exc: BaseException) -> None:
            line = str(exc).split(": ", 1)[-1] if "cannot reach" not in str(exc) else str(exc)
            errors[line] = errors.get(line, 0) + 1

        started = time.monotonic()
        for i in range(connections):
            try:
                c = IxmClient(sock_path, name=f"flood{i}", timeout=0.5)
            except IxmError as exc:
                note(exc)
                # a raw connection that never speaks still costs the daemon an fd: hold some of those too
                s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
                try:
                    s.connect(sock_path)
                    raw.append(s)
                except OSError:
                    s.close()
                if sum(errors.values()) > 20:
                    break
                continue
            clients.append(c)
            for j in range(keys_per_connection):
                try:
                    c.open(f"/flood/{i}/{j}", "int32", mode="rw")
                    keys += 1
                except IxmError as exc:
                    note(exc)
                    break
        report(
            {
                "clients": len(clients),
                "raw": len(raw),
                "keys": keys,
                "errors": errors,
                "seconds": time.monotonic() - started,
            }
        )
        for c in clients:
            c.close()
        for s in raw:
            s.close()
        return {"done": True}

    return run


def normal_client_works(path: str) -> str:
    try:
        with IxmClient(path, name="normal", timeout=3) as ixm:
            key = ixm.open("/normal", "float64", mode="rw")
            key.write(1.5)
            value = key.read()
            key.close()
            return f"ok {value}"
    except IxmError as exc:
        return f"error: {exc}"


def test_hostile_clients_of_one_uid_cannot_exhaust_the_daemon_fds_and_a_normal_client_still_works(
    procs: Processes,
) -> None:
    user = nobody()
    with shared_dir() as tmp:
        path = os.path.join(tmp, "ixm.sock")
        log = os.path.join(tmp, "daemon.log")
        daemon = start_limited_daemon(procs, path, 512, log)
        child = Child(user, flood(path, 600, 64))
        try:
            held = child.line()
            cpu0 = cpu_seconds(daemon.pid)
            t0 = time.monotonic()
            normal = normal_client_works(path)
            time.sleep(0.5)
            cpu = (cpu_seconds(daemon.pid) - cpu0) / (time.monotonic() - t0)
            fds = fd_count(daemon.pid)
            rss = rss_kib(daemon.pid)
            alive = daemon.poll() is None
            child.go()
            child.line()
        finally:
            child.close()
        lines = Path(log).read_text().count("\n")
        print(
            f"hostile held {held}; daemon fds {fds}/512, rss {rss} KiB, cpu {cpu:.2f}, log lines {lines}",
            file=sys.stderr,
        )
        assert alive, "the daemon died"
        assert normal == "ok 1.5"
        assert fds < 512 - 16, "the daemon ran out of file descriptors"
        assert cpu < 0.5, "the daemon spins while under attack"
        assert lines < 200, "the attack floods the log"
        refusals = list(held["errors"])
        assert refusals, "the hostile uid was never refused"
        assert all("\n" not in r and ("limit" in r or "too many" in r) for r in refusals), refusals


def test_an_accept_loop_out_of_fds_backs_off_answers_a_clear_error_and_recovers(procs: Processes) -> None:
    """Caps set above the process's fd limit (an operator's mistake): EMFILE must not spin or flood."""
    user = nobody()
    with shared_dir() as tmp:
        path = os.path.join(tmp, "ixm.sock")
        log = os.path.join(tmp, "daemon.log")
        big = {"max_clients": 100_000, "max_clients_per_uid": 100_000, "max_keys": 100_000, "max_keys_per_uid": 100_000}
        daemon = start_limited_daemon(procs, path, 128, log, **big)
        child = Child(user, flood(path, 400, 0))
        try:
            held = child.line()
            cpu0 = cpu_seconds(daemon.pid)
            t0 = time.monotonic()
            time.sleep(1.0)
            cpu = (cpu_seconds(daemon.pid) - cpu0) / (time.monotonic() - t0)
            rss = rss_kib(daemon.pid)
            alive = daemon.poll() is None
            child.go()
            child.line()
        finally:
            child.close()
        # once the hostile clients are gone the daemon accepts again (its back-off is at most a second)
        deadline = time.monotonic() + 5.0
        normal = normal_client_works(path)
        while normal != "ok 1.5" and time.monotonic() < deadline:
            time.sleep(0.2)
            normal = normal_client_works(path)
        lines = Path(log).read_text().count("\n")
        print(f"hostile held {held}; daemon cpu {cpu:.2f}, rss {rss} KiB, log lines {lines}", file=sys.stderr)
        assert alive, "the daemon died"
        assert cpu < 0.2, "the accept loop spins on EMFILE"
        assert lines < 200, "EMFILE floods the log"
        assert any("file descriptors" in e for e in held["errors"]), held["errors"]
        assert normal == "ok 1.5"


def test_the_master_answers_while_ixm_is_flooded_in_the_real_daemon(procs: Processes) -> None:
    user = nobody()
    with shared_dir() as tmp:
        path = os.path.join(tmp, "ixm.sock")
        port = free_port()
        env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "MROSD_", "NOTIFY_", "WATCHDOG_"))}
        env.update(MROSD_IXM_SOCKET=path, ROS_HOSTNAME="127.0.0.1", MROSD_MASTER_HOST="127.0.0.1")
        code = (
            "import resource, runpy, sys; resource.setrlimit(resource.RLIMIT_NOFILE, (512, 512)); "
            f"sys.argv = ['mrosd', '--port', '{port}']; runpy.run_module('mrosd.daemon', run_name='__main__')"
        )
        daemon = procs.start([sys.executable, "-c", code], env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        uri = f"http://127.0.0.1:{port}/"
        deadline = time.monotonic() + 30
        while True:
            try:
                with xmlrpc.client.ServerProxy(uri) as proxy:
                    proxy.getPid("/probe")
                break
            except OSError:
                assert time.monotonic() < deadline, "the daemon did not start"
                time.sleep(0.1)
        deadline = time.monotonic() + 10
        while not os.path.exists(path):
            assert time.monotonic() < deadline, "no IXM socket"
            time.sleep(0.05)
        child = Child(user, flood(path, 600, 64))
        try:
            held = child.line()
            answers = []
            for _ in range(5):
                t0 = time.monotonic()
                try:
                    transport = xmlrpc.client.Transport()
                    transport.timeout = 3.0  # type: ignore[attr-defined]
                    with xmlrpc.client.ServerProxy(uri, transport=transport) as proxy:
                        code_, _msg, pid = proxy.getPid("/probe")
                    answers.append((code_, pid == daemon.pid or pid > 0, round(time.monotonic() - t0, 3)))
                except OSError as exc:
                    answers.append((-9, False, repr(exc)))
            normal = normal_client_works(path)
            fds = fd_count(daemon.pid)
            rss = rss_kib(daemon.pid)
            child.go()
            child.line()
        finally:
            child.close()
        print(f"hostile held {held}; master answers {answers}; daemon fds {fds}/512, rss {rss} KiB", file=sys.stderr)
        assert daemon.poll() is None
        assert all(a[0] == 1 and a[1] for a in answers), answers
        assert normal == "ok 1.5"
