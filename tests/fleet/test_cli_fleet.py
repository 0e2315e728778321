"""`mros fleet status`: the text report (pure), and the answer when the fleet part is not running."""

from __future__ import annotations

import subprocess
import sys

from mros_cli.fleet import format_status

from tests.rosenv import Processes, free_port, wait_for_xmlrpc

STATUS = {
    "robot": "robot2",
    "mode": "peer",
    "zid": "abc",
    "peers": ["def"],
    "remote_items": 3,
    "bad_announcements": 0,
    "refused_items": 0,
    "refused_calls": 0,
    "sent": {
        "/odom": {
            "key": "k",
            "matched": False,
            "messages": 0,
            "bytes": 0,
            "rate_hz": 0.0,
            "dropped": 0,
            "rate_limited": 0,
            "latched": False,
        }
    },
    "received": {
        "/robot1/map": {
            "key": "k2",
            "robot": "robot1",
            "subscribed": True,
            "messages": 1,
            "bytes": 10,
            "rate_hz": 0.5,
            "dropped": 2,
            "refused": 0,
            "latched": True,
        }
    },
    "services_sent": {},
    "services_received": {"/robot1/set": {"key": "k3", "calls": 4, "errors": 1}},
    "announce_period": 1.0,
}


def test_the_report_names_peers_topics_and_counts() -> None:
    text = format_status(STATUS)
    assert "robot:   robot2 (peer, zenoh id abc)" in text
    assert "peers:   def" in text
    assert "/odom  nobody asked  0 msgs" in text
    assert "/robot1/map  from robot1  subscribed  1 msgs 10 B  0.5 Hz  dropped 2  latched" in text
    assert "/robot1/set  4 calls  1 errors" in text


def test_without_the_fleet_part_it_says_so_and_exits_1(procs: Processes) -> None:
    port = free_port()
    procs.our_python(["-m", "mrosd.master", "--host", "127.0.0.1", "--port", str(port)])
    uri = f"http://127.0.0.1:{port}/"
    wait_for_xmlrpc(uri)
    done = subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "--master-uri", uri, "fleet", "status"],
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )
    assert done.returncode == 1
    assert "is [fleet] enabled in mrosd.toml?" in done.stderr
