"""``[images]`` in the daemon's configuration: defaults off, globs checked, the environment overrides."""

from __future__ import annotations

import pytest

from mrosd.config import ImagesConfig, apply_environment, parse_config
from mrosd.errors import ConfigError


def test_images_are_off_by_default_with_the_plugins_quality() -> None:
    images = parse_config("").images
    assert images == ImagesConfig() and images.compressed == [] and images.quality == 80


def test_images_section_is_read_and_checked() -> None:
    images = parse_config('[images]\ncompressed = ["/camera/*"]\nquality = 50\nmax_width = 640\n').images
    assert (images.compressed, images.quality, images.max_width) == (["/camera/*"], 50, 640)
    for text, needle in [
        ('compressed = ["camera/*"]', "images.compressed[0]"),
        ("quality = 0", "quality"),
        ("png_level = 10", "png_level"),
        ("max_width = -1", "max_width"),
        ("colour = true", "colour"),
    ]:
        with pytest.raises(ConfigError, match=needle.replace("[", r"\[")):
            parse_config(f"[images]\n{text}\n", "mrosd.toml")


def test_environment_sets_the_globs() -> None:
    cfg = apply_environment(parse_config(""), {"MROSD_IMAGES_COMPRESSED": "/camera/*, /arm/**/image"})
    assert cfg.images.compressed == ["/camera/*", "/arm/**/image"]
    with pytest.raises(ConfigError, match="MROSD_IMAGES_COMPRESSED"):
        apply_environment(parse_config(""), {"MROSD_IMAGES_COMPRESSED": "camera"})
