"""A Foxglove client behind a 20 Mbit/s link (tests/netns/wifi.py): small topics are not starved by a raw camera,
the camera's frames drop in the daemon with the newest kept, and permessage-deflate is negotiated when offered.

One scene (namespaces, daemon, publisher) for the whole module; each test runs its own clients.
"""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from tests.netns.wifi import CAMERA, FLOAT, MASTER_PORT, ODOM, WifiScene, wifi_scene

pytestmark = pytest.mark.root

#: 1280x720 rgb8 is 2.76 MB: 1.1 s of a 20 Mbit/s link per frame, so at most one frame a second gets through
FRAME_WIRE_S = 1280 * 720 * 3 * 8 / 20e6


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WifiScene]:
    with wifi_scene(tmp_path_factory.mktemp("wifi")) as lab:
        yield lab


def test_small_topics_keep_their_rate_beside_a_raw_camera_and_frames_drop_with_the_newest_kept(
    scene: WifiScene,
) -> None:
    fox = scene.foxglove(shaped=True)
    try:
        fox.subscribe(CAMERA, ODOM, FLOAT)
        got = fox.collect(seconds=3.0, warmup=2.0)
    finally:
        fox.close()
    summary = {t: (s.count, round(s.rate, 1), round(s.median_age, 3), round(s.p90_age, 3)) for t, s in got.items()}
    print("count, Hz, median age s, p90 age s", summary)
    if FLOAT in got:
        st = got[FLOAT].stamps
        gaps = sorted((b - a for a, b in zip(sorted(st), sorted(st)[1:], strict=False)), reverse=True)[:8]
        print("largest gaps between Float64 stamps received (s)", [round(g, 3) for g in gaps])
    assert FLOAT in got and got[FLOAT].rate >= 95.0, summary
    assert ODOM in got and got[ODOM].rate >= 0.95 * 50, summary
    camera = got.get(CAMERA)
    assert camera is not None and camera.count >= 2, summary
    # the newest kept: a frame that reaches the client is at most the one in flight plus the next (not a
    # backlog of seconds of frames in the daemon's queue or the kernel's send buffer)
    assert camera.p90_age <= 3 * FRAME_WIRE_S, summary
    assert camera.stamps == sorted(camera.stamps), "frames out of order"
    assert any("dropped" in s["message"] for s in fox.statuses), fox.statuses
    # and the daemon's status file (``mros daemon status``) names this client's drops of the camera
    status = json.loads((scene.tmp / "run" / f"mrosd-{MASTER_PORT}.json").read_text())
    assert any(CAMERA in d["dropped"] for d in status["web"]["drops"]), status["web"]


def test_permessage_deflate_is_negotiated_when_the_client_offers_it_and_not_needed_when_it_does_not(
    scene: WifiScene,
) -> None:
    offered = scene.foxglove(shaped=True, deflate=True)
    plain = scene.foxglove(shaped=True, deflate=False)
    try:
        assert "permessage-deflate" in offered.opened.get("extensions", ""), offered.opened
        assert plain.opened.get("extensions", "") == "", plain.opened
        for fox in (offered, plain):
            fox.subscribe(ODOM, FLOAT)
        for fox in (offered, plain):
            got = fox.collect(seconds=1.0, warmup=0.3, settle=0.3)  # no camera on this link now: no wait
            assert got.get(FLOAT) is not None and got[FLOAT].count >= 80, got.keys()
    finally:
        offered.close()
        plain.close()


def test_a_loopback_client_is_not_slowed_by_a_client_on_the_shaped_link(scene: WifiScene) -> None:
    slow = scene.foxglove(shaped=True)
    fast = scene.foxglove(shaped=False)
    try:
        slow.subscribe(CAMERA, FLOAT)
        fast.subscribe(CAMERA, FLOAT)
        got = fast.collect(seconds=2.0, warmup=1.0, settle=0.3)
    finally:
        slow.close()
        fast.close()
    assert got.get(CAMERA) is not None and got[CAMERA].rate >= 25.0, {t: s.rate for t, s in got.items()}
    assert got[FLOAT].rate >= 95.0, {t: s.rate for t, s in got.items()}
