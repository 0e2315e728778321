"""[fleet] in mrosd.toml -> FleetOptions -> Zenoh settings (pure), and mrosd without eclipse-zenoh."""

from __future__ import annotations

import json
import sys

import pytest

from mrosd.config import parse_config
from mrosd.errors import ConfigError
from mrosd.fleet.options import FleetOptions, fleet_options, zenoh_settings

GOOD = """
[fleet]
enabled = true
robot = "robot1"
listen = ["tcp/0.0.0.0:7447"]
connect = ["tcp/10.0.0.2:7447"]
send_topics = ["/chatter", "/camera/**"]
send_topics_exclude = ["/camera/secret/**"]
receive_topics = ["/robot2/**"]
prefix_tf = true
[[fleet.limits]]
topic = "/camera/**"
max_hz = 5
"""


def test_a_fleet_section_becomes_options() -> None:
    opts = fleet_options(parse_config(GOOD).fleet)
    assert opts.robot == "robot1" and opts.prefix_tf
    assert "/camera/image" in opts.send_topics and "/camera/secret/x" not in opts.send_topics
    assert "/robot2/odom" in opts.receive_topics and "/robot3/odom" not in opts.receive_topics
    limit = opts.limit_for("/camera/image")
    assert limit is not None and limit.max_hz == 5
    assert opts.limit_for("/chatter") is None


def test_fleet_is_off_by_default() -> None:
    assert not parse_config("").fleet.enabled


@pytest.mark.parametrize(
    ("text", "key"),
    [
        ("[fleet]\nenabled = true\n", "fleet.robot"),
        ('[fleet]\nrobot = "r-1"\n', "fleet.robot"),
        ('[fleet]\nrobot = "r1"\nlisten = ["7447"]\n', "fleet.listen"),
        ('[fleet]\nrobot = "r1"\nmode = "client"\n', "fleet.connect"),
        ('[fleet]\nrobot = "r1"\nconnect = ["tls/h:7447"]\n', "fleet.tls_root_ca"),
        ('[fleet]\nrobot = "r1"\nlisten = ["tls/h:7447"]\ntls_root_ca = "ca.pem"\n', "fleet.tls_certificate"),
    ],
)
def test_bad_settings_name_their_key(text: str, key: str) -> None:
    with pytest.raises(ConfigError, match=key):
        fleet_options(parse_config(text).fleet)


def test_unknown_keys_are_refused() -> None:
    with pytest.raises(ConfigError):
        parse_config('[fleet]\nrobot = "r1"\nsend = ["/x"]\n')


def test_zenoh_settings_scouting_off_short_lease_endless_retries() -> None:
    got = dict(zenoh_settings(FleetOptions("r1", listen=("tcp/0.0.0.0:7447",))))
    assert json.loads(got["scouting/multicast/enabled"]) is False
    assert json.loads(got["transport/link/tx/lease"]) == 3000
    assert json.loads(got["connect/retry"])["period_max_ms"] == 1000
    assert "connect/timeout_ms" not in got  # 0 there would also end the background retries


def test_without_eclipse_zenoh_the_fleet_part_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    from mrosd.fleet.bridge import require_zenoh

    monkeypatch.setitem(sys.modules, "zenoh", None)  # import zenoh -> ImportError
    with pytest.raises(ConfigError, match=r"pip install 'mrosd\[fleet\]'"):
        require_zenoh()
