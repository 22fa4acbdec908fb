"""Reflectance textures (`bitmap`, `checkerboard`) at the uv of meshes and rectangles, against Mitsuba 3
(scalar_rgb): OBJ texture coordinates flipped as Mitsuba flips them, PLY's not, to_uv, wrap modes, filters."""
import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from probvis.io.image import write_exr
from tests.conftest import assert_matches_mitsuba, sensor, write_scene

LIGHT = """
    <shape type="rectangle"><transform name="to_world"><scale value="0.6"/><rotate x="1" angle="180"/>
        <translate x="0.3" y="0.2" z="2.2"/></transform>
        <emitter type="area"><rgb name="radiance" value="12"/></emitter></shape>
    <shape type="cube"><transform name="to_world"><scale value="0.2"/><translate x="0.4" y="-0.3" z="0.4"/></transform>
    </shape>"""
QUAD_OBJ = "v -1 -1 0\nv 1 -1 0\nv 1 1 0\nv -1 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n"
QUAD_PLY = """ply
format ascii 1.0
element vertex 4
property float x
property float y
property float z
property float u
property float v
element face 2
property list uchar int vertex_indices
end_header
-1 -1 0 0 0
1 -1 0 1 0
1 1 0 1 1
-1 1 0 0 1
3 0 1 2
3 0 2 3
"""


def picture(h=12, w=16):
    """An asymmetric colour image: any flip, shift or wrong filter shows."""
    y, x = np.mgrid[0:h, 0:w]
    img = np.stack([x / (w - 1), y / (h - 1), ((x // 3 + y // 2) % 2) * 0.8 + 0.1], -1)
    img[1, 2] = [1.0, 0.0, 0.0]
    return img.astype(np.float32)


def textured(shape, texture, transform='<scale value="1.2"/>'):
    return f"""
    <shape type="{shape}"><transform name="to_world">{transform}</transform>
        <bsdf type="diffuse">{texture}</bsdf></shape>"""


SRGB_TO_XYZ = np.array([[0.412453, 0.357580, 0.180423], [0.212671, 0.715160, 0.072169],
                        [0.019334, 0.119193, 0.950227]])  # linear sRGB to CIE XYZ (Mitsuba's)


CASES = {
    "bitmap-png-rectangle": textured("rectangle", '<texture type="bitmap" name="reflectance">'
                                                  '<string name="filename" value="pic.png"/></texture>'),
    "bitmap-exr-obj-to_uv-mirror": textured('obj"><string name="filename" value="quad.obj"/><foo type="',
                                            '<texture type="bitmap" name="reflectance"><string name="filename" '
                                            'value="pic.exr"/><string name="wrap_mode" value="mirror"/>'
                                            '<transform name="to_uv"><scale x="2" y="1.5"/></transform></texture>'),
    "bitmap-nearest-clamp-ply": textured('ply"><string name="filename" value="quad.ply"/><foo type="',
                                         '<texture type="bitmap" name="reflectance"><string name="filename" '
                                         'value="pic.exr"/><string name="filter_type" value="nearest"/>'
                                         '<string name="wrap_mode" value="clamp"/><transform name="to_uv">'
                                         '<scale value="1.4"/><translate x="-0.2" y="-0.1"/></transform></texture>'),
    "checkerboard-sphere": textured("sphere", '<texture type="checkerboard" name="reflectance"><rgb name="color0" '
                                              'value="0.9, 0.2, 0.1"/><transform name="to_uv"><scale x="8" y="4"/>'
                                              '</transform></texture>', '<scale value="0.6"/><rotate x="1" angle="70"/>'
                                                                        '<rotate z="1" angle="20"/>'
                                                                        '<translate x="-0.6" y="-0.7"/>'),
    "bitmap-bmp": textured("rectangle", '<texture type="bitmap" name="reflectance">'
                               '<string name="filename" value="pic.bmp"/></texture>'),
    "bitmap-tga": textured("rectangle", '<texture type="bitmap" name="reflectance">'
                               '<string name="filename" value="pic.tga"/></texture>'),
    "bitmap-ppm": textured("rectangle", '<texture type="bitmap" name="reflectance">'
                               '<string name="filename" value="pic.ppm"/></texture>'),
    "bitmap-exr-grey": textured("rectangle", '<texture type="bitmap" name="reflectance">'
                                     '<string name="filename" value="pic-grey.exr"/></texture>'),
    "bitmap-exr-layer": textured("rectangle", '<texture type="bitmap" name="reflectance">'
                                     '<string name="filename" value="pic-layer.exr"/></texture>'),
    "bitmap-exr-xyz": textured("rectangle", '<texture type="bitmap" name="reflectance">'  # Mitsuba: to sRGB
                                   '<string name="filename" value="pic-xyz.exr"/></texture>'),
    "bitmap-exr-lower": textured("rectangle", '<texture type="bitmap" name="reflectance">'  # r, g, b channels
                                     '<string name="filename" value="pic-lower.exr"/></texture>'),
    "bitmap-disk": textured("disk", '<texture type="bitmap" name="reflectance"><string name="filename" '
                                    'value="pic.exr"/></texture>', '<rotate z="1" angle="-30"/>'),
    "bitmap-cylinder": textured("cylinder", '<texture type="bitmap" name="reflectance"><string name="filename" '
                                            'value="pic.png"/><transform name="to_uv"><scale x="2"/></transform>'
                                            '</texture>', '<scale x="0.6" y="0.6" z="1.2"/><rotate x="1" angle="80"/>'
                                                          '<translate z="-0.2"/>'),
    "checkerboard-obj": textured('obj"><string name="filename" value="quad.obj"/><foo type="',
                                 '<texture type="checkerboard" name="reflectance"><rgb name="color0" '
                                 'value="0.9, 0.2, 0.1"/><rgb name="color1" value="0.1, 0.3, 0.8"/>'
                                 '<transform name="to_uv"><scale value="5"/></transform></texture>'),
}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    import imageio.v3 as iio

    d = tmp_path_factory.mktemp("textures")
    write_exr(d / "pic.exr", picture())
    iio.imwrite(d / "pic.png", (picture() * 255).astype(np.uint8))
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    for kind, channels in (("grey", {"Y": np.ascontiguousarray(picture()[..., 0])}),  # Mitsuba: luminance, grey
                           ("layer", {"diffuse": picture()}),  # diffuse.R, .G, .B: Mitsuba reads the layer
                           ("xyz", dict(zip("XYZ", np.ascontiguousarray(np.moveaxis(picture() @ SRGB_TO_XYZ.T, -1, 0),
                                                                       np.float32)))),
                           ("lower", dict(zip("rgb", np.ascontiguousarray(np.moveaxis(picture(), -1, 0)))))):
        with OpenEXR.File(header, channels) as f:
            f.write(str(d / f"pic-{kind}.exr"))
    from PIL import Image

    eight = (picture() * 255).astype(np.uint8)  # Mitsuba reads BMP, TGA and PPM too, sRGB-encoded like PNG
    Image.fromarray(eight).save(d / "pic.bmp")
    Image.fromarray(eight).save(d / "pic.tga")
    Image.fromarray(eight).save(d / "pic.ppm")
    (d / "quad.obj").write_text(QUAD_OBJ)
    (d / "quad.ply").write_text(QUAD_PLY)
    return d


def scene_file(folder, name):
    body = CASES[name].replace('<foo type="">', "")
    return write_scene(folder / f"{name}.xml", sensor(origin="0, -0.4, 3", target="0, 0, 0", fov=45, spp="$spp",
                                                      w=32, h=32, sr=1) + LIGHT + body,
                       '<default name="spp" value="16"/>')


@pytest.mark.filterwarnings("ignore:.*outside \\[0, 1\\]")  # XYZ's round trip: -3e-7 where sRGB had 0
@pytest.mark.parametrize("name", sorted(CASES))
def test_textured_surface_matches_mitsuba(folder, name):
    assert_matches_mitsuba(scene_file(folder, name), shadow_rays=1)


def test_texture_is_looked_up_per_point(folder):
    """The image is not one colour: the textured render's pixels vary more than the light alone explains."""
    r = probvis.render(scene_file(folder, "checkerboard-obj"), spp=4, shadow_rays=1)
    ratio = r.image[8:24, 8:24, 2] / np.maximum(r.image[8:24, 8:24, 0], 1e-9)
    assert ratio.max() > 4 * ratio.min()


@pytest.mark.parametrize("texture, message", [
    ('<texture type="bitmap" name="reflectance"><string name="filename" value="nope.png"/></texture>',
     "image not found"),
    ('<texture type="bitmap" name="reflectance"><string name="filename" value="bad.png"/></texture>',
     "cannot read image"),
    ('<texture type="bitmap" name="reflectance"/>', "needs a 'filename'"),
    ('<texture type="bitmap" name="reflectance"><string name="filename" value="pic.exr"/>'
     '<string name="wrap_mode" value="tile"/></texture>', "wrap_mode must be one of"),
    ('<ref name="reflectance" id="nothing"/>', "unknown id 'nothing'"),
    ('<texture type="bitmap" name="reflectance"><string name="filename" value=""/></texture>',
     "<texture>: the filename is empty"),
    ('<texture type="bitmap" name="reflectance"><string name="filename" value="huge.exr"/></texture>',
     "huge.exr: its header declares a 30000x30000 image"),
    ('<texture type="bitmap" name="reflectance"><string name="filename" value="cut.exr"/></texture>',
     "cut.exr: .*the file is truncated or not an OpenEXR image"),
])
def test_bad_texture_names_file_and_line(folder, texture, message):
    """A huge header was a 10 GiB allocation, a truncated file a line from the library and a wrong reason."""
    import struct

    (folder / "bad.png").write_text("not a png")
    exr = (folder / "pic.exr").read_bytes()
    at = exr.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    (folder / "huge.exr").write_bytes(exr[:at] + struct.pack("<4i", 0, 0, 29999, 29999) + exr[at + 16:])
    (folder / "cut.exr").write_bytes(exr[:-40])
    path = write_scene(folder / "bad.xml", sensor() + LIGHT + textured("rectangle", texture))
    with pytest.raises(ProbvisError, match=message) as err:
        probvis.load_scene(path)
    assert "bad.xml:" in str(err.value)


def test_shapes_naming_the_same_image_share_one_texture(folder):
    """Each shape decoded its own copy of the file and the film packed them all (12.5 GB for 1000 shapes)."""
    from probvis.texture import texture_arrays

    body = "".join(textured("rectangle", '<texture type="bitmap" name="reflectance"><string name="filename" '
                                         'value="pic.png"/></texture>', f'<translate x="{k}"/>') for k in range(50))
    scene = probvis.load_scene(write_scene(folder / "many.xml", sensor() + LIGHT + body))
    assert len(scene.textures) == 1
    assert len(texture_arrays(scene.textures).data) == 12 * 16


def test_texture_on_a_cube_warns_and_strict_refuses(folder):
    body = textured("cube", '<texture type="checkerboard" name="reflectance"/>', '<scale value="0.3"/>')
    path = write_scene(folder / "cube.xml", sensor() + LIGHT + body)
    with pytest.warns(UserWarning, match="texture on a 'cube'.*mean colour"):
        scene = probvis.load_scene(path)
    assert np.allclose(scene.reflectance[-1], 0.3)
    with pytest.raises(ProbvisError, match="texture on a 'cube'"):
        probvis.load_scene(path, strict=True)


def test_top_level_texture_by_reference(folder):
    body = ('<texture type="checkerboard" id="chk"><rgb name="color0" value="0.9"/></texture>' +
            textured("rectangle", '<ref name="reflectance" id="chk"/>'))
    scene = probvis.load_scene(write_scene(folder / "ref.xml", sensor() + LIGHT + body))
    assert len(scene.textures) == 1 and scene.tri_uv is not None
