"""``[ros2]`` in mrosd.toml -> the bridge's options."""

from __future__ import annotations

import pytest

from mrosd.config import parse_config
from mrosd.errors import ConfigError
from mrosd.ros2.bridge import ros2_options


def test_the_ros2_part_is_off_by_default_and_connects_to_rmw_zenohs_router() -> None:
    cfg = parse_config("")
    assert not cfg.ros2.enabled
    opts = ros2_options(cfg.ros2, {})
    assert opts.connect == ("tcp/localhost:7447",) and opts.domain_id == 0 and opts.to_ros2 == ()


def test_settings_and_ros_domain_id() -> None:
    cfg = parse_config(
        '[ros2]\nenabled = true\nto_ros2 = ["/chatter", "/camera/**"]\nconnect = ["tcp/10.0.0.2:7447"]\n'
    )
    assert cfg.ros2.enabled
    opts = ros2_options(cfg.ros2, {"ROS_DOMAIN_ID": "7"})
    assert opts.domain_id == 7 and opts.to_ros2 == ("/chatter", "/camera/**")
    assert ros2_options(parse_config("[ros2]\ndomain_id = 3\n").ros2, {"ROS_DOMAIN_ID": "7"}).domain_id == 3
    assert ros2_options(parse_config('[ros2]\nfrom_ros2 = ["/cmd_vel"]\n').ros2, {}).from_ros2 == ("/cmd_vel",)


@pytest.mark.parametrize("bad", ["x", "233", "-1"])
def test_a_bad_ros_domain_id_is_one_line(bad: str) -> None:
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID"):
        ros2_options(parse_config("").ros2, {"ROS_DOMAIN_ID": bad})


def test_unknown_keys_and_out_of_range_domains_are_refused() -> None:
    with pytest.raises(ConfigError):
        parse_config("[ros2]\nbogus = 1\n")
    with pytest.raises(ConfigError):
        parse_config("[ros2]\ndomain_id = 300\n")


def test_tls_endpoints_need_the_ca_and_a_listening_one_its_certificate_and_key() -> None:
    """Mutual TLS as ``[fleet]`` does: the CA for any ``tls/`` endpoint, a certificate and key to listen on one
    (and then every session must show one of that CA: ``enable_mtls``)."""
    with pytest.raises(ConfigError, match="tls_root_ca"):
        ros2_options(parse_config('[ros2]\nconnect = ["tls/robot:7447"]\n').ros2, {})
    with pytest.raises(ConfigError, match="tls_certificate"):
        ros2_options(
            parse_config('[ros2]\nrouter = true\nlisten = ["tls/[::]:7447"]\ntls_root_ca = "ca.pem"\n').ros2, {}
        )
    text = '[ros2]\nrouter = true\nlisten = ["tls/[::]:7447"]\ntls_root_ca = "ca.pem"\n'
    text += 'tls_certificate = "robot.pem"\ntls_private_key = "robot.key"\n'
    opts = ros2_options(parse_config(text).ros2, {})
    assert (opts.tls_root_ca, opts.tls_certificate, opts.tls_private_key) == ("ca.pem", "robot.pem", "robot.key")
