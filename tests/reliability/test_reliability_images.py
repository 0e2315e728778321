"""Hostile images from a peer: sizes that disagree with the bytes received, huge claimed dimensions, short
steps. Each is one ``ImageError`` line, refused before any buffer is made from the claim."""

from __future__ import annotations

import tracemalloc

import pytest

from mrosd.images import ImageError, RawImage, encode_image
from mrosd.images.encoding import MAX_SIDE


@pytest.mark.parametrize(
    ("image", "words"),
    [
        (RawImage(720, 1280, "rgb8", 0, 3840, b"\0" * 100), "carries 100 bytes"),  # claims 2.7 MB, sends 100
        (RawImage(2, 2, "rgb8", 0, 5, b"\0" * 100), "shorter than"),  # step below a row
        (RawImage(1 << 31, 1 << 31, "rgb8", 0, 1, b"\0" * 16), "outside"),  # dimensions far past MAX_SIDE
        (RawImage(MAX_SIDE + 1, 1, "mono8", 0, 1, b"\0" * (MAX_SIDE + 1)), "outside"),
        (RawImage(0, 10, "mono8", 0, 10, b""), "outside"),
        (RawImage(4, 4, "mono16", 0, 8, b"\0" * 31), "carries 31 bytes"),
        (RawImage(4, 2**30, "mono8", 0, 2**30, b"\0" * 64), "outside"),
        (RawImage(2**20, 4, "16UC1", 1, 2**40, b"\0" * 64), "outside"),
    ],
)
def test_bad_image_headers_are_one_line_errors_before_any_allocation(image: RawImage, words: str) -> None:
    tracemalloc.start()
    try:
        with pytest.raises(ImageError) as err:
            encode_image(image)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert words in str(err.value) and "\n" not in str(err.value)
    assert peak < 64 * 1024  # nothing sized by the claim was made


def test_a_huge_step_with_few_rows_is_refused_by_the_bytes_actually_received() -> None:
    with pytest.raises(ImageError, match="carries"):
        encode_image(RawImage(3, 4, "mono8", 0, 2**40, b"\0" * 4096))
