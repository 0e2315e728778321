"""``[[web.images]]``: the encoder settings of the web part's ``T/compressed`` topics; each error one line
naming the key."""

from __future__ import annotations

from pathlib import Path

import pytest

from mrosd.config import load_config
from mrosd.errors import ConfigError


def test_web_images_tables_are_read_with_their_defaults(tmp_path: Path) -> None:
    path = tmp_path / "m.toml"
    path.write_text('[[web.images]]\ntopics = ["/camera/*"]\nquality = 60\n\n[[web.images]]\ntopics = ["/**"]\n')
    first, second = load_config(path, {}).web.images
    assert (first.topics, first.quality, first.max_width, first.max_rate) == (["/camera/*"], 60, 0, 0.0)
    assert (second.quality, second.max_width, second.max_rate) == (80, 0, 0.0)


@pytest.mark.parametrize(
    ("body", "key"),
    [
        ('topics = ["/c"]\nquality = 0', "web.images[0].quality"),
        ('topics = ["/c"]\nmax_rate = -1', "web.images[0].max_rate"),
        ('topics = ["/c"]\nmax_width = 8', "web.images[0].max_width"),
        ('topics = ["c/*"]', "web.images[0].topics[0]"),
        ('topics = ["/c"]\njpeg = 1', "jpeg"),
        ("quality = 50", "topics"),
    ],
)
def test_bad_web_images_values_are_one_line_naming_the_key(tmp_path: Path, body: str, key: str) -> None:
    path = tmp_path / "m.toml"
    path.write_text("[[web.images]]\n" + body + "\n")
    with pytest.raises(ConfigError) as err:
        load_config(path, {})
    assert key in str(err.value) and "\n" not in str(err.value)
