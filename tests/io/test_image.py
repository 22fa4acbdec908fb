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
    from probvis.io.image import read_linear_rgb, write_pfm

    (tmp_path / "t.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 100000 +X 100000\n" + bytes(20))
    with pytest.raises(ProbvisError, match=r"t.hdr: image is 100000x100000 \(10000 Mpixel\), above the 134 Mpixel"):
        read_linear_rgb(tmp_path / "t.hdr")
    write_pfm(tmp_path / "t.pfm", np.ones((10, 10, 3)))
    (tmp_path / "u.pfm").write_bytes((tmp_path / "t.pfm").read_bytes()[:-20])
    with pytest.raises(ProbvisError, match="truncated: 1,180 bytes of pixels where its 10x10 header needs 1,200"):
        read_linear_rgb(tmp_path / "u.pfm")
    assert read_linear_rgb(tmp_path / "t.pfm").shape == (10, 10, 3)
