"""Fixtures of the ros2 tests: an in-process Zenoh router and zenoh-ros2-sdk's message folder filled offline."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.rosenv import free_port


@pytest.fixture
def router() -> Iterator[int]:
    """A Zenoh router on a free loopback port, as ``rmw_zenohd`` would be."""
    port = free_port()
    zenoh = pytest.importorskip("zenoh")
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", f'["tcp/127.0.0.1:{port}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    try:
        yield port
    finally:
        session.close()


@pytest.fixture
def messages_dir(tmp_path: Path) -> Iterator[Path]:
    """zenoh-ros2-sdk's message folder, filled offline (it would clone ros2/common_interfaces otherwise)."""
    folder = tmp_path / "messages"
    (folder / "std_msgs" / "msg").mkdir(parents=True)
    (folder / "std_msgs" / "msg" / "String.msg").write_text("string data\n")
    pytest.importorskip("zenoh_ros2_sdk")
    from zenoh_ros2_sdk import message_registry

    old = message_registry._registry
    message_registry._registry = message_registry.MessageRegistry(str(folder))
    yield folder
    message_registry._registry = old
