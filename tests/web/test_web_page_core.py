"""The page's pure cores: which asset names are served (``mrosd.web.page.asset``), ``RateWindow``, ``mros web``."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st
from mros_cli.web import page_url

from mrosd.web.page import ASSET_NAME, CONTENT_TYPES, asset
from mrosd.web.rates import RateWindow


def test_every_shipped_asset_is_served_with_its_content_type() -> None:
    for name, ctype in [("index.html", "text/html"), ("app.js", "text/javascript"), ("style.css", "text/css")]:
        found = asset(name)
        assert found is not None and found[1].startswith(ctype) and found[0]


@given(st.text(max_size=80))
def test_any_other_name_is_refused(name: str) -> None:
    found = asset(name)
    if found is not None:
        assert ASSET_NAME.fullmatch(name) and "/" not in name and ".." not in name
        assert found[1] in CONTENT_TYPES.values()


@pytest.mark.parametrize("name", ["../page.py", "..", "/etc/passwd", "page.py", "app.js/", "x/../app.js", ""])
def test_names_outside_the_folder_are_refused(name: str) -> None:
    assert asset(name) is None


def test_rate_over_the_window() -> None:
    w = RateWindow(span=5.0)
    assert w.rate() is None
    for i in range(11):  # 20 msg/s, 100 B each, sampled once a second for 10 s
        w.add(float(i), 20 * i, 2000 * i)
    hz, bps = w.rate() or (0, 0)
    assert hz == pytest.approx(20.0) and bps == pytest.approx(2000.0)


def test_a_counter_that_restarts_restarts_the_window() -> None:
    w = RateWindow(span=5.0)
    w.add(0.0, 100, 1000)
    w.add(1.0, 110, 1100)
    w.add(2.0, 3, 30)  # the subscription was closed and opened again
    assert w.rate() is None
    w.add(3.0, 13, 130)
    assert w.rate() == (10.0, 100.0)


@given(st.lists(st.tuples(st.floats(0.01, 3.0), st.integers(0, 1000), st.integers(0, 10**6)), max_size=50))
def test_the_window_stays_bounded_and_rates_are_never_negative(steps: list[tuple[float, int, int]]) -> None:
    w = RateWindow(span=5.0)
    t = m = b = 0.0
    for dt, dm, db in steps:
        t, m, b = t + dt, m + dm, b + db
        w.add(t, int(m), int(b))
        assert len(w._samples) <= 5 / 0.01 + 2
        rate = w.rate()
        assert rate is None or (rate[0] >= 0 and rate[1] >= 0)


def mros_web(tmp_path: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("MROSD_", "ROS_"))}
    if "MROSD_CONFIG" not in env:  # not /etc/mrosd/mrosd.toml of this machine: an empty configuration
        (tmp_path / "empty.toml").write_text("")
        clean["MROSD_CONFIG"] = str(tmp_path / "empty.toml")
    return subprocess.run(
        [sys.executable, "-m", "mros_cli.main", "web", *args],
        env={**clean, **env},
        capture_output=True,
        text=True,
        timeout=30,
        check=False,
    )


def test_mros_web_prints_the_pages_url_with_the_token_and_warns_when_nothing_listens(tmp_path: Path) -> None:
    config = tmp_path / "mrosd.toml"
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = free.getsockname()[1]
    config.write_text(f'[web]\nfoxglove_port = {port}\ntoken = "s3cret"\nhost = "127.0.0.1"\n')
    out = mros_web(tmp_path, MROSD_CONFIG=str(config))
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == f"http://127.0.0.1:{port}/?token=s3cret"
    assert "nothing answers" in out.stderr
    off = mros_web(tmp_path, MROSD_WEB="0")
    assert off.returncode == 1 and "off" in off.stderr


def test_page_url_of_wildcard_and_ipv6_hosts() -> None:
    assert page_url("::1", 8765, "") == "http://[::1]:8765/"
    assert page_url("0.0.0.0", 1, "t") == f"http://{socket.gethostname()}:1/?token=t"


async def test_the_start_log_line_names_the_page(caplog: pytest.LogCaptureFixture) -> None:
    import logging

    from mrosd.master import Master
    from mrosd.web.server import WebServer

    caplog.set_level(logging.INFO, logger="mrosd.web.server")
    async with Master(host="127.0.0.1", port=0) as master, WebServer(master.uri, port=0, node_host="127.0.0.1") as s:
        assert f"page http://127.0.0.1:{s.port}/" in caplog.text


def test_the_x_mrosd_ops_decode_and_bad_shapes_are_refused() -> None:
    from mrosd.web import foxglove as fg

    op = fg.decode_client_text('{"op": "x-mrosd.throttle", "subscriptionId": 3, "maxRate": 20}')
    assert isinstance(op, fg.Throttle) and op.maxRate == 20
    assert isinstance(fg.decode_client_text('{"op": "x-mrosd.subscribeStats"}'), fg.SubscribeStats)
    assert isinstance(fg.decode_client_text('{"op": "x-mrosd.unsubscribeStats"}'), fg.UnsubscribeStats)
    details = fg.decode_client_text('{"op": "x-mrosd.nodeDetails", "node": "/n", "id": "x"}')
    assert isinstance(details, fg.NodeDetails) and details.node == "/n"
    for bad in (
        '{"op": "x-mrosd.throttle", "subscriptionId": 3, "maxRate": -1}',
        '{"op": "x-mrosd.throttle", "subscriptionId": -3, "maxRate": 1}',
        '{"op": "x-mrosd.throttle", "subscriptionId": 3, "maxRate": 1e300}',
        '{"op": "x-mrosd.nodeDetails"}',
    ):
        with pytest.raises(fg.ProtocolRefusal, match="malformed"):
            fg.decode_client_text(bad)
