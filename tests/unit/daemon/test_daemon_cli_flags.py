"""``mrosd --version`` and the web part's flags: what a newcomer types first.

Before, ``mrosd --version`` was a usage error, ``--help`` named neither the page nor its ports, and only
the environment or the file could set them.
"""

from __future__ import annotations

import json
import os
from importlib.metadata import version

import pytest

from mrosd.daemon import build_parser, main


@pytest.fixture(autouse=True)
def _clean_env(monkeypatch: pytest.MonkeyPatch) -> None:
    for key in [k for k in os.environ if k.startswith(("MROSD_", "ROS_"))]:
        monkeypatch.delenv(key)


def test_version_prints_the_installed_distribution_version(capsys: pytest.CaptureFixture[str]) -> None:
    import mrosd

    with pytest.raises(SystemExit) as exited:
        main(["--version"])
    assert exited.value.code == 0
    assert capsys.readouterr().out.strip() == f"mrosd {version('mrosd')}"
    assert mrosd.__version__ == version("mrosd")  # one source: the package metadata


def test_help_shows_the_web_flags_and_their_environment_variables() -> None:
    text = build_parser().format_help()
    for flag in ("--web-port", "--rosbridge-port", "--web-host", "--no-web"):
        assert flag in text
    for var in ("MROSD_WEB_PORT", "MROSD_WEB_ROSBRIDGE_PORT", "MROSD_WEB_HOST", "MROSD_WEB_TOKEN", "MROSD_CONFIG"):
        assert var in text
    assert "page" in text


def _checked(capsys: pytest.CaptureFixture[str], *argv: str) -> dict[str, object]:
    assert main([*argv, "--check-config"]) == 0
    out = capsys.readouterr().out
    web: dict[str, object] = json.loads(out[out.index("{") :])["web"]
    return web


def test_the_web_flags_set_the_ports_and_override_the_environment(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("MROSD_WEB_PORT", "1111")
    web = _checked(capsys, "--web-port", "26765", "--rosbridge-port", "-1", "--web-host", "127.0.0.1,::1")
    assert (web["foxglove_port"], web["rosbridge_port"], web["host"]) == (26765, -1, ["127.0.0.1", "::1"])
    assert _checked(capsys, "--no-web")["enabled"] is False


def test_a_web_port_out_of_range_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--web-port", "70000", "--check-config"]) == 2
    assert "--web-port must be 0..65535" in capsys.readouterr().err


def test_a_non_loopback_web_host_from_the_flag_still_needs_a_token(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--web-host", "0.0.0.0", "--check-config"]) == 2
    assert "not loopback" in capsys.readouterr().err
