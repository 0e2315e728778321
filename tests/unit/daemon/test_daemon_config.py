"""The daemon's TOML configuration and environment overrides: defaults, precedence, errors naming the key."""

from __future__ import annotations

import importlib
import inspect
import os
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.config import (
    MAX_DEPTH,
    Config,
    IxmConfig,
    MasterConfig,
    load_config,
    parse_config,
    part_options,
    valid_host,
)
from mrosd.errors import ConfigError

EXAMPLE = Path(__file__).resolve().parents[3] / "packaging" / "mrosd.toml"


def test_the_packaged_example_config_is_valid_and_equals_the_defaults() -> None:
    cfg = parse_config(EXAMPLE.read_text(), str(EXAMPLE))
    default = Config()
    assert cfg.master == default.master
    assert cfg.rosout == default.rosout
    assert cfg.log == default.log
    assert cfg.ixm.socket == "/run/mrosd/ixm.sock"


def test_an_empty_file_gives_the_defaults() -> None:
    cfg = parse_config("")
    assert cfg.master.port == 11311
    assert cfg.master.host == "0.0.0.0"
    assert cfg.rosout.enabled is True


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('[master]\nport = "x"\n', "master.port"),
        ("[master]\nprot = 1\n", "prot"),
        ("[bogus]\n", "bogus"),
        ("[master]\nport = 70000\n", "master.port"),
        ('[master]\nallow = ["not-a-net"]\n', "master.allow[0]"),
        ('[log]\nlevel = "loud"\n', "log.level"),
        ('[log]\ndir = "relative/logs"\n', "log.dir"),
        ("[log]\nmax_bytes = 0\n", "log.max_bytes"),
        ("[log]\nbackups = -1\n", "log.backups"),
        ("port = ", "not valid TOML"),
    ],
)
def test_a_bad_config_is_an_error_naming_the_key(text: str, needle: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(text, "mrosd.toml")
    assert needle in str(info.value)
    assert "mrosd.toml" in str(info.value)


def test_web_assets_default_to_meshes_and_an_empty_list_offers_none() -> None:
    from mrosd.web.access import DEFAULT_ASSETS

    web = parse_config("").web
    assert (web.assets, web.asset_bytes) == (list(DEFAULT_ASSETS), None)
    web = parse_config("[web]\nassets = []\nasset_bytes = 1024\n").web
    assert (web.assets, web.asset_bytes) == ([], 1024)
    with pytest.raises(ConfigError, match=r"web\.asset_bytes"):
        parse_config("[web]\nasset_bytes = 0\n")


def test_web_host_is_one_address_or_a_list_and_any_off_loopback_needs_the_token() -> None:
    assert parse_config("").web.hosts() == ["127.0.0.1"]
    web = parse_config('[web]\nhost = ["127.0.0.1", "::1"]\n').web
    assert (web.host, web.hosts()) == (["127.0.0.1", "::1"], ["127.0.0.1", "::1"])
    # the rule and its wording as for one address, naming the one that is not loopback
    with pytest.raises(ConfigError, match=r"web\.host '192\.0\.2\.1' is not loopback: set web\.token"):
        parse_config('[web]\nhost = ["127.0.0.1", "192.0.2.1"]\n', "mrosd.toml")
    web = parse_config('[web]\nhost = ["127.0.0.1", "192.0.2.1"]\ntoken = "s3cret"\n').web
    assert web.hosts() == ["127.0.0.1", "192.0.2.1"]
    for text, needle in [("[]", "empty list"), ('["::1", "::1"]', "twice"), ('["::1", "999.1.1.1"]', "999.1.1.1")]:
        with pytest.raises(ConfigError, match=needle):
            parse_config(f"[web]\nhost = {text}\n")


def test_mrosd_web_host_is_a_comma_separated_list() -> None:
    assert load_config(None, {"MROSD_WEB_HOST": "::1"}).web.host == "::1"
    assert load_config(None, {"MROSD_WEB_HOST": "127.0.0.1, ::1"}).web.hosts() == ["127.0.0.1", "::1"]
    with pytest.raises(ConfigError, match=r"web\.host '0\.0\.0\.0' is not loopback"):
        load_config(None, {"MROSD_WEB_HOST": "127.0.0.1,0.0.0.0"})
    cfg = load_config(None, {"MROSD_WEB_HOST": "127.0.0.1,0.0.0.0", "MROSD_WEB_TOKEN": "s3cret"})
    assert cfg.web.hosts() == ["127.0.0.1", "0.0.0.0"]


def test_mrosd_check_prints_the_list_and_refuses_it_without_token(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from mrosd.daemon import main

    for key in [k for k in os.environ if k.startswith(("MROSD_", "ROS_"))]:
        monkeypatch.delenv(key)
    config = tmp_path / "mrosd.toml"
    config.write_text('[web]\nhost = ["127.0.0.1", "::1"]\n')
    assert main(["--config", str(config), "--check-config"]) == 0
    assert '"host": [\n      "127.0.0.1",\n      "::1"\n    ]' in capsys.readouterr().out
    config.write_text('[web]\nhost = ["127.0.0.1", "0.0.0.0"]\n')
    assert main(["--config", str(config), "--check-config"]) == 2
    assert "web.host '0.0.0.0' is not loopback: set web.token" in capsys.readouterr().err


def test_the_log_directory_is_ros_s_unless_set_or_off() -> None:
    assert parse_config("").log.dir == ""  # the daemon then follows ROS_LOG_DIR, ROS_HOME/log, ~/.ros/log
    assert parse_config('[log]\ndir = "off"\n').log.dir == "off"
    cfg = parse_config('[log]\ndir = "/var/log/mrosd"\nmax_bytes = 1000\nbackups = 0\n')
    assert (cfg.log.dir, cfg.log.max_bytes, cfg.log.backups) == ("/var/log/mrosd", 1000, 0)


def test_the_ixm_rules_table_is_passed_through_untouched() -> None:
    cfg = parse_config('[ixm.rules]\n"/cam/*" = { read = ["video"], write = ["camera"] }\n')
    assert cfg.ixm.rules == {"/cam/*": {"read": ["video"], "write": ["camera"]}}


def test_environment_overrides_the_file(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text("[master]\nport = 1234\n[rosout]\nenabled = true\n")
    env = {"ROS_MASTER_URI": "http://localhost:22422/", "MROSD_ROSOUT": "0", "MROSD_IXM_SOCKET": "/x/ixm.sock"}
    cfg = load_config(path, env)
    assert cfg.master.port == 22422
    assert cfg.rosout.enabled is False
    assert cfg.ixm.socket == "/x/ixm.sock"
    assert load_config(path, {**env, "MROSD_MASTER_PORT": "5"}).master.port == 5


def test_a_named_config_file_that_is_missing_is_an_error(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "nope.toml", {})


@pytest.mark.parametrize(
    "env",
    [{"MROSD_MASTER_PORT": "eleven"}, {"MROSD_ROSOUT": "maybe"}, {"ROS_MASTER_URI": "localhost:11311"}],
)
def test_a_malformed_environment_override_is_an_error_naming_the_variable(env: dict[str, str]) -> None:
    with pytest.raises(ConfigError) as info:
        load_config(None, env)
    assert next(iter(env)) in str(info.value)


@given(st.text(max_size=200))
def test_arbitrary_text_either_parses_or_raises_config_error(text: str) -> None:
    try:
        parse_config(text)
    except ConfigError:
        pass


@pytest.mark.parametrize("host", ["999.1.1.1", "1.2.3", "", "bad host", "-x.example", "a..b", "x" * 64 + ".com"])
def test_a_master_host_that_is_no_address_or_name_is_refused(host: str) -> None:
    with pytest.raises(ConfigError, match=r"master\.host"):
        parse_config(f"[master]\nhost = {host!r}\n".replace("'", '"'), "mrosd.toml")


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "127.0.0.1", "fe80::1", "localhost", "robot-1.lan", "robot.lan."])
def test_addresses_and_host_names_are_valid_master_hosts(host: str) -> None:
    assert valid_host(host)
    assert parse_config(f'[master]\nhost = "{host}"\n').master.host == host


def test_the_environment_host_is_validated_too() -> None:
    with pytest.raises(ConfigError, match="MROSD_MASTER_HOST"):
        load_config(None, {"MROSD_MASTER_HOST": "999.1.1.1"})


@pytest.mark.parametrize(
    "text",
    [
        "a = " + "[" * 5000 + "]" * 5000,
        "a = " + "{b = " * 3000 + "1" + "}" * 3000,
        "a = " + "[" * (MAX_DEPTH + 2) + "]" * (MAX_DEPTH + 2),
        "[ixm.rules]\n" + ".".join(["x"] * (MAX_DEPTH + 2)) + " = 1",
    ],
)
def test_deeply_nested_toml_is_a_config_error_not_a_crash(text: str) -> None:
    with pytest.raises(ConfigError, match="nested"):
        parse_config(text, "mrosd.toml")


@given(st.integers(1, 4000))
def test_any_nesting_depth_is_either_accepted_or_a_config_error(depth: int) -> None:
    try:
        parse_config("[ixm.rules]\nx = " + "[" * depth + "]" * depth)
    except ConfigError:
        assert depth > MAX_DEPTH - 2


@pytest.mark.parametrize(
    ("section", "part"), [(MasterConfig, "mrosd.master:Master"), (IxmConfig, "mrosd.ixm.server:IxmServer")]
)
def test_every_cap_of_a_section_is_a_keyword_of_its_part(section: type[MasterConfig | IxmConfig], part: str) -> None:
    module, name = part.split(":")
    params = inspect.signature(getattr(importlib.import_module(module), name)).parameters
    caps = set(section.__struct_fields__) - section.DAEMON_KEYS
    assert caps, "no caps to pass"
    assert caps <= {p for p, v in params.items() if v.kind is inspect.Parameter.KEYWORD_ONLY}


def test_caps_are_passed_only_when_set_and_must_be_positive() -> None:
    cfg = parse_config("[master]\nidle_timeout = 30\nmax_connections = 100\n[ixm]\nmax_keys_per_uid = 64\n")
    assert part_options(cfg.master) == {"idle_timeout": 30.0, "max_connections": 100}
    assert part_options(cfg.ixm) == {"max_keys_per_uid": 64}
    assert part_options(Config().master) == {}
    for bad in ("[master]\nidle_timeout = 0\n", "[ixm]\nmax_clients = -1\n", '[ixm]\nmax_keys = "many"\n'):
        with pytest.raises(ConfigError, match=r"master\.idle_timeout|ixm\.max_"):
            parse_config(bad, "mrosd.toml")
