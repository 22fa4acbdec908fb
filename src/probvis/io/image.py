"""Image files: EXR (float32, signed values kept), PFM, and PNG (sRGB tonemap with exposure). Textures and
environment maps are read as linear RGB by `linear_rgb`.

Every writer goes through a temporary file in the destination folder and an atomic rename, so an
interrupted or failed write never leaves a partial file under the requested name.
"""
import errno
import os
import warnings
from pathlib import Path

import numpy as np

from ..errors import ProbvisError, is_number, missing_file, shown
from .atomic import atomic_path, temp_beside
from .library_output import library_output

FORMATS = (".exr", ".pfm", ".png")
MAX_EXPOSURE = 64.0  # stops: 2^64 scales any radiance out of range
MAX_IMAGE_BYTES = 4 << 30  # an image file larger than this is refused before reading

XYZ_TO_SRGB = np.array([[3.240479, -1.537150, -0.498535],  # CIE XYZ to linear sRGB (Rec. 709, D65), as Mitsuba's
                        [-0.969256, 1.875991, 0.041556],
                        [0.055648, -0.204043, 1.057311]])


def utf8_path(path):
    """Whether the full path (its folders too, links resolved) is UTF-8 as the file system stores it: OpenEXR
    takes names as UTF-8 text (`exr_name`)."""
    try:
        exr_name(os.path.realpath(path))
    except UnicodeError:
        return False
    return True


def exr_name(path):
    """The name OpenEXR opens as `path`: its bytes on the file system read as UTF-8 (under a locale whose file
    system encoding is not UTF-8, Python holds a UTF-8 name's bytes as surrogate escapes, which OpenEXR's
    encoder refuses). Raises UnicodeError for a name whose bytes are not UTF-8."""
    return os.fsencode(path).decode("utf-8")


def check_writable(path, formats=FORMATS, role="an image"):
    """Fail early, before a long render, when `path` cannot be written or its extension is not one of `formats`
    (`role` names what it is for in the message)."""
    if not str(path):
        raise ProbvisError(f"{role} needs a file name (got an empty one)")
    if str(path).endswith(os.sep):
        raise ProbvisError(f"cannot write '{path}': the name ends in '{os.sep}' (a folder's name); give a file name")
    path = Path(path)
    if path.name.lower() in formats:  # '.exr' is a hidden file's name, without an extension
        raise ProbvisError(f"cannot write '{path}': the name is an extension alone; give a name before it, such as "
                           f"'{path.with_name('out' + path.name)}'")
    if path.suffix.lower() not in formats:
        raise ProbvisError(f"cannot write '{path}': {role} must be a {', '.join(formats)} file")
    if path.suffix.lower() == ".exr" and not utf8_path(path):
        raise ProbvisError(f"cannot write '{path}': OpenEXR's writer takes only file and folder names in UTF-8; "
                           "give another name")
    try:
        if path.is_symlink():
            try:
                path.resolve()
            except RuntimeError:  # Python before 3.13 (later ones raise an OSError, ELOOP)
                raise ProbvisError(f"cannot write '{path}': it is a symbolic link that loops back to itself; "
                                   "remove it or give another name") from None
        # a symbolic link is written through: its target's folder counts
        parent = (Path(os.path.realpath(path)).parent if path.is_symlink() else
                  path.parent if str(path.parent) else Path("."))
        if not parent.is_dir():
            what = "is a file, not a folder" if parent.exists() else "does not exist"
            raise ProbvisError(f"cannot write '{path}': folder '{parent}' {what}")
        if not os.access(parent, os.W_OK):
            raise ProbvisError(f"cannot write '{path}': folder '{parent}' is not writable")
        if path.is_dir():
            raise ProbvisError(f"cannot write '{path}': it is a folder")
        if path.exists() and not path.resolve().is_file():
            raise ProbvisError(f"cannot write '{path}': it is not a regular file (a pipe, socket or device); "
                               "give a file name")
        # what the atomic write will do: a temporary file in the output's folder, renamed
        fd, tmp = temp_beside(parent, path.suffix)
        os.close(fd)
        os.unlink(tmp)
        if len(os.fsencode(path.name)) > os.pathconf(parent, "PC_NAME_MAX"):
            raise OSError(errno.ENAMETOOLONG, os.strerror(errno.ENAMETOOLONG))
    except OSError as exc:
        link = f" (a link to '{os.path.realpath(path)}')" if os.path.islink(path) else ""
        raise ProbvisError(f"cannot write '{path}'{link}: {exc.strerror or exc}") from None


MAX_IMAGE_PIXELS = 1 << 27  # a PNG or JPEG larger than this (3 GiB as linear RGB) is refused from its header


def _as_rgb(image):
    img = np.asarray(image)
    if img.dtype.kind not in "biuf":
        raise ProbvisError(f"expected an image of numbers, got {type(image).__name__} of {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    if img.ndim != 3 or img.shape[2] != 3 or min(img.shape[:2]) < 1:
        raise ProbvisError(f"expected an (h, w, 3) or (h, w) image of at least one pixel, got shape {img.shape}")
    return img


def _float32(path, values):
    """`values` as contiguous float32, refused (naming the file) where float32 cannot hold them: they would be
    written as infinities."""
    values = np.asarray(values, dtype=np.float64)
    biggest = float(np.max(np.abs(values), initial=0.0))
    limit = float(np.finfo(np.float32).max)
    if biggest > limit:
        raise ProbvisError(f"cannot write '{path}': the image has values up to {biggest:.3g}, beyond what a float32 "
                           f"file holds ({limit:.3g}): lower the emitters' radiance or scale")
    return np.ascontiguousarray(values, dtype=np.float32)


def _channel_names(path, channels):
    """`write_exr`'s `channels`: a dict of at least one channel, named by non-empty strings that an EXR header
    can hold (UTF-8, no NUL)."""
    if not isinstance(channels, dict) or not channels:
        got = "an empty dict" if isinstance(channels, dict) else type(channels).__name__
        raise ProbvisError(f"cannot write '{path}': channels must be a dict of names to (h, w) images, got {got}")
    for name in channels:
        try:
            ok = isinstance(name, str) and name and "\0" not in name and name.encode("utf-8")
        except UnicodeEncodeError:  # a lone surrogate
            ok = False
        if not ok:
            raise ProbvisError(f"cannot write '{path}': a channel name must be a non-empty string in UTF-8 without "
                               f"NUL, got {shown(name, repr)[:200]}")


def write_exr(path, image, channels=None):
    """Write float32 channels; by default RGB. `channels` maps names to (h, w) arrays instead."""
    import OpenEXR

    if channels is None:
        data = {"RGB": _float32(path, _as_rgb(image))}
    else:
        _channel_names(path, channels)
        data = {k: _float32(path, v) for k, v in channels.items()}
        shapes = {v.shape for v in data.values()}
        if len(shapes) != 1 or len(next(iter(shapes))) != 2 or min(next(iter(shapes))) < 1:
            raise ProbvisError(f"cannot write '{path}': channels must be (h, w) images of one size, got "
                               f"{', '.join(f'{k} {v.shape}' for k, v in data.items())}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        with OpenEXR.File(header, data) as f:
            f.write(exr_name(tmp))


def _input_path(path):
    """`path` as a Path, if it is a file name (str or Path; not bytes, not a number)."""
    if not isinstance(path, (str, os.PathLike)) or not str(path):
        raise ProbvisError(f"an input path must be a file name (str or Path), got {shown(path, repr)[:200]}")
    return Path(path)


def check_readable(path, what):
    """Fail with the system's reason (permission) when `path` cannot be opened for reading, before a decoder
    would report an unreadable file as an invalid one. `what` names the kind of file in the message."""
    try:
        Path(path).open("rb").close()
    except OSError as exc:
        raise ProbvisError(f"cannot read {what} {path}: {exc.strerror or exc}") from None


def read_exr(path, channel=None):
    """Read an RGB EXR as (h, w, 3) float32, or one named `channel` as (h, w). The header is read first: a size
    no image needs is refused before its pixels are allocated."""
    path = _input_path(path)
    if not path.is_file():
        raise ProbvisError(f"image {path} is not a regular file" if path.exists() else missing_file(path, "image"))
    if not utf8_path(path):
        raise ProbvisError(f"cannot read '{path}': OpenEXR opens only file and folder names in UTF-8; rename it")
    check_readable(path, "EXR")
    with library_output() as said:  # the library reports a failed read (a truncated file) as a line of its own
        try:
            return _exr_pixels(path, channel, said)
        except (ProbvisError, MemoryError):
            raise
        except Exception as exc:
            raise ProbvisError(f"cannot read EXR {path}: {said() or exc} (the file is truncated or not an OpenEXR "
                               "image)") from None


def _exr_pixels(path, channel, said):
    import OpenEXR

    with OpenEXR.File(exr_name(path), header_only=True) as head:
        lo, hi = (np.asarray(c, dtype=np.int64) for c in head.header()["dataWindow"])
    w, h = hi - lo + 1
    if w * h > MAX_IMAGE_PIXELS or min(w, h) < 1:
        raise ProbvisError(f"{path}: its header declares a {w}x{h} image ({w * h / 1e6:.0f} Mpixel), outside the 1 "
                           f"to {MAX_IMAGE_PIXELS / 1e6:.0f} Mpixel probvis reads")
    with OpenEXR.File(exr_name(path)) as f:
        if said():
            raise ValueError(said())
        ch = f.channels()
        if channel is not None:
            if channel not in ch:
                raise ProbvisError(f"{path}: no channel {channel} (found {', '.join(ch)})")
            return np.array(ch[channel].pixels, dtype=np.float32)
        if "RGB" in ch:
            return np.array(ch["RGB"].pixels, dtype=np.float32)
        if "RGBA" in ch:  # alpha dropped, as for PNG (Mitsuba reads RGBA EXRs)
            return np.array(ch["RGBA"].pixels, dtype=np.float32)[..., :3]
        single = {k.upper(): k for k in ch if len(k) == 1}  # R, G, B or r, g, b: Mitsuba reads either
        if all(c in single for c in "RGB"):
            return np.stack([np.array(ch[single[c]].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
        if all(c in single for c in "XYZ"):  # CIE XYZ, turned into linear sRGB as Mitsuba does
            xyz = np.stack([np.array(ch[single[c]].pixels, dtype=np.float64) for c in "XYZ"], axis=-1)
            return (xyz @ XYZ_TO_SRGB.T).astype(np.float32)
        grey = next((k for k in ("Y", "YA", single.get("Y")) if k in ch), None)
        if grey is not None:  # luminance alone: grey, as Mitsuba reads it
            y = np.array(ch[grey].pixels, dtype=np.float32)
            return np.repeat((y if y.ndim == 2 else y[..., 0])[..., None], 3, axis=-1)
        layers = [k for k in ch if np.ndim(ch[k].pixels) == 3 and np.shape(ch[k].pixels)[2] in (3, 4)]
        if len(layers) == 1:  # one layer's R, G, B ("diffuse.R", ...): that layer, as Mitsuba reads it
            return np.array(ch[layers[0]].pixels, dtype=np.float32)[..., :3]
        raise ProbvisError(f"{path}: no RGB channels (found {', '.join(ch)}" +
                           (": more than one layer, and probvis reads one)" if layers else ")"))


def write_pfm(path, image):
    img = _float32(path, _as_rgb(image)[::-1]).astype("<f4", copy=False)
    h, w = img.shape[:2]
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(f"PF\n{w} {h}\n-1.0\n".encode())
            f.write(img.tobytes())


def read_pfm(path):
    """A PFM image as (h, w, channels) float32, top row first; a file that is not one is named."""
    path = _input_path(path)
    try:
        return _read_pfm(path)
    except (ValueError, OSError) as exc:
        raise ProbvisError(f"cannot read PFM image {path}: {getattr(exc, 'strerror', None) or exc}") from None


def _read_pfm(path):
    if Path(path).exists() and not Path(path).is_file():
        raise ValueError("not a regular file")
    with open(path, "rb") as f:
        kind = f.readline().strip()
        try:
            if kind not in (b"PF", b"Pf"):
                raise ValueError
            w, h = (int(x) for x in f.readline().split())
            scale = float(f.readline())
        except ValueError:
            raise ValueError("its header is not 'PF' or 'Pf', then the width and height, then the scale") from None
        if not scale or not np.isfinite(scale):
            raise ValueError(f"its header's scale is {scale:g}: the scale's sign gives the byte order (-1 for "
                             "little-endian)")
        dtype = "<f4" if scale < 0 else ">f4"
        ch = 3 if kind == b"PF" else 1
        if w <= 0 or h <= 0:
            raise ValueError(f"its header gives {w}x{h} pixels")
        if w * h > MAX_IMAGE_PIXELS:
            raise ValueError(f"its header gives {w}x{h} pixels ({w * h / 1e6:.0f} Mpixel), above the "
                             f"{MAX_IMAGE_PIXELS / 1e6:.0f} Mpixel probvis reads (scale it down)")
        body = f.read()
        if len(body) < 4 * w * h * ch:
            raise ValueError(f"truncated: {len(body):,} bytes of pixels where its {w}x{h} header needs "
                             f"{4 * w * h * ch:,}")
        data = np.frombuffer(body, dtype=dtype, count=w * h * ch).reshape(h, w, ch)
    return data[::-1].astype(np.float32)


def tonemap_srgb(image, exposure=0.0):
    """Linear radiance -> 8-bit sRGB after scaling by 2**exposure; negative values clamp to black."""
    if not is_number(exposure) or not -MAX_EXPOSURE <= exposure <= MAX_EXPOSURE:
        raise ProbvisError(f"exposure must be a number of stops from -{MAX_EXPOSURE:g} to {MAX_EXPOSURE:g}, got "
                           f"{exposure!r}")
    x = np.clip(np.nan_to_num(_as_rgb(image) * (2.0 ** exposure), nan=0.0), 0.0, 1.0)  # NaN: black, as negative
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def write_png(path, image, exposure=0.0):
    import imageio.v3 as iio

    rgb = _as_rgb(image)
    bad = int(np.count_nonzero(~np.isfinite(rgb).all(axis=-1)))
    if bad:  # a render never holds them (its values are checked); an image from elsewhere may
        warnings.warn(f"{path}: {bad:,} of {rgb.shape[0] * rgb.shape[1]:,} pixels are NaN or infinite: written as "
                      "black or white", stacklevel=2)
    data = iio.imwrite("<bytes>", tonemap_srgb(rgb, exposure), extension=".png")  # encoded in memory: a failed
    with atomic_path(path) as tmp, open(tmp, "wb") as f:  # write is then our OSError, not imageio's at exit
        f.write(data)


def write_image(path, image, exposure=0.0):
    """Write `image` in the format given by the file extension."""
    if not isinstance(path, (str, os.PathLike)):
        raise ProbvisError(f"an output path must be a file name (str or Path), got {path!r}")
    ext = Path(path).suffix.lower()
    if ext == ".exr":
        write_exr(path, image)
    elif ext == ".pfm":
        write_pfm(path, image)
    elif ext == ".png":
        write_png(path, image, exposure)
    else:
        raise ProbvisError(f"cannot write '{path}': unknown format (use {', '.join(FORMATS)})")
