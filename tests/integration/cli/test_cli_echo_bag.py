"""`mros topic echo -b BAG` renders stored messages with the live echo's options (-n, -p, --filter, --nostr)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from mrosd.bag.files import open_writer
from mrosd.bag.model import ConnectionInfo
from mrosd.msg import get_message_class


def _bag(path: Path) -> None:
    string = get_message_class("std_msgs/String")
    writer = open_writer(str(path), "bag")
    conn = writer.add_connection(ConnectionInfo("/a", "std_msgs/String", string._md5sum, string._full_text, "/rec"))
    for i in range(5):
        writer.write(conn, 1_700_000_000_000_000_000 + i, string(data=f"stored {i}").serialize())
    writer.close()


def _echo(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "topic", "echo", *args],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_echo_from_a_bag_takes_the_echo_options(tmp_path: Path) -> None:
    bag = tmp_path / "s.bag"
    _bag(bag)
    out = _echo("-b", str(bag), "-n", "2", "/a")
    assert (out.returncode, out.stdout) == (0, 'data: "stored 0"\n---\ndata: "stored 1"\n---\n'), out.stderr
    out = _echo("-b", str(bag), "--filter", "m.data.endswith(('3', '4'))", "--nostr", "/a")
    assert (out.returncode, out.stdout) == (0, 'data: "<string length: 8>"\n---\n' * 2), out.stderr
    out = _echo("-b", str(bag), "-p", "-n", "1", "/a")
    assert out.returncode == 0, out.stderr
    assert out.stdout.splitlines()[0] == "%time,field.data"
    assert out.stdout.splitlines()[1].endswith(",stored 0")
