"""JPEG encoders over libjpeg-turbo: simplejpeg (preferred: its wheel carries libjpeg-turbo, a pip install is
all it needs), PyTurboJPEG (needs the system's libturbojpeg), Pillow (fallback). All three are optional:
``pip install mrosd[images]`` brings simplejpeg and numpy. Without any of them an 8-bit image cannot be
encoded (``ImageError`` saying what to install); 16-bit PNG needs none of them.

Each encoder takes the received buffer as it is (rows may be padded), scales it down by a whole factor with a
box filter when asked, and encodes with 4:2:0 chroma subsampling, as OpenCV's ``imencode(".jpg")`` (the
plugin's encoder) does by default. Choice by ``python -m bench images`` (docs/images.md).
"""

from __future__ import annotations

import functools
import importlib.util
import io
from typing import TYPE_CHECKING, Any, Protocol

from mrosd.images.encoding import ImageError, PixelLayout, RawImage

if TYPE_CHECKING:
    import numpy as np

__all__ = ["ENCODERS", "JpegEncoder", "available_encoders", "best_encoder", "encoder"]


class JpegEncoder(Protocol):
    """``encode`` returns the JPEG and the width and height it has after scaling."""

    name: str

    def encode(self, image: RawImage, layout: PixelLayout, factor: int, quality: int) -> tuple[bytes, int, int]: ...


def _pixels(image: RawImage, layout: PixelLayout, factor: int) -> np.ndarray[Any, Any]:
    """A (height, width, channels) uint8 view of the rows (no copy), box-averaged by ``factor`` if above 1."""
    import numpy as np

    height, width, step = image.height, image.width, image.step
    rows = np.frombuffer(image.data, np.uint8, count=step * height).reshape(height, step)
    img = rows[:, : width * layout.channels].reshape(height, width, layout.channels)
    if factor == 1:
        return img
    return _reduce(img, factor)


def _reduce(img: np.ndarray[Any, Any], factor: int) -> np.ndarray[Any, Any]:
    """Box-average whole ``factor`` x ``factor`` blocks (at least one pixel is kept). Pillow's ``reduce`` when
    installed (C, about 3x faster than the numpy sums here), else numpy with 16-bit sums."""
    import numpy as np

    height, width, channels = img.shape
    h, w = max(1, height // factor), max(1, width // factor)
    if height < factor or width < factor:  # smaller than one block: keep a corner
        return np.ascontiguousarray(img[:h, :w])
    img = img[: h * factor, : w * factor]
    if importlib.util.find_spec("PIL") is not None:
        from PIL import Image

        mode = {1: "L", 3: "RGB", 4: "RGBA"}[channels]
        plane = np.ascontiguousarray(img[..., 0] if channels == 1 else img)
        small = np.asarray(Image.fromarray(plane, mode).reduce(factor))
        return small.reshape(h, w, channels)
    total = np.zeros((h, w, channels), np.uint16 if factor <= 16 else np.uint32)
    for dy in range(factor):
        for dx in range(factor):
            np.add(total, img[dy::factor, dx::factor], out=total)
    total += factor * factor // 2  # round to nearest, as Pillow does
    np.floor_divide(total, factor * factor, out=total)
    return total.astype(np.uint8)


class SimpleJpeg:
    """simplejpeg: libjpeg-turbo inside its wheel."""

    name = "simplejpeg"

    def __init__(self) -> None:
        import simplejpeg

        self._encode = simplejpeg.encode_jpeg

    def encode(self, image: RawImage, layout: PixelLayout, factor: int, quality: int) -> tuple[bytes, int, int]:
        img = _pixels(image, layout, factor)
        sub = "Gray" if layout.order == "GRAY" else "420"
        return bytes(self._encode(img, quality, layout.order, sub)), img.shape[1], img.shape[0]


class TurboJpeg:
    """PyTurboJPEG: ctypes over the system's libturbojpeg (Debian: libturbojpeg0)."""

    name = "turbojpeg"

    def __init__(self) -> None:
        import turbojpeg

        self._tj = turbojpeg.TurboJPEG()  # OSError/RuntimeError when libturbojpeg is not installed
        self._formats = {
            "RGB": turbojpeg.TJPF_RGB,
            "BGR": turbojpeg.TJPF_BGR,
            "RGBA": turbojpeg.TJPF_RGBX,
            "BGRA": turbojpeg.TJPF_BGRX,
            "GRAY": turbojpeg.TJPF_GRAY,
        }
        self._sub = {True: turbojpeg.TJSAMP_GRAY, False: turbojpeg.TJSAMP_420}

    def encode(self, image: RawImage, layout: PixelLayout, factor: int, quality: int) -> tuple[bytes, int, int]:
        img = _pixels(image, layout, factor)
        gray = layout.order == "GRAY"
        out = self._tj.encode(img, quality, self._formats[layout.order], self._sub[gray])
        return bytes(out), img.shape[1], img.shape[0]


class PillowJpeg:
    """Pillow: its own libjpeg(-turbo); reads the padded rows itself, so it needs no numpy."""

    name = "pillow"
    _MODES = {"RGB": ("RGB", "RGB"), "BGR": ("RGB", "BGR"), "RGBA": ("RGB", "RGBX"), "BGRA": ("RGB", "BGRX")}

    def __init__(self) -> None:
        from PIL import Image

        self._image = Image

    def encode(self, image: RawImage, layout: PixelLayout, factor: int, quality: int) -> tuple[bytes, int, int]:
        mode, raw = self._MODES.get(layout.order, ("L", "L"))
        size, rows = (image.width, image.height), bytes(memoryview(image.data)[: image.step * image.height])
        img = self._image.frombuffer(mode, size, rows, "raw", raw, image.step, 1)
        if factor > 1:
            crop = (
                min(img.width, img.width // factor * factor or 1),
                min(img.height, img.height // factor * factor or 1),
            )
            img = img.crop((0, 0, *crop)).reduce(factor)  # box filter over whole blocks, as the numpy path
        out = io.BytesIO()
        img.save(out, "JPEG", quality=quality, subsampling=2)  # 2: 4:2:0
        return out.getvalue(), img.width, img.height


#: In order of preference (``python -m bench images`` measured them; docs/images.md).
ENCODERS: dict[str, type[SimpleJpeg] | type[TurboJpeg] | type[PillowJpeg]] = {
    "simplejpeg": SimpleJpeg,
    "turbojpeg": TurboJpeg,
    "pillow": PillowJpeg,
}
_MODULES = {"simplejpeg": ("simplejpeg", "numpy"), "turbojpeg": ("turbojpeg", "numpy"), "pillow": ("PIL",)}


@functools.cache
def encoder(name: str) -> JpegEncoder:
    """The encoder ``name`` (one of ``ENCODERS``), made once.

    Raises:
        ImageError: it is not installed (or, for turbojpeg, libturbojpeg is missing).
    """
    if name not in ENCODERS:
        raise ImageError(f"no JPEG encoder {name!r}; choose from {', '.join(ENCODERS)}")
    missing = [m for m in _MODULES[name] if importlib.util.find_spec(m) is None]
    if missing:
        raise ImageError(f"JPEG encoder {name} needs {', '.join(missing)}: pip install 'mrosd[images]'")
    try:
        return ENCODERS[name]()
    except (ImportError, OSError, RuntimeError) as exc:
        raise ImageError(f"JPEG encoder {name} cannot load: {exc}") from exc


def available_encoders() -> list[str]:
    """The names of the encoders that load here, best first."""
    names = []
    for name in ENCODERS:
        try:
            encoder(name)
        except ImageError:
            continue
        names.append(name)
    return names


def best_encoder() -> JpegEncoder:
    """The first encoder of ``ENCODERS`` that loads.

    Raises:
        ImageError: none does: the message says to install ``mrosd[images]``.
    """
    names = available_encoders()
    if not names:
        raise ImageError("no JPEG encoder installed: pip install 'mrosd[images]' (simplejpeg and numpy)")
    return encoder(names[0])
