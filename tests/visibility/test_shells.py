"""Conservative shells: their decisions against closed-form sphere visibility, exact images unchanged bit for bit,
open and broken meshes getting no inner shell, and the cache."""
import numpy as np
import pytest
import trimesh

import probvis
from probvis.accel import build_bvh
from probvis.scene import SceneBuilder
from probvis.scene import shapes as shp
from probvis.scene import transform as tf
from probvis.scene import Camera
from probvis.settings import RenderSettings
from probvis.shells import (FREE, PAD, SOLID, SURFACE, build_shells, classify_segments, heavy_meshes, is_closed,
                            mesh_closed, shell_tests, span)
from probvis.voxels import BOUNDS_CHUNK, bounds


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
    """Per segment: enters a SOLID voxel (blocked); visits only FREE voxels (clear of the sphere)."""
    state, _, _ = classify_segments(sh.grid, sh.lo, sh.pitch, org, d, np.ones(len(org)))
    return state == SOLID, state == FREE


def test_shell_decisions_agree_with_the_sphere():
    """Segments between points outside the unit sphere: every one crossing the inner shell passes within the
    sphere (it is blocked), every one the outer shell rules out passes outside it, and the shells decide most
    segments that pass well inside or well outside."""
    scene = sphere_scene()
    sh = build_shells(scene, build_bvh(scene.triangles), heavy_meshes(scene, 1000))
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
    assert e["tests"]["shells"]["voxel"] > 0
    assert e["tests"]["scene"]["node"] < plain.stats["intersection_tests"]["shadow"]["node"]
    # their memory: a byte a voxel, and the BVH of the rest of the scene (the floor, the light); none without
    assert e["memory_bytes"]["shells"] == e["shells"]["bytes"] > np.prod(e["shells"]["grid"])
    assert plain.stats["estimator"]["memory_bytes"] == {}
    # the default, shells auto: the closed sphere gets them, the open leaves do not
    auto = probvis.render(scene, spp=2, shadow_rays=8, seed=3, visibility_options={"min_triangles": 1000})
    np.testing.assert_array_equal(plain.image, auto.image)
    assert [m["name"] for m in auto.stats["estimator"]["shells"]["meshes"]] == ["sphere"]
    assert auto.stats["estimator"]["tests"]["scene"]["node"] < plain.stats["intersection_tests"]["shadow"]["node"]


def test_open_meshes_get_no_shells_by_default(cache):
    """`shells auto` skips a scene whose heavy meshes are all open: exact visibility's own kernel, no shells
    built, no stats of theirs; `--no-shells` and `off` likewise, `on` builds them. The closedness verdicts are
    cached, one per mesh."""
    scene = sphere_scene(leaves=1500)
    leaves_only = dict(min_triangles=6000)  # of the sphere's 5,120 triangles and 8,000 leaves: only the leaves
    heavy = heavy_meshes(scene, 1000)
    assert [s.name for s in heavy] == ["sphere", "leaves"]
    assert [s.name for s in heavy if mesh_closed(span(scene, s))] == ["sphere"]
    open_scene = sphere_scene(leaves=8000)
    assert [s.name for s in heavy_meshes(open_scene, **leaves_only)] == ["leaves"]
    assert [s.name for s in heavy_meshes(open_scene, **leaves_only) if mesh_closed(span(open_scene, s))] == []
    for setting in ("auto", "off", False):
        r = probvis.render(open_scene, spp=1, shadow_rays=2, visibility_options=dict(leaves_only, shells=setting))
        assert "shells" not in r.stats["estimator"] and r.stats["estimator"]["memory_bytes"] == {}
    assert r.stats["render_path"] == "fused-exact" and not list(cache.glob("shells/*.npz"))
    r = probvis.render(open_scene, spp=1, shadow_rays=2, visibility_options=dict(leaves_only, shells="on"))
    assert [m["name"] for m in r.stats["estimator"]["shells"]["meshes"]] == ["leaves"]
    assert len(list(cache.glob("closed/*.npz"))) == 3  # the sphere, 1,500 leaves and 8,000 leaves


def test_open_and_broken_meshes_get_no_inner_shell():
    ico = trimesh.creation.icosphere(subdivisions=2)
    tris = np.asarray(ico.vertices)[np.asarray(ico.faces)]
    assert is_closed(tris) and ico.is_watertight
    assert not is_closed(tris[1:])  # a hole
    assert not is_closed(np.concatenate([tris, tris[:1]]))  # a face three times over one edge: non-manifold
    scene = sphere_scene(light_z=0.5)  # the light inside the sphere's bounds: its inner shell could lie
    sh = build_shells(scene, build_bvh(scene.triangles), heavy_meshes(scene, 1000))
    assert sh.shapes[0]["closed"] is False and sh.solid_voxels == 0 and sh.surface_voxels > 0


def test_the_walk_visits_the_voxels_a_segment_crosses():
    """Against brute force on a 5x4x3 grid of random states: a segment's voxels are those whose box its
    parameter interval overlaps (slab tests); its class is SOLID if any is, else the highest state; without
    SOLID the walk visits each voxel once; with SURFACE its t range spans the SURFACE voxels'."""
    rng = np.random.default_rng(7)
    grid = rng.choice(np.array([FREE, FREE, FREE, SURFACE, SOLID], np.uint8), size=(5, 4, 3))
    lo, pitch = np.array([-1.0, 2.0, 0.5]), 0.7
    n = 3000
    org = lo + rng.uniform(-1, 4.5, (n, 3)) * pitch
    d = rng.normal(size=(n, 3)) * rng.uniform(0.1, 4, (n, 1))
    d[:50, 1:] = 0.0  # along the first axis only
    tmax = rng.uniform(0.2, 1.0, n)
    state, steps, t_range = classify_segments(grid, lo, pitch, org, d, tmax)
    cells = np.argwhere(np.ones(grid.shape, bool))
    box_lo, box_hi = lo + cells * pitch, lo + (cells + 1) * pitch
    for s in range(n):
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (box_lo - org[s]) / d[s], (box_hi - org[s]) / d[s]
        inside = (org[s] >= box_lo) & (org[s] <= box_hi)
        t0 = np.where(d[s] == 0, np.where(inside, -np.inf, np.inf), np.minimum(ta, tb)).max(axis=1)
        t1 = np.where(d[s] == 0, np.where(inside, np.inf, -np.inf), np.maximum(ta, tb)).min(axis=1)
        hit = np.maximum(t0, 0) < np.minimum(t1, tmax[s])
        states = grid[tuple(cells[hit].T)]
        expect = SOLID if (states == SOLID).any() else (states.max() if len(states) else FREE)
        assert state[s] == expect, s
        if expect != SOLID:
            assert steps[s] == hit.sum(), s
        if expect == SURFACE:  # the t range of its SURFACE voxels, widened by at most half the padding
            surface = hit & (grid[tuple(cells.T)] == SURFACE)
            first, last = np.maximum(t0[surface], 0).min(), np.minimum(t1[surface], tmax[s]).max()
            margin = 0.5 * PAD * pitch / np.abs(d[s]).sum() + 1e-12
            assert first - margin <= t_range[s, 0] <= first and last <= t_range[s, 1] <= last + margin, s


def test_shells_are_cached(cache):
    scene = sphere_scene()
    bvh = build_bvh(scene.triangles)
    first, again = (build_shells(scene, bvh, heavy_meshes(scene, 1000)) for _ in range(2))
    assert not first.cached and again.cached
    np.testing.assert_array_equal(first.grid, again.grid)
    assert len(list(cache.glob("shells/*.npz"))) == 1
    assert not shell_tests(scene, bvh, heavy_meshes(scene, 10 ** 6)).active  # no mesh that heavy: no shells


def test_the_heavy_builtins_open_and_closed():
    """heavy-scan and heavy-small are closed, heavy-open-scan is not (holes); `auto` gives shells to heavy-scan
    only: heavy-small's scan is closed but few segments come near it. Small subdivisions stand in for the
    built-ins' 1.3M triangles."""
    from probvis.scene.builtin import heavy_open_scan, heavy_scan, heavy_small

    for make, closed, shelled in ((heavy_scan, True, True), (heavy_small, True, False),
                                  (heavy_open_scan, False, False)):
        scene = make(res=32, subdivisions=3)
        scan = next(s for s in scene.shapes if s.name == "scan")
        assert is_closed(span(scene, scan)) == closed == mesh_closed(span(scene, scan))
        r = probvis.render(scene, spp=1, shadow_rays=2, visibility_options={"min_triangles": 1000})
        assert [m["name"] for m in (r.stats["estimator"].get("shells") or {}).get("meshes", [])] == \
            (["scan"] if shelled else [])


def test_the_survey_asks_closedness_only_of_crossed_meshes(cache):
    """The survey decides from the cheapest evidence first: a heavy mesh few pilot segments cross (heavy-small's
    scan) costs no closedness test and leaves no cache entry; a crossed one (heavy-scan's) is tested once. A
    shape's bounds, which the crossing test uses, are those of its triangles."""
    from probvis.scene.builtin import heavy_scan, heavy_small

    for make, crossed in ((heavy_small, False), (heavy_scan, True)):
        scene = make(res=32, subdivisions=3)
        scan = next(s for s in scene.shapes if s.name == "scan")
        lo, hi = span(scene, scan).reshape(-1, 3).min(axis=0), span(scene, scan).reshape(-1, 3).max(axis=0)
        np.testing.assert_array_equal(np.stack([scan.lo, scan.hi]), np.stack([lo, hi]))
        before = len(list(cache.glob("closed/*.npz")))
        probvis.render(scene, spp=1, shadow_rays=2, visibility_options={"min_triangles": 1000})
        assert len(list(cache.glob("closed/*.npz"))) - before == int(crossed)


@pytest.mark.parametrize("n", [1, 2, BOUNDS_CHUNK - 1, BOUNDS_CHUNK, BOUNDS_CHUNK + 1, 3 * BOUNDS_CHUNK + 7])
def test_the_parallel_box_is_numpy_s(n):
    """`voxels.bounds` (chunks over the threads) against numpy's min and max, at the chunks' edges and on views."""
    pts = np.random.default_rng(n).normal(scale=5.0, size=(n, 3))
    for view in (pts, pts[::-1], np.asfortranarray(pts), pts.astype(np.float32)):
        lo, hi = bounds(view)
        np.testing.assert_array_equal(lo, view.min(axis=0))
        np.testing.assert_array_equal(hi, view.max(axis=0))
    tris = pts[: n - n % 3].reshape(-1, 3, 3)
    if len(tris):
        np.testing.assert_array_equal(bounds(tris)[0], tris.reshape(-1, 3).min(axis=0))
