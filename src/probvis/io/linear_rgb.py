"""Textures and environment maps read as linear RGB, as Mitsuba's bitmap loader gives them: EXR, Radiance HDR
and PFM as stored, PNG, JPEG, BMP, TGA and PPM decoded from sRGB; a file by its first bytes where they name a
format (an EXR named .png is an EXR), else by its extension. Sizes are checked from the header before anything
is decoded."""
import re
import warnings
from pathlib import Path

import numpy as np

from ..errors import ProbvisError, missing_file
from .image import MAX_IMAGE_BYTES, MAX_IMAGE_PIXELS, check_readable, read_exr, read_pfm
from .library_output import library_output


def srgb_to_linear(v):
    """The sRGB transfer function's inverse, for 8-bit images."""
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _hdr_size(path):
    """(width, height) a Radiance HDR file's header declares ((0, 0) if it has none readable)."""
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    found = re.search(rb"\n\n[-+]Y (\d{1,12}) [-+]X (\d{1,12})", head)
    return (int(found.group(2)), int(found.group(1))) if found else (0, 0)


# Pillow modes read as another: 1-bit as 8-bit grey, CMYK and other colour spaces as RGB (their fourth channel
# is not alpha)
_PILLOW_FORMATS = (".png", ".jpg", ".jpeg", ".bmp", ".tga", ".ppm")  # 8 or 16 bits, sRGB-encoded, as Mitsuba reads them
READ_FORMATS = (".exr", ".hdr", ".pfm", *_PILLOW_FORMATS)  # what `read_linear_rgb` reads
_PILLOW_MODES = {"1": "L", "CMYK": "RGB", "YCbCr": "RGB", "LAB": "RGB", "HSV": "RGB"}
# what Pillow finds in a file read as one of `_PILLOW_FORMATS`: the formats Mitsuba reads by content, whatever the
# extension (MPO: a camera's JPEG with a second picture; DIB: a BMP's bitmap)
_PILLOW_CONTENT = {"PNG", "JPEG", "MPO", "BMP", "DIB", "TGA", "PPM"}


_SIGNATURES = ((b"\x89PNG\r\n\x1a\n", ".png"), (b"\xff\xd8\xff", ".jpg"), (b"v/1\x01", ".exr"),
               (b"#?", ".hdr"), (b"PF\n", ".pfm"), (b"Pf\n", ".pfm"), (b"BM", ".bmp"), (b"P5", ".ppm"),
               (b"P6", ".ppm"))  # a file's first bytes and the format they start


def _format_by_content(path):
    """The extension of the format a file's first bytes announce (None: none of `_SIGNATURES`)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return None
    return next((ext for magic, ext in _SIGNATURES if head.startswith(magic)), None)


def read_linear_rgb(path, raw=False):
    """An image file as linear RGB (h, w, 3) float64, as Mitsuba's bitmap loader gives it: EXR, HDR and PFM as
    stored, `_PILLOW_FORMATS` decoded from sRGB (unless `raw`); grey repeated over the channels, alpha dropped.
    Raises `ProbvisError` naming the file when it is missing or unreadable."""
    path = Path(path)
    if not path.exists():
        raise ProbvisError(missing_file(path, "image"))
    if not path.is_file():
        raise ProbvisError(f"image {path} is not a regular file")
    size = path.stat().st_size
    if size == 0:
        raise ProbvisError(f"image {path} is empty (0 bytes)")
    if size > MAX_IMAGE_BYTES:
        raise ProbvisError(f"image {path} is {size / 2**30:.1f} GiB, more than any texture or environment map "
                           f"probvis reads (at most {MAX_IMAGE_BYTES >> 30} GiB)")
    check_readable(path, "image")
    ext = _format_by_content(path) or path.suffix.lower()  # as Mitsuba's bitmap loader: by the file's first bytes
    if ext == ".exr":
        img = read_exr(path)
    elif ext == ".pfm":
        img = read_pfm(path)
    elif ext == ".hdr":
        import cv2

        w, h = _hdr_size(path)
        if w * h > MAX_IMAGE_PIXELS:
            raise ProbvisError(f"{path}: image is {w}x{h} ({w * h / 1e6:.0f} Mpixel), above the "
                               f"{MAX_IMAGE_PIXELS / 1e6:.0f} Mpixel probvis reads (scale it down)")
        _check_decode_memory(path, w, h, 3)
        with library_output() as said:  # OpenCV logs a failed read on lines of its own
            try:
                img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
            except cv2.error:
                img = None
            found = re.search(r"error: \([^)]*\) (.*?)(?: in function|$)", said())  # "...: error: (-2:...) why"
            reason = found.group(1) if found else said()
        if img is None:
            raise ProbvisError(f"cannot read Radiance HDR image {path}" + (f" ({reason[:300]})" if reason else ""))
        img = img[..., ::-1] if img.ndim == 3 else img
    elif ext in _PILLOW_FORMATS:
        import imageio.v3 as iio

        from PIL import Image

        limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None  # Pillow's own bomb check names no size
        mode = content = None
        try:
            with Image.open(path) as im:  # the header only: refuse a size no texture needs before decoding it
                w, h = im.size
                mode, bands, content = im.mode, len(im.getbands()), im.format
        except Exception:
            w = h = bands = 0
        finally:
            Image.MAX_IMAGE_PIXELS = limit
        if content is not None and content not in _PILLOW_CONTENT:
            raise ProbvisError(f"{path}: the file holds a {content} image, not a format probvis reads (supported: "
                               f"{', '.join(READ_FORMATS)}); Mitsuba refuses it too")
        if content in ("BMP", "DIB") and mode == "P":
            warnings.warn(f"{path}: a palette BMP: probvis reads its colours, Mitsuba 3.9 its palette indices as "
                          "grey (a different image); save it as RGB for the same image in both", stacklevel=2)
        if w * h > MAX_IMAGE_PIXELS:
            raise ProbvisError(f"{path}: image is {w}x{h} ({w * h / 1e6:.0f} Mpixel), above the "
                               f"{MAX_IMAGE_PIXELS / 1e6:.0f} Mpixel probvis reads (scale it down)")
        _check_decode_memory(path, w, h, bands)
        try:
            with warnings.catch_warnings():  # probvis's own limit applies, above: Pillow's "decompression bomb" note
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # would repeat it in other words
                data = iio.imread(path, plugin="pillow", mode=_PILLOW_MODES.get(mode))
        except MemoryError:
            raise
        except Exception as exc:
            raise ProbvisError(f"cannot read image {path}: not a valid {ext[1:].upper()} file "
                               f"({type(exc).__name__})") from None
        if data.dtype.kind != "u":
            raise ProbvisError(f"{path}: unsupported pixel type {data.dtype}")
        img = data.astype(np.float64) / np.iinfo(data.dtype).max
        img = img if raw else srgb_to_linear(img)
    else:
        raise ProbvisError(f"{path}: unsupported image format '{ext}' (supported: {', '.join(READ_FORMATS)})")
    img = np.asarray(img, dtype=np.float64)
    if img.ndim == 2:
        img = img[..., None]
    if img.shape[2] in (2, 4):
        img = img[..., :-1]  # alpha
    if img.shape[2] == 1:
        img = np.repeat(img, 3, axis=2)
    if not np.all(np.isfinite(img)):
        raise ProbvisError(f"{path}: the image has NaN or infinite pixels")
    return np.ascontiguousarray(img)


def _check_decode_memory(path, w, h, bands):
    """Refuse an image whose decoding would not fit in the memory available (the machine's or the process's
    limit), from its header: its `bands` channels as float64 through the conversion's temporaries (about four),
    then the linear RGB result (measured: 103 bytes a pixel for an RGB PNG)."""
    from ..memory import GIB, available

    need, have = w * h * (bands * 8 * 4 + 24), available()
    if need > have:
        raise ProbvisError(f"{path}: a {w}x{h} image needs about {need / GIB:.1f} GiB to read as linear RGB but "
                           f"{have / GIB:.1f} GiB are available (the machine's or the process's limit): scale it down")
