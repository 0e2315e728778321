"""Fixtures for master interop tests: either master (ours or Debian's rosmaster) and a recording slave API.

``any_master`` is parametrized over ``rosmaster`` and ``mrosd``: a test using it states the real
rosmaster's behaviour once and checks that ours matches it in the same run.
"""

from __future__ import annotations

import subprocess
import threading
import time
import xmlrpc.client
from collections.abc import Callable, Iterator
from typing import Any
from xmlrpc.server import SimpleXMLRPCRequestHandler, SimpleXMLRPCServer

import pytest

from tests.rosenv import Processes, free_port, ros_env, start_rosmaster, wait_for_xmlrpc


def start_our_master(procs: Processes, *extra: str) -> str:
    """Start ``python -m mrosd.master`` on a free port; return its URI once it answers."""
    port = free_port()
    uri = f"http://127.0.0.1:{port}/"
    procs.our_python(
        ["-m", "mrosd.master", "--port", str(port), *extra],
        ros_env(uri, procs.tmp),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    wait_for_xmlrpc(uri)
    return uri


@pytest.fixture(params=["rosmaster", "mrosd"])
def any_master(request: pytest.FixtureRequest, procs: Processes) -> str:
    """URI of a fresh master: Debian's rosmaster, then ours (the same test runs against both)."""
    if request.param == "rosmaster":
        return start_rosmaster(procs)
    return start_our_master(procs)


@pytest.fixture
def m(any_master: str) -> Iterator[xmlrpc.client.ServerProxy]:
    """A plain stdlib XML-RPC proxy of ``any_master``, the client ros_comm's own tests use."""
    with xmlrpc.client.ServerProxy(any_master) as master:
        yield master


class _QuietHandler(SimpleXMLRPCRequestHandler):
    def log_message(self, format: str, *args: Any) -> None:
        pass


class RecordingSlave:
    """A slave API that answers every master callback with success and records ``(method, args)``.

    ``calls`` lists what the master sent, in arrival order (caller id included as ``args[0]``).
    """

    def __init__(self) -> None:
        self.calls: list[tuple[str, tuple[Any, ...]]] = []
        self._cond = threading.Condition()
        self._server = SimpleXMLRPCServer(
            ("127.0.0.1", 0), requestHandler=_QuietHandler, logRequests=False, allow_none=True
        )
        self._server.register_instance(self)
        self._server.register_introspection_functions()
        self.uri = f"http://127.0.0.1:{self._server.server_address[1]}/"
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        self._thread.start()

    def _dispatch(self, method: str, params: tuple[Any, ...]) -> Any:
        with self._cond:
            self.calls.append((method, params))
            self._cond.notify_all()
        if method == "getPid":
            return [1, "", 4242]
        return [1, "", 0]

    def wait_for(self, predicate: Any, timeout: float = 10.0) -> list[tuple[str, tuple[Any, ...]]]:
        """Block until ``predicate(calls)`` holds; return a copy of the calls."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate(self.calls):
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(f"master callbacks so far: {self.calls}")
                self._cond.wait(remaining)
            return list(self.calls)

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        self._thread.join(5)


@pytest.fixture
def make_slave() -> Iterator[Callable[[], RecordingSlave]]:
    """Factory of ``RecordingSlave`` instances, all closed at teardown."""
    slaves: list[RecordingSlave] = []

    def make() -> RecordingSlave:
        slave = RecordingSlave()
        slaves.append(slave)
        return slave

    try:
        yield make
    finally:
        for slave in slaves:
            slave.close()
