import os
import re

import numpy as np
import pytest

from probvis import ProbvisError
from probvis.io import check_writable, read_exr, read_pfm, tonemap_srgb, write_image


def test_exr_and_pfm_round_trip_keep_signed_values(tmp_path):
    img = np.random.default_rng(0).normal(size=(5, 7, 3)).astype(np.float32)
    for ext, reader in ((".exr", read_exr), (".pfm", read_pfm)):
        write_image(tmp_path / f"a{ext}", img)
        np.testing.assert_array_equal(reader(tmp_path / f"a{ext}"), img)
    assert not list(tmp_path.glob(".*"))  # no temporary files left behind


def test_png_tonemap():
    assert tonemap_srgb(np.array([[[0.0, 1.0, 0.5]]])).tolist() == [[[0, 255, 188]]]
    assert tonemap_srgb(np.array([[[-1.0, 0.25, 4.0]]]), exposure=1).tolist() == [[[0, 188, 255]]]


def test_unwritable_outputs_are_caught_early(tmp_path):
    with pytest.raises(ProbvisError, match="does not exist"):
        check_writable(tmp_path / "no" / "out.exr")
    with pytest.raises(ProbvisError, match="must be a .exr, .pfm, .png file"):
        check_writable(tmp_path / "out.jpg")
    with pytest.raises(ProbvisError, match="is a folder"):
        check_writable(tmp_path / "dir.exr") if (tmp_path / "dir.exr").mkdir() is None else None


def test_an_hdr_header_too_large_and_a_truncated_pfm_are_named(tmp_path):
    """An HDR's declared size is checked from its header before decoding (as a PNG's); a PFM shorter than its
    header says is called truncated."""
    from probvis.io.image import write_pfm
    from probvis.io.linear_rgb import read_linear_rgb

    (tmp_path / "t.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n" + bytes(20))
    with pytest.raises(ProbvisError, match=r"t.hdr: image is 100000x100000 \(10000 Mpixel\), above the 134 Mpixel"):
        read_linear_rgb(tmp_path / "t.hdr")
    write_pfm(tmp_path / "t.pfm", np.ones((10, 10, 3)))
    (tmp_path / "u.pfm").write_bytes((tmp_path / "t.pfm").read_bytes()[:-20])
    with pytest.raises(ProbvisError, match="truncated: 1,180 bytes of pixels where its 10x10 header needs 1,200"):
        read_linear_rgb(tmp_path / "u.pfm")
    assert read_linear_rgb(tmp_path / "t.pfm").shape == (10, 10, 3)
    (tmp_path / "v.pfm").write_bytes(b"PF\n20000 10000\n-1\n" + bytes(20))  # as the HDR: the limit and the fix
    with pytest.raises(ProbvisError, match=r"20000x10000 pixels \(200 Mpixel\), above the 134 Mpixel probvis reads "
                                           r"\(scale it down\)"):
        read_linear_rgb(tmp_path / "v.pfm")


@pytest.mark.parametrize("kind", ["1-bit.png", "cmyk.jpg", "rgba.exr"])
def test_valid_images_of_other_pixel_modes_read_as_rgb(tmp_path, kind):
    """A 1-bit PNG was refused, a white CMYK JPEG read black (K taken for alpha), an RGBA EXR refused."""
    from PIL import Image

    from probvis.io.linear_rgb import read_linear_rgb

    path = tmp_path / kind
    if kind == "1-bit.png":
        Image.new("1", (4, 4), 1).save(path)
    elif kind == "cmyk.jpg":
        Image.new("CMYK", (4, 4), (0, 0, 0, 0)).save(path)
    else:
        import OpenEXR

        with OpenEXR.File({"type": OpenEXR.scanlineimage}, {"RGBA": np.ones((4, 4, 4), np.float32)}) as f:
            f.write(str(path))
    img = read_linear_rgb(path)
    assert img.shape == (4, 4, 3) and np.allclose(img, 1.0, atol=0.01)


def test_a_pfm_scale_of_zero_or_a_comment_is_named(tmp_path):
    """The scale's sign is the byte order: 0 read as big-endian turned 0.5 into 1e-41 (a black texture)."""
    from probvis.io.image import read_pfm

    path = tmp_path / "t.pfm"
    path.write_bytes(b"PF\n2 2\n0\n" + np.full(12, 0.5, "<f4").tobytes())
    with pytest.raises(ProbvisError, match="scale is 0: the scale's sign gives the byte order"):
        read_pfm(path)
    path.write_bytes(b"PF\n# a comment\n2 2\n-1\n" + np.full(12, 0.5, "<f4").tobytes())
    with pytest.raises(ProbvisError, match="its header is not 'PF' or 'Pf', then the width and height"):
        read_pfm(path)


def test_the_io_functions_name_their_mistakes(tmp_path):
    """probvis.io's exported functions raised raw ValueError, TypeError and FileNotFoundError (the last with the
    temporary file's internal name), and write_stats wrote NaN, which is not JSON."""
    from probvis.io import write_exr, write_png, write_stats

    cases = [
        (lambda: write_exr(tmp_path / "x.exr", np.zeros(5)),
         r"expected an \(h, w, 3\) or \(h, w\) image of at least one pixel, got shape \(5,\)"),
        (lambda: tonemap_srgb("x"), "expected an image of numbers, got str"),
        (lambda: write_png(5, np.zeros((2, 2, 3))), r"an output path must be a file name \(str or Path\), got 5"),
        (lambda: read_pfm(tmp_path / "nothere.pfm"), "cannot read PFM image .*nothere.pfm: No such file"),
        (lambda: write_stats(tmp_path / "no" / "s.json", {}), "cannot write '.*s.json': folder '.*no' does not exist"),
        (lambda: write_exr(tmp_path / "no" / "x.exr", np.zeros((2, 2, 3))), "folder '.*no' does not exist"),
        (lambda: write_stats(tmp_path / "s.json", {"a": float("nan")}), "the stats hold a value JSON cannot hold"),
    ]
    for call, message in cases:
        with pytest.raises(ProbvisError, match=message):
            call()
    assert not list(tmp_path.iterdir())


def test_an_empty_write_is_refused(tmp_path):
    """OpenEXR's writer reports nothing when it can write nothing (ulimit -f 0): an empty file is an error."""
    from probvis.io.atomic import atomic_path

    with pytest.raises(ProbvisError, match="cannot write '.*e.exr': nothing could be written"):
        with atomic_path(str(tmp_path / "e.exr")) as tmp:
            open(tmp, "wb").close()
    assert not list(tmp_path.iterdir())


def test_a_damaged_hdr_is_one_error_with_opencv_s_reason(tmp_path, capfd):
    """OpenCV logged '[ERROR:0@...] global loadsave.cpp ...' and a blank line before probvis's error."""
    from probvis.io.linear_rgb import read_linear_rgb

    (tmp_path / "t.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X 8\n" + bytes([2, 2, 0, 8, 9]))
    with pytest.raises(ProbvisError, match=r"cannot read Radiance HDR image .*t.hdr \(RGBE read error\)"):
        read_linear_rgb(tmp_path / "t.hdr")
    out, err = capfd.readouterr()
    assert out == "" and err == ""


@pytest.mark.parametrize("call, message", [
    (lambda io, p: io.write_exr(p / "o.exr", None, channels={"R": np.zeros((4, 4)), "G": np.zeros((5, 5))}),
     "channels must be (h, w) images of one size"),
    (lambda io, p: io.write_image(p / "o.png", np.zeros((4, 4, 3)), 1e6), "exposure must be a number of stops"),
    (lambda io, p: io.write_image(p / "o.png", np.zeros((4, 4, 3)), "2"), "exposure must be a number of stops"),
    (lambda io, p: io.write_image(p / "o.png", np.zeros((1, 0, 3))), "of at least one pixel, got shape (1, 0, 3)"),
    (lambda io, p: io.write_image(None, np.zeros((4, 4, 3))), "an output path must be a file name"),
    (lambda io, p: io.write_exr(p / "o.exr", None, channels={1: np.zeros((4, 4))}), "a channel name must be a non"),
    (lambda io, p: io.write_exr(p / "o.exr", None, channels={"\udcff": np.zeros((4, 4))}), "in UTF-8 without NUL"),
    (lambda io, p: io.write_exr(p / "o.exr", None, channels={"a\0b": np.zeros((4, 4))}), "got 'a\\x00b'"),
    (lambda io, p: io.write_exr(p / "o.exr", None, channels=[("R", np.zeros((4, 4)))]), "a dict of names to (h, w)"),
    (lambda io, p: io.write_exr(p / "o.exr", None, channels={}), "images, got an empty dict"),
])
def test_the_image_writers_name_bad_arguments(tmp_path, call, message):
    """Each was a ValueError, OverflowError or TypeError from inside the writer."""
    import probvis.io.image as io

    with pytest.raises(ProbvisError, match=re.escape(message)):
        call(io, tmp_path)
    assert not list(tmp_path.iterdir())


def test_the_io_helpers_name_what_they_were_given(tmp_path):
    """A device as a PFM (MemoryError), case shares of the wrong shape (IndexError), stats nested 100,000 deep
    (RecursionError) and a summary of a dict that is no render's stats (KeyError)."""
    from probvis.io import read_pfm, summary, write_case_images, write_stats

    with pytest.raises(ProbvisError, match="cannot read PFM image /dev/zero: not a regular file"):
        read_pfm("/dev/zero")
    with pytest.raises(ProbvisError, match=re.escape("case shares are an (h, w, emitters, 4) array")):
        write_case_images(tmp_path / "c.png", np.zeros((4, 4, 3)))
    deep = level = {}
    for _ in range(100_000):
        level["a"] = level = {}
    with pytest.raises(ProbvisError, match="the stats nest too deep"):
        write_stats(tmp_path / "s.json", deep)
    with pytest.raises(ProbvisError, match="summary takes a render's stats"):
        summary({"a": 1})
    with pytest.raises(ProbvisError, match=re.escape("summary takes a render's stats (RenderResult.stats, a dict), "
                                                     "got NoneType")):
        summary(None)
    with pytest.raises(ProbvisError, match=re.escape("stats are a dict (RenderResult.stats), got list")):
        write_stats(tmp_path / "s.json", [1, 2])
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("path", [3, b"a.exr", None, ""])
def test_the_readers_name_a_path_that_is_no_file_name(path):
    """read_exr(3) and read_pfm(0) were TypeErrors from pathlib; the writers already refused them."""
    from probvis.io import read_exr, read_pfm

    for read in (read_exr, read_pfm):
        with pytest.raises(ProbvisError, match="an input path must be a file name"):
            read(path)


def test_case_colours_and_png_name_what_they_cannot_show(tmp_path):
    from probvis.io import case_colours, write_image

    for shares in (np.ones((2, 2)), np.ones((2, 2, 3)), np.array([["a"] * 4])):
        with pytest.raises(ProbvisError, match=re.escape("case shares are an (..., 4) array of numbers")):
            case_colours(shares)
    image = np.zeros((2, 2, 3))
    image[0, 0, 1], image[1, 1] = np.nan, np.inf
    with pytest.warns(UserWarning, match="2 of 4 pixels are NaN or infinite: written as black or white"):
        write_image(tmp_path / "o.png", image)


def test_readers_refuse_what_is_no_regular_file(tmp_path):
    """A FIFO hung read_pfm for ever, and a folder or FIFO read as an EXR was 'image not found'."""
    import os

    from probvis.io import read_exr, read_pfm

    os.mkfifo(tmp_path / "f.pfm")
    os.mkfifo(tmp_path / "f.exr")
    (tmp_path / "d.exr").mkdir()
    for read, name in ((read_pfm, "f.pfm"), (read_exr, "f.exr"), (read_exr, "d.exr")):
        with pytest.raises(ProbvisError, match="not a regular file"):
            read(tmp_path / name)


def test_pillow_s_decompression_bomb_note_is_not_shown(tmp_path, monkeypatch):
    """probvis's own pixel limit applies before decoding; Pillow's DecompressionBombWarning (its lower limit)
    repeated it as a library's note on stderr."""
    import warnings

    from PIL import Image

    from probvis.io import write_png
    from probvis.io.linear_rgb import read_linear_rgb

    write_png(tmp_path / "t.png", np.full((4, 4, 3), 0.5))
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 10)  # 16 pixels: above it, below twice it (an error)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert read_linear_rgb(tmp_path / "t.png").shape == (4, 4, 3)


@pytest.mark.parametrize("kind", ["png", "exr", "pfm"])
def test_an_image_under_another_extension_is_read_by_its_content(tmp_path, kind):
    """As Mitsuba's bitmap loader, a file whose extension names no format is read by its first bytes; one whose
    bytes announce none either is refused naming the extensions read."""
    from probvis.io.linear_rgb import read_linear_rgb

    img = np.random.default_rng(0).random((3, 4, 3))
    write_image(tmp_path / f"a.{kind}", img)
    (tmp_path / "a.texture").write_bytes((tmp_path / f"a.{kind}").read_bytes())
    np.testing.assert_array_equal(read_linear_rgb(tmp_path / "a.texture"), read_linear_rgb(tmp_path / f"a.{kind}"))
    (tmp_path / "c.png").write_bytes((tmp_path / f"a.{kind}").read_bytes())  # a known extension, another format
    np.testing.assert_array_equal(read_linear_rgb(tmp_path / "c.png"), read_linear_rgb(tmp_path / f"a.{kind}"))
    (tmp_path / "b.texture").write_bytes(b"not an image at all")
    with pytest.raises(ProbvisError, match=r"b.texture: unsupported image format '.texture' \(supported: .exr"):
        read_linear_rgb(tmp_path / "b.texture")


def test_an_image_of_a_format_probvis_does_not_read_is_refused_whatever_its_name(tmp_path):
    """Sweep 49: WebP (or GIF) data in a file named .png was decoded by Pillow and rendered, where Mitsuba refuses
    it; a JPEG named .png is read by its content, as Mitsuba reads it."""
    from PIL import Image

    from probvis.io.linear_rgb import read_linear_rgb

    img = Image.fromarray(np.random.default_rng(0).integers(0, 255, (4, 5, 3), dtype=np.uint8))
    for fmt in ("WEBP", "GIF"):
        img.save(tmp_path / "t.png", format=fmt)
        with pytest.raises(ProbvisError, match=f"t.png: the file holds a {fmt} image, not a format probvis reads"):
            read_linear_rgb(tmp_path / "t.png")
    img.save(tmp_path / "t.png", format="JPEG")
    img.save(tmp_path / "t.jpg", format="JPEG")
    np.testing.assert_array_equal(read_linear_rgb(tmp_path / "t.png"), read_linear_rgb(tmp_path / "t.jpg"))


def test_a_palette_bmp_warns_that_mitsuba_reads_it_otherwise(tmp_path):
    """Sweep 49: Mitsuba 3.9 reads a palette BMP's indices as grey (its mean 0.67× probvis's on the sweep's
    image); probvis reads the colours, the same image as the RGB file's, and says so."""
    import warnings

    from PIL import Image

    from probvis.io.linear_rgb import read_linear_rgb

    rgb = Image.fromarray(np.random.default_rng(1).integers(0, 255, (4, 5, 3), dtype=np.uint8))
    pal = rgb.quantize(colors=8)
    pal.save(tmp_path / "p.bmp")
    pal.convert("RGB").save(tmp_path / "c.bmp")
    with pytest.warns(UserWarning, match="p.bmp: a palette BMP: probvis reads its colours, Mitsuba 3.9 its palette "
                                         "indices as grey"):
        got = read_linear_rgb(tmp_path / "p.bmp")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        np.testing.assert_array_equal(got, read_linear_rgb(tmp_path / "c.bmp"))


@pytest.mark.parametrize("name, reader", [("t.png", "linear_rgb.read_linear_rgb"),
                                          ("t.exr", "linear_rgb.read_linear_rgb"), ("t.exr", "image.read_exr")])
def test_an_unreadable_image_says_so(tmp_path, name, reader):
    """A texture or environment map the process may not read was 'not a valid PNG file (OSError)' (sweep 38):
    now the system's reason; an EXR read as such said 'Permission denied (the file is truncated or not an OpenEXR
    image)'. As root, the permission is taken away by dropping the capabilities that bypass it."""
    import subprocess
    import sys

    from tests.conftest import without_permission_override

    write_image(tmp_path / name, np.full((4, 4, 3), 0.5))
    (tmp_path / name).chmod(0)
    module, function = reader.split(".")
    code = (f"from probvis.io.{module} import {function}\nfrom probvis import ProbvisError\n"
            f"try:\n    {function}({str(tmp_path / name)!r})\nexcept ProbvisError as exc:\n    print(exc)")
    r = subprocess.run(without_permission_override([sys.executable, "-c", code]), capture_output=True, text=True,
                       timeout=120)
    what = "EXR" if function == "read_exr" else "image"
    assert r.stdout.strip() == f"cannot read {what} {tmp_path / name}: Permission denied", r.stderr


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="no /proc")
def test_a_folder_that_exists_but_takes_no_file_is_not_called_missing():
    """/proc exists and answers ENOENT to a new file: "folder '/proc' does not exist" misled."""
    with pytest.raises(ProbvisError, match=r"cannot write '/proc/r.exr': No such file or directory"):
        write_image("/proc/r.exr", np.zeros((2, 2, 3)))
