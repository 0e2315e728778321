"""The daemon's TOML configuration and environment overrides: defaults, precedence, errors naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from mrosd.config import Config, load_config, parse_config
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
        ("port = ", "not valid TOML"),
    ],
)
def test_a_bad_config_is_an_error_naming_the_key(text: str, needle: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(text, "mrosd.toml")
    assert needle in str(info.value)
    assert "mrosd.toml" in str(info.value)


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
