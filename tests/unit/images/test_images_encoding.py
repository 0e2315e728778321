"""The pure encoder core: compressed_image_transport's ``format`` strings, JPEG within JPEG error for every
installed encoder, lossless 16-bit PNG in either byte order, padded rows, whole-factor downscaling."""

from __future__ import annotations

import io

import pytest

from mrosd.images import EncodeSettings, ImageError, RawImage, compressed_format, encode_image
from mrosd.images.jpeg import available_encoders, encoder
from mrosd.images.png import encode_png

np = pytest.importorskip("numpy")
Image = pytest.importorskip("PIL.Image")

ENCODERS = available_encoders()


def _picture(h: int, w: int, channels: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    planes = [(x * 255 // max(1, w - 1)), (y * 255 // max(1, h - 1)), ((x + y) * 127 // max(1, w + h))]
    planes.append(np.full_like(x, 200))
    return np.stack(planes[:channels], axis=-1).astype(np.uint8)


@pytest.mark.parametrize(
    ("encoding", "fmt"),
    [
        ("rgb8", "rgb8; jpeg compressed bgr8"),
        ("bgr8", "bgr8; jpeg compressed bgr8"),
        ("rgba8", "rgba8; jpeg compressed bgr8"),
        ("bgra8", "bgra8; jpeg compressed bgr8"),
        ("mono8", "mono8; jpeg compressed "),
        ("8UC1", "8UC1; jpeg compressed "),
        ("8UC3", "8UC3; jpeg compressed "),
        ("mono16", "mono16; png compressed "),
        ("16UC1", "16UC1; png compressed "),
    ],
)
def test_format_is_written_as_the_compressed_plugin_writes_it(encoding: str, fmt: str) -> None:
    assert compressed_format(encoding) == fmt


@pytest.mark.parametrize("encoding", ["bayer_rggb8", "yuv422", "32FC1", "16SC1", "rgb16", "", "x" * 1000])
def test_unsupported_encodings_are_one_line_errors(encoding: str) -> None:
    with pytest.raises(ImageError) as err:
        encode_image(RawImage(2, 2, encoding, 0, 12, b"\0" * 48))
    assert "\n" not in str(err.value) and len(str(err.value)) < 300


@pytest.mark.parametrize("name", ENCODERS)
@pytest.mark.parametrize(
    ("encoding", "channels", "order"),
    [("rgb8", 3, [0, 1, 2]), ("bgr8", 3, [2, 1, 0]), ("rgba8", 4, [0, 1, 2]), ("bgra8", 4, [2, 1, 0])],
)
def test_colour_decodes_to_the_same_picture_within_jpeg_error(
    name: str, encoding: str, channels: int, order: list[int]
) -> None:
    rgb = _picture(48, 64, 3)
    raw = rgb[..., order]
    if channels == 4:
        raw = np.concatenate([raw, np.full((48, 64, 1), 255, np.uint8)], axis=-1)
    pad = 5  # padded rows: step above width * channels
    rows = np.zeros((48, 64 * channels + pad), np.uint8)
    rows[:, : 64 * channels] = raw.reshape(48, -1)
    frame = encode_image(RawImage(48, 64, encoding, 0, 64 * channels + pad, rows.tobytes()), jpeg=encoder(name))
    assert frame.data[:2] == b"\xff\xd8"
    back = np.asarray(Image.open(io.BytesIO(frame.data)).convert("RGB"), dtype=np.int16)
    assert np.abs(back - rgb).mean() < 4.0


@pytest.mark.parametrize("name", ENCODERS)
def test_mono_stays_grey_and_downscales_by_a_whole_factor(name: str) -> None:
    grey = _picture(60, 100, 1)[..., 0]
    frame = encode_image(
        RawImage(60, 100, "mono8", 0, 100, grey.tobytes()), EncodeSettings(max_width=40), encoder(name)
    )
    img = Image.open(io.BytesIO(frame.data))
    assert img.mode == "L" and img.size == (33, 20) == (frame.width, frame.height)  # factor ceil(100/40) = 3
    box = grey[:60, :99].reshape(20, 3, 33, 3).mean(axis=(1, 3))
    assert np.abs(np.asarray(img, dtype=np.float64) - box).mean() < 4.0


@pytest.mark.parametrize("bigendian", [0, 1])
def test_sixteen_bit_is_lossless_png_in_either_byte_order(bigendian: int) -> None:
    depth = (np.arange(30 * 40, dtype=np.uint32) * 977 % 65536).astype(np.uint16).reshape(30, 40)
    src = depth.astype(">u2" if bigendian else "<u2")
    rows = np.zeros((30, 84), np.uint8)
    rows[:, :80] = src.view(np.uint8).reshape(30, 80)
    frame = encode_image(RawImage(30, 40, "16UC1", bigendian, 84, rows.tobytes()))
    assert frame.format == "16UC1; png compressed "
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(frame.data))).astype(np.uint16), depth)


def test_sixteen_bit_downscaling_keeps_samples_never_averages_them() -> None:
    depth = (np.arange(30 * 40, dtype=np.uint16) * 31).reshape(30, 40)
    frame = encode_image(RawImage(30, 40, "mono16", 0, 80, depth.tobytes()), EncodeSettings(max_width=20))
    back = np.asarray(Image.open(io.BytesIO(frame.data))).astype(np.uint16)
    assert np.array_equal(back, depth[::2, ::2])


def test_png_writer_output_is_read_back_by_pillow() -> None:
    png = encode_png(3, 2, [b"\x00\x10\x20", b"\x30\x40\x50"], bit_depth=8, color_type=0, level=9)
    assert np.asarray(Image.open(io.BytesIO(png))).tolist() == [[0, 16, 32], [48, 64, 80]]


@pytest.mark.parametrize(
    "kwargs",
    [{"quality": 0}, {"quality": 101}, {"max_width": -1}, {"png_level": 10}],
)
def test_settings_out_of_range_are_refused(kwargs: dict[str, int]) -> None:
    with pytest.raises(ValueError):
        EncodeSettings(**kwargs)
