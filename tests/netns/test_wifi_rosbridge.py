"""roslibpy over rosbridge behind a 20 Mbit/s link (tests/netns/wifi.py), CBOR and permessage-deflate, subscribed
to the raw camera beside the small topics: the small topics keep their rates."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.netns.wifi import CAMERA, FLOAT, ODOM, WifiScene, wifi_scene

pytestmark = pytest.mark.root


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory) -> Iterator[WifiScene]:
    with wifi_scene(tmp_path_factory.mktemp("wifi_rb")) as lab:
        yield lab


def test_roslibpy_with_cbor_and_deflate_keeps_the_small_topics_rates_beside_a_raw_camera(scene: WifiScene) -> None:
    client = scene.roslibpy(
        {CAMERA: "sensor_msgs/Image", ODOM: "nav_msgs/Odometry", FLOAT: "std_msgs/Float64"}, shaped=True
    )
    try:
        assert "permessage-deflate" in client.opened.get("extensions", ""), client.opened
        got = client.collect(seconds=3.0, warmup=2.0)
    finally:
        client.close()
    summary = {t: (s.count, round(s.rate, 1), round(s.median_age, 3)) for t, s in got.items()}
    print("count, Hz, median age s" + (", p90 age s" if len(next(iter(summary.values()))) > 3 else ""), summary)
    assert FLOAT in got and got[FLOAT].rate >= 95.0, summary
    assert ODOM in got and got[ODOM].rate >= 0.95 * 50, summary
    assert CAMERA in got and got[CAMERA].count >= 1, summary
