"""Conservative shells: their decisions against closed-form sphere visibility, exact images unchanged bit for bit,
open and broken meshes getting no inner shell, and the cache."""
import numpy as np
import pytest
import trimesh

import probvis
from probvis.accel import build_bvh, occluded_segments
from probvis.scene import SceneBuilder
from probvis.scene import shapes as shp
from probvis.scene import transform as tf
from probvis.scene.scene import Camera
from probvis.settings import RenderSettings
from probvis.shells import boundary_triangles, build_shells, is_closed, shell_tests


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("PROBVIS_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def sphere_scene(res=24, leaves=0, light_z=3.0):
    """A unit icosphere (5,120 triangles) at the origin over a floor, optionally a soup of `leaves` random leaf
    triangles beside it (an open mesh), under a square light at height `light_z`."""
    b = SceneBuilder("sphere", "test:sphere")
    v, f = shp.rectangle()
    b.add_mesh("floor", "rectangle", v, f, tf.translate([0, 0, -1.2]) @ tf.scale([4, 4, 1]),
               b.material((0.7, 0.7, 0.7)))
    ico = trimesh.creation.icosphere(subdivisions=4)
    b.add_mesh("sphere", "mesh", np.asarray(ico.vertices), np.asarray(ico.faces), None, b.material((0.6, 0.5, 0.4)))
    if leaves:
        rng = np.random.default_rng(5)
        c = np.column_stack([rng.uniform(1.3, 2.5, leaves), rng.uniform(-1, 1, leaves), rng.uniform(-0.5, 0.5, leaves)])
        lv = (c[:, None] + rng.normal(scale=0.05, size=(leaves, 3, 3))).reshape(-1, 3)
        b.add_mesh("leaves", "mesh", lv, np.arange(3 * leaves).reshape(-1, 3), None, b.material((0.2, 0.5, 0.1)))
    b.add_mesh("light", "rectangle", v, f, tf.translate([0.4, 0, light_z]) @ tf.rotate([1, 0, 0], 180), None,
               radiance=(5.0, 5.0, 5.0))
    cam = Camera(tf.look_at([0, -5, 3], [0, 0, -0.5], [0, 0, 1]), 45.0, res, res)
    return b.build(cam, RenderSettings(2, 4, 0))


def shell_decisions(sh, org, d):
    """Per segment: crosses the inner shell; starts outside the outer grid and misses the outer shell."""
    n = len(org)
    ones, ids = np.ones(n), np.arange(n)
    inner = occluded_segments(build_bvh(sh.inner), org, d, ones, ids)[0]
    outer = occluded_segments(build_bvh(sh.outer), org, d, ones, ids)[0]
    idx = np.floor((org - sh.lo) / sh.pitch).astype(int)
    ok = np.all((idx >= 0) & (idx < sh.grid.shape), axis=1)
    start_in = np.zeros(n, bool)
    start_in[ok] = sh.grid[tuple(idx[ok].T)] > 0
    return inner, ~outer & ~start_in


def test_shell_decisions_agree_with_the_sphere():
    """Segments between points outside the unit sphere: every one crossing the inner shell passes within the
    sphere (it is blocked), every one the outer shell rules out passes outside it, and the shells decide most
    segments that pass well inside or well outside."""
    scene = sphere_scene()
    sh = build_shells(scene, build_bvh(scene.triangles), 1000)
    assert sh.shapes == [{"name": "sphere", "triangles": 5120, "closed": True}]
    rng = np.random.default_rng(0)
    n = 40000
    a, b = (rng.normal(size=(n, 3)) for _ in range(2))
    a *= rng.uniform(1.01, 2.0, (n, 1)) / np.linalg.norm(a, axis=1, keepdims=True)
    b *= rng.uniform(1.01, 2.0, (n, 1)) / np.linalg.norm(b, axis=1, keepdims=True)
    d = b - a
    t = np.clip(-np.einsum("ij,ij->i", a, d) / np.einsum("ij,ij->i", d, d), 0, 1)
    closest = np.linalg.norm(a + t[:, None] * d, axis=1)  # the segment's distance from the centre
    inner, far = shell_decisions(sh, a, d)
    assert np.all(closest[inner] < 0.999) and np.all(closest[far] > 0.99)  # icosphere(4): radii 0.9968..1
    assert inner[closest < 0.8].mean() > 0.9 and far[closest > 1.2].mean() > 0.9


def test_shells_never_change_an_exact_image():
    """Exact visibility with shells (a closed sphere and an open leaf soup) renders the same image bit for bit,
    with fewer scene tests: the shells decided segments."""
    scene = sphere_scene(leaves=1500)
    plain = probvis.render(scene, spp=2, shadow_rays=8, seed=3)
    shelled = probvis.render(scene, spp=2, shadow_rays=8, seed=3, visibility="exact",
                             visibility_options={"shells": True, "min_triangles": 1000})
    np.testing.assert_array_equal(plain.image, shelled.image)
    e = shelled.stats["estimator"]
    assert [m["closed"] for m in e["shells"]["meshes"]] == [True, False]
    assert e["tests"]["shells"]["node"] > 0
    assert e["tests"]["scene"]["node"] < plain.stats["intersection_tests"]["shadow"]["node"]


def test_open_and_broken_meshes_get_no_inner_shell():
    ico = trimesh.creation.icosphere(subdivisions=2)
    tris = np.asarray(ico.vertices)[np.asarray(ico.faces)]
    assert is_closed(tris) and ico.is_watertight
    assert not is_closed(tris[1:])  # a hole
    assert not is_closed(np.concatenate([tris, tris[:1]]))  # a face three times over one edge: non-manifold
    scene = sphere_scene(light_z=0.5)  # the light inside the sphere's bounds: its inner shell could lie
    sh = build_shells(scene, build_bvh(scene.triangles), 1000)
    assert sh.shapes[0]["closed"] is False and len(sh.inner) == 0 and len(sh.outer) > 0


def test_a_voxel_boundary_is_its_cube():
    occ = np.zeros((3, 3, 3), bool)
    occ[1, 2, 0] = True
    tris = boundary_triangles(occ, np.array([10.0, 20.0, 30.0]), 0.5)
    assert tris.shape == (12, 3, 3)
    np.testing.assert_allclose(tris.min((0, 1)), [10.5, 21.0, 30.0])
    np.testing.assert_allclose(tris.max((0, 1)), [11.0, 21.5, 30.5])
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1).sum()
    assert area == pytest.approx(6 * 0.25)
    full = np.ones((4, 5, 6), bool)  # a box of voxels merges into one rectangle per side
    assert boundary_triangles(full, np.zeros(3), 1.0).shape == (12, 3, 3)


def test_shells_are_cached(cache):
    scene = sphere_scene()
    bvh = build_bvh(scene.triangles)
    first, again = build_shells(scene, bvh, 1000), build_shells(scene, bvh, 1000)
    assert not first.cached and again.cached
    np.testing.assert_array_equal(first.inner, again.inner)
    assert len(list(cache.glob("shells/*.npz"))) == 1
    assert shell_tests(scene, bvh, 10 ** 6).flags == 0  # no mesh that heavy: no shells
