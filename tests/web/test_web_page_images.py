"""The page's image view in headless Chromium against a running daemon: a raw Image topic shown from its
``/compressed`` twin (made by the daemon's web part) or raw, with a toggle; frames per second and age on
screen; a per-topic rate limit. One daemon, one camera and one browser for the module; screenshots as the
other page tests save them.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Iterator

import pytest

from tests.integration.daemon.daemonproc import DaemonRun
from tests.rosenv import Processes
from tests.web.test_web_page import HERE, Browser, cwd_env, page_url, pytestmark, read_pixels

__all__ = ["pytestmark"]

W, H, HZ = 320, 240, 30.0


@pytest.fixture(scope="module")
def page(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Browser, str]]:
    tmp = tmp_path_factory.mktemp("page_images")
    procs = Processes(tmp)
    config = tmp / "mrosd.toml"
    config.write_text('[master]\ncleanup_interval = 0\n\n[[web.images]]\ntopics = ["/camera/*"]\nquality = 70\n')
    run = DaemonRun(procs, tmp, "--config", str(config))
    try:
        status = run.ready()
        assert status.startswith("running:"), status
        env = {
            **cwd_env(),
            "ROS_MASTER_URI": run.uri,
            "ROS_HOSTNAME": "127.0.0.1",
            "PYTHONPATH": os.pathsep.join(sys.path),
        }
        camera = [sys.executable, str(HERE / "stamped_camera.py"), str(W), str(H), str(HZ), "0"]
        procs.start(camera, env, stdout=None, stderr=None)
        browser = Browser(procs)
        yield browser, page_url(status)
        assert browser.proc.stdin is not None
        browser.proc.stdin.close()  # page_browser.mjs closes Chromium and exits (a kill waits its grace period)
        browser.proc.wait(10)
    finally:
        run.close()
        procs.close()


def overlay(browser: Browser) -> str:
    return str(browser.eval("document.querySelector('#image-overlay').textContent"))


def test_the_compressed_view_shows_fps_and_age_and_the_toggle_switches_to_raw(page: tuple[Browser, str]) -> None:
    browser, url = page
    browser.do("goto", url=url + "?images=compressed#topic=/camera/image")
    browser.until("mrosdPage.state.current && mrosdPage.state.current.topic === '/camera/image/compressed'")
    browser.until("mrosdPage.meter.fps >= 10 && mrosdPage.meter.ageMs !== null", timeout=30)
    text = overlay(browser)
    assert "compressed" in text and "fps" in text and "age" in text, text
    age = browser.eval("mrosdPage.meter.ageMs")
    assert 0 <= age < 1000, age
    # the picture is drawn at the camera's size, not blank
    assert browser.eval("[document.querySelector('#image').width, document.querySelector('#image').height]") == [W, H]
    assert any(sum(px[:3]) > 0 for px in read_pixels(browser, [(8, 8), (100, 60), (300, 200)]))
    browser.shot("image_compressed.png")

    browser.eval("document.querySelector('#image-mode').click()")
    browser.until("mrosdPage.state.current.topic === '/camera/image'")
    browser.until("mrosdPage.meter.fps >= 5", timeout=30)
    assert "raw" in overlay(browser)
    browser.shot("image_raw.png")


def test_the_rate_limit_control_throttles_the_view(page: tuple[Browser, str]) -> None:
    browser, url = page
    browser.do("goto", url=url + "?images=compressed#topic=/camera/image")
    browser.until("mrosdPage.meter.fps >= 10", timeout=30)
    browser.eval(
        "(() => { const r = document.querySelector('#image-rate'); r.value = '4';"
        " r.dispatchEvent(new Event('change')); })()"
    )
    time.sleep(1.5)  # a full one-second fps window after the change
    fps = browser.until("mrosdPage.meter.fps > 0 && mrosdPage.meter.fps")
    assert fps <= 6, fps


def test_on_loopback_the_default_is_raw(page: tuple[Browser, str]) -> None:
    browser, url = page
    browser.do("goto", url=url + "#topic=/camera/image")
    browser.until("mrosdPage.state.current && mrosdPage.meter.fps > 0", timeout=30)
    assert browser.eval("mrosdPage.state.current.topic") == "/camera/image"
    assert url.startswith("http://127.0.0.1:")


def test_quality_and_width_set_from_the_page_reach_the_encoder(page: tuple[Browser, str]) -> None:
    browser, url = page
    browser.do("goto", url=url + "?images=compressed#topic=/camera/image")
    # the [[web.images]] rule's quality, as the daemon answers it
    browser.until("!document.querySelector('#image-settings').hidden")
    assert browser.eval("document.querySelector('#image-quality').value") == "70"
    browser.eval(
        "(() => { const w = document.querySelector('#image-width'); w.value = '320';"
        " w.dispatchEvent(new Event('change')); })()"
    )
    # 320 wide already: the width stays; 160 halves it
    browser.eval(
        "(() => { const w = document.querySelector('#image-width'); w.add(new Option('160', '160')); w.value = '160';"
        " w.dispatchEvent(new Event('change')); })()"
    )
    browser.until("document.querySelector('#image').width === 160", timeout=20)
    browser.shot("image_settings.png")
    browser.eval(
        "(() => { const w = document.querySelector('#image-width'); w.value = '0';"
        " w.dispatchEvent(new Event('change')); })()"
    )
    browser.until(f"document.querySelector('#image').width === {W}", timeout=20)
