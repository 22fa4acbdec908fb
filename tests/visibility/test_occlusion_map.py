"""The occlusion map: cases on a quad over a plane, analytic polygon light, volumetric culling, determinism,
bad input and the no-photon fallback."""
import warnings

import numba
import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from probvis.accel import build_bvh, closest_hit
from probvis.cases import CASE_LIT, CASE_MASK, CASE_PENUMBRA, CASE_SHADOWED
from probvis.emitters import build_emitter_sampler, triangle_irradiance
from probvis.integrator import Integrator
from probvis.visibility.occlusion_map import closed_orientation
from probvis.scene import SceneBuilder, load_scene
from probvis.scene import shapes as shp
from probvis.visibility import ShadingPoints, make_estimator
from probvis.geometry import unit_normals
from probvis.accel import visibility_from_lists
from tests.conftest import sensor, write_scene


def prepared(scene, **options):
    est = make_estimator("occlusion-map", **options)
    bvh, emitters = build_bvh(scene.triangles), build_emitter_sampler(scene)
    est.prepare(scene, bvh, emitters, scene.defaults, Integrator(scene, bvh, emitters))
    return est


def floor_points(scene, xy):
    """Shading points on quad-shadow's floor (z = 0) below the given (x, y)."""
    org = np.column_stack([xy, np.full(len(xy), 0.5)])
    bvh = build_bvh(scene.triangles)
    prim, t, _, _, _, _ = closest_hit(bvh.arrays, org, np.tile([0.0, 0.0, -1.0], (len(xy), 1)),
                                      np.zeros(len(xy)), np.full(len(xy), np.inf))
    assert np.all(prim >= 0) and np.allclose(t, 0.5)
    return ShadingPoints(org - [0, 0, 0.5], np.tile([0.0, 0.0, 1.0], (len(xy), 1)), prim,
                         np.arange(len(xy), dtype=np.uint64))


@pytest.mark.parametrize("penumbra", ["list", "bvh"])
def test_quad_over_plane_cases_and_candidate_lists(penumbra):
    """Blocker [-0.5, 0.5]^2 at z = 1, light [-0.25, 0.25]^2 at z = 2: umbra |x|, |y| < 0.75, lit beyond 1.25."""
    scene = load_scene("quad-shadow")
    est = prepared(scene, photons=200_000, penumbra=penumbra)
    umbra, lit, pen = [[0.0, 0.0], [0.3, -0.2]], [[2.0, 0.0], [0.0, -2.5], [1.8, 1.8]], [[1.0, 0.0], [0.0, -1.0]]
    points = floor_points(scene, np.array(umbra + lit + pen))
    case = est.classify(points)[:, 0] & CASE_MASK
    assert case.tolist() == [CASE_SHADOWED] * 2 + [CASE_LIT] * 3 + [CASE_PENUMBRA] * 2
    blocker = set(range(scene.shapes[1].first_triangle, scene.shapes[1].first_triangle + 2))
    if penumbra == "list":
        for i in (5, 6):
            assert set(est.lookup.candidates(i, 0).tolist()) == blocker


def mc_irradiance(tri, p, n, samples, rng):
    """Monte Carlo of the integral of max(0, n.w) over the triangle's front side, sampling its area."""
    u, v = rng.random(samples), rng.random(samples)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    y = tri[0] + u[:, None] * (tri[1] - tri[0]) + v[:, None] * (tri[2] - tri[0])
    cross = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    area, ln = np.linalg.norm(cross) / 2, cross / np.linalg.norm(cross)
    w = y - p
    d2 = np.einsum("ij,ij->i", w, w)
    w /= np.sqrt(d2)[:, None]
    f = np.maximum(0, w @ n) * np.maximum(0, -(w @ ln)) / d2 * area
    return f.mean(), f.std() / np.sqrt(samples)


@pytest.mark.parametrize("tri, n, what", [
    ([[-0.3, -0.2, 1.0], [0.4, -0.1, 1.0], [0.0, 0.5, 1.0]], [0, 0, 1], "above, facing down"),
    ([[-0.3, -0.2, 1.0], [0.0, 0.5, 1.0], [0.4, -0.1, 1.0]], [0, 0, 1], "back side: zero"),
    ([[1.0, -0.5, -0.4], [1.0, 0.5, -0.4], [1.0, 0.0, 0.8]], [0, 0, 1], "crossing the horizon"),
    ([[0.5, -0.5, -0.9], [0.6, 0.5, 0.3], [0.4, 0.1, 1.2]], [0.2, 0.3, 0.93], "tilted receiver, crossing"),
])
def test_analytic_polygon_irradiance_matches_monte_carlo(tri, n, what):
    tri = np.array(tri, dtype=float)
    n = np.array(n, dtype=float) / np.linalg.norm(n)
    facing = np.cross(tri[1] - tri[0], tri[2] - tri[0]) @ (np.zeros(3) - tri[0]) > 0
    if facing != (what != "back side: zero"):  # wind the emitting side towards the receiver, or away
        tri = tri[[0, 2, 1]]
    exact = triangle_irradiance(tri[None], 0, 0.0, 0.0, 0.0, *n)
    mc, se = mc_irradiance(tri, np.zeros(3), n, 2_000_000, np.random.default_rng(1))
    if what == "back side: zero":
        assert exact == 0.0 and mc == 0.0
    else:
        assert exact > 0 and abs(exact - mc) < 4 * se, what


def closed_scene():
    b = SceneBuilder("closed")
    v, f, _ = shp.uv_sphere(12, 24)
    b.add_mesh("ball", "sphere", v, f, None, b.material(0.5))
    v, f = shp.cube()
    b.add_mesh("box", "cube", v, f, np.diag([0.7, 0.3, 0.5, 1.0]) + np.array(
        [[0, 0, 0, 2.0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]), b.material(0.5))
    b.add_mesh("light", "rectangle", *shp.rectangle(), None, None, radiance=1.0)
    return b.build(load_scene("quad-shadow").camera)


def test_closed_components_are_found_and_culling_keeps_visibility_identical():
    scene = closed_scene()
    orient = closed_orientation(scene)
    ball, box, light = scene.shapes
    assert np.all(orient[:ball.n_triangles + box.n_triangles] == 1)
    assert np.all(orient[light.first_triangle:] == 0)  # an open rectangle
    rng = np.random.default_rng(5)
    n = 20000
    a = rng.normal(size=(n, 3))
    b = rng.normal(size=(n, 3))
    org = 2.5 * a / np.linalg.norm(a, axis=1, keepdims=True) + [1, 0, 0]
    end = 2.5 * b / np.linalg.norm(b, axis=1, keepdims=True) + [1, 0, 0]
    everything = np.arange(scene.n_triangles, dtype=np.int32)
    lo, hi = np.zeros(n, np.int64), np.full(n, scene.n_triangles, np.int64)
    fn = unit_normals(scene.triangles)
    args = (org, end - org, np.ones(n), lo, hi, everything)
    vis_all, tests_all, cull_none = visibility_from_lists(scene.triangles, np.zeros_like(orient), fn, *args)
    vis_cull, tests_cull, culled = visibility_from_lists(scene.triangles, orient, fn, *args)
    np.testing.assert_array_equal(vis_cull, vis_all)
    assert 0.1 < (vis_all == 0).mean() < 0.9
    assert cull_none.sum() == 0 and culled.sum() > 0
    assert tests_cull.sum() < 0.75 * tests_all.sum()


def test_volumetric_culling_does_not_change_the_image():
    kw = dict(visibility="occlusion-map", resolution=(24, 24), spp=2, shadow_rays=4)
    a = probvis.render("cornell-box", visibility_options=dict(penumbra="list", volumetric=True), **kw)
    b = probvis.render("cornell-box", visibility_options=dict(penumbra="list", volumetric=False), **kw)
    np.testing.assert_array_equal(a.image, b.image)
    assert a.stats["estimator"]["culled_candidates"] > 0 == b.stats["estimator"]["culled_candidates"]
    assert a.stats["intersection_tests"]["triangle"] < b.stats["intersection_tests"]["triangle"]


def test_deterministic_for_a_seed_whatever_the_thread_count():
    kw = dict(visibility="occlusion-map", resolution=(24, 24), spp=2, shadow_rays=4, seed=7,
              visibility_options=dict(penumbra="list", adaptive_photons=True))
    prev = numba.get_num_threads()
    try:
        a = probvis.render("quad-shadow", threads=1, **kw)
        b = probvis.render("quad-shadow", threads=min(2, numba.config.NUMBA_NUM_THREADS), **kw)
    finally:
        numba.set_num_threads(prev)
    np.testing.assert_array_equal(a.image, b.image)
    assert a.stats["estimator"]["photons"] == b.stats["estimator"]["photons"]
    assert a.stats["estimator"]["adaptive_rounds"][0]["photons_added"] > 0


def test_matches_exact_visibility_within_the_noise():
    """With the whole BVH in the penumbra, only misclassified lit/shadowed points could bias the image."""
    kw = dict(resolution=(32, 32), spp=16, shadow_rays=8, seed=1)
    om = probvis.render("quad-shadow", visibility="occlusion-map", **kw)
    ex = probvis.render("quad-shadow", visibility="exact", **kw)
    assert om.stats["shadow_rays"] < 0.5 * ex.stats["shadow_rays"]
    var = (om.aovs["second_moment"] - om.image ** 2) / kw["spp"] + (ex.aovs["second_moment"] - ex.image ** 2) / kw["spp"]
    diff = (om.image - ex.image).mean()
    se = np.sqrt(np.maximum(var, 0).sum()) / var.size
    assert abs(diff) < 4 * se


@pytest.mark.parametrize("options, message", [
    (dict(photons=0), "photons must be from 1 to 1,073,741,824, got 0"),
    (dict(neighbours=-3), "neighbours must be from 1 to 1,024"),
    (dict(neighbours=2.5), "neighbours expects integer, got 2.5"),
    (dict(radius=-1.0), "radius must be positive"),
    (dict(radius=float("nan")), "radius expects a finite number, got nan"),
    (dict(penumbra="grid"), "penumbra must be one of bvh, list, got 'grid'"),
    (dict(pneumbra="list"), "visibility 'occlusion-map' has no option 'pneumbra'"),
])
def test_bad_options_are_clear_errors(options, message):
    with pytest.raises(ProbvisError, match=message):
        make_estimator("occlusion-map", **options)


def test_no_photon_hits_anything_falls_back_to_exact(tmp_path):
    """A light facing up into empty space lights nothing: every point is unknown, the image is exact's."""
    body = sensor(origin="0, 0, 3", spp=2, sr=2) + """
    <shape type="rectangle"><transform name="to_world"><scale value="3"/></transform></shape>
    <shape type="rectangle"><transform name="to_world"><translate z="1"/></transform>
        <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"""
    path = write_scene(tmp_path / "up.xml", body)
    with pytest.warns(UserWarning, match="no photon"):
        om = probvis.render(path, visibility="occlusion-map")
    ex = probvis.render(path, visibility="exact")
    np.testing.assert_array_equal(om.image, ex.image)
    assert om.stats["cases"]["unknown"]["share"] == 1.0


def test_an_automatic_radius_beyond_the_scene_warns():
    """Too few photons for the neighbours asked: the radius the map picks spans the whole Cornell box (diagonal
    3.46), which the user is told, naming what to change; the defaults stay silent."""
    with pytest.warns(UserWarning, match=r"automatic radius [\d.]+ is larger than the scene \(diagonal 3.464\): "
                                         r"\d+ photons are too few for neighbours 1024.*more photons or fewer"):
        probvis.render("cornell-box", resolution=(8, 8), spp=1, visibility="occlusion-map",
                       visibility_options={"photons": 1000, "neighbours": 1024})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        probvis.render("cornell-box", resolution=(8, 8), spp=1, visibility="occlusion-map")


def test_the_scene_structure_is_cached_by_content(tmp_path, monkeypatch):
    """Components and closed orientation come from the disk cache on the second render, equal to a fresh
    computation; another scene gets its own entry."""
    from probvis.visibility.occlusion_map.components import closed_orientation, components, structure

    monkeypatch.setenv("PROBVIS_CACHE_DIR", str(tmp_path))
    scene = probvis.load_scene("cornell-box", res=8)
    first, again = structure(scene), structure(scene)
    label, _, n = components(scene)
    for st in (first, again):
        np.testing.assert_array_equal(st.label, label)
        np.testing.assert_array_equal(st.orientation, closed_orientation(scene))
        assert st.n_components == n
    assert len(list((tmp_path / "structure").glob("*.npz"))) == 1
    structure(probvis.load_scene("box-city", res=8))
    assert len(list((tmp_path / "structure").glob("*.npz"))) == 2
    assert structure(scene, use_cache=False).n_components == n


@pytest.mark.parametrize("entry", [{"x": np.arange(3)}, {"label": np.zeros(5, np.int64), "n_components": 1,
                                                         "orientation": np.zeros(5, np.int8)}])
def test_a_foreign_cache_entry_is_rebuilt(tmp_path, monkeypatch, entry):
    """An entry with other arrays, or arrays of other shapes, was a KeyError or a wrong-shape traceback (the
    proxies' and shells' entries likewise); it is rebuilt as a damaged one is."""
    from probvis.visibility.occlusion_map.components import components, structure

    monkeypatch.setenv("PROBVIS_CACHE_DIR", str(tmp_path))
    scene = probvis.load_scene("cornell-box", res=8)
    structure(scene)
    (path,) = (tmp_path / "structure").glob("*.npz")
    np.savez(path.with_suffix(""), **entry)
    label, _, n = components(scene)
    st = structure(scene)
    np.testing.assert_array_equal(st.label, label)
    assert st.n_components == n


@pytest.mark.parametrize("damage", ["truncated", "crc", "huge"])
def test_a_damaged_cache_archive_is_rebuilt(tmp_path, monkeypatch, damage):
    """A truncated .npz (BadZipFile) or one with a bad member checksum was a traceback, not a rebuild; a member
    whose header declares (10^11, 3) over 64 bytes was 'out of memory: lower the resolution'."""
    import io
    import zipfile
    from probvis.visibility.occlusion_map.components import components, structure

    monkeypatch.setenv("PROBVIS_CACHE_DIR", str(tmp_path))
    scene = probvis.load_scene("cornell-box", res=8)
    structure(scene)
    (path,) = (tmp_path / "structure").glob("*.npz")
    data = bytearray(path.read_bytes())
    if damage == "truncated":
        del data[len(data) // 2:]
    elif damage == "huge":
        member = io.BytesIO()
        np.lib.format.write_array_header_1_0(member, {"descr": "<i8", "fortran_order": False, "shape": (10**11, 3)})
        buffer = io.BytesIO()
        with zipfile.ZipFile(buffer, "w") as archive:
            for name in ("label", "n_components", "orientation"):
                archive.writestr(f"{name}.npy", member.getvalue() + bytes(64))
        data = bytearray(buffer.getvalue())
    else:
        at = data.index(b"\x93NUMPY") + 200  # a byte of the first member's array data
        data[at] ^= 0xFF
    path.write_bytes(bytes(data))
    assert structure(scene).n_components == components(scene)[2]


def test_a_cache_entry_that_would_inflate_beyond_memory_is_rebuilt(tmp_path, monkeypatch):
    """An archive whose members honestly inflate to more than the process can allocate (zeros compress well) was
    loaded, and its MemoryError was 'out of memory: lower the resolution'; it now counts as damaged."""
    from probvis import disk_cache

    monkeypatch.setenv("PROBVIS_CACHE_DIR", str(tmp_path))
    disk_cache.store("structure", "k", {"label": np.zeros(1000, np.int64)})
    assert disk_cache.load("structure", "k") is not None
    monkeypatch.setattr(disk_cache.memory, "available", lambda: 4000)  # 8,000 bytes declared
    assert disk_cache.load("structure", "k") is None


def test_a_cache_entry_changed_since_it_was_stored_is_rebuilt(tmp_path, monkeypatch):
    """An entry of the right names, shapes and types but other values (a huge n_components was 'out of memory',
    a shells grid of zeros a wrong image) no longer matches the digest stored with it, and is rebuilt; a write
    that fails leaves no temporary file behind."""
    from probvis import disk_cache
    from probvis.visibility.occlusion_map.components import components, structure

    monkeypatch.setenv("PROBVIS_CACHE_DIR", str(tmp_path))
    scene = probvis.load_scene("cornell-box", res=8)
    structure(scene)
    (path,) = (tmp_path / "structure").glob("*.npz")
    with np.load(path) as f:
        entry = {k: f[k] for k in f.files}
    entry["n_components"] = np.array(10 ** 12)
    np.savez(path.with_suffix(""), **entry)
    assert structure(scene).n_components == components(scene)[2]
    assert disk_cache.load("structure", path.stem) is not None  # rebuilt and stored again, with its digest

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(disk_cache.np, "savez", full)
    with pytest.warns(UserWarning, match="cannot cache in .*No space left on device") as said:
        disk_cache.store("structure", "k", {"x": np.arange(3)})
        disk_cache.store("structure", "k2", {"x": np.arange(3)})  # the same folder: said once
    assert len(said) == 1
    assert sorted(p.name for p in (tmp_path / "structure").iterdir()) == [path.name]
    monkeypatch.setenv("PROBVIS_CACHE_DIR", "")
    monkeypatch.setenv("HOME", "")
    assert disk_cache.cache_dir("plans").is_absolute() and str(disk_cache.cache_dir("plans")) != "/.cache/probvis/plans"


@pytest.mark.parametrize("n_groups", [5, 60, 300])  # up to 64 distinct groups ordered by comparisons, more sorted
def test_candidate_lists_hold_the_neighbours_groups_most_often_recorded_first(n_groups):
    """Each penumbra point's list: its agreeing shadow photons' blocker groups, by descending count, ties by
    lower group id (the definition, by NumPy), each group's triangles in its order; the Good-Turing share."""
    from probvis.visibility.occlusion_map.components import BlockerGroups
    from probvis.visibility.occlusion_map.lookup import classify_points
    from probvis.visibility.occlusion_map.photons import PhotonArrays
    rng = np.random.default_rng(n_groups)
    n_photons, k, max_hits = 400, 32, 16
    n_blockers = np.where(rng.random(n_photons) < 0.3, 0, rng.integers(1, max_hits + 1, n_photons)).astype(np.int32)
    start = np.concatenate([[0], np.cumsum(n_blockers)[:-1]]).astype(np.int64)
    n_tris = 2 * n_groups
    ray_tris = rng.integers(0, n_tris, int(n_blockers.sum())).astype(np.int32)
    group = (np.arange(n_tris) // 2).astype(np.int32)  # triangles 2g and 2g + 1 stand for group g, listed reversed
    groups = BlockerGroups(group, np.arange(0, n_tris + 1, 2, dtype=np.int64),
                           np.arange(n_tris, dtype=np.int32).reshape(-1, 2)[:, ::-1].ravel().copy())
    normal = np.tile([0.0, 0.0, 1.0], (n_photons, 1))
    normal[rng.random(n_photons) < 0.1] = [1.0, 0.0, 0.0]  # photons whose normals disagree do not count
    nbr = rng.integers(-1, n_photons, (50, k))
    nrm = np.tile([0.0, 0.0, 1.0], (50, 1))
    case, offsets, tris, counts, unseen = classify_points(nbr, nrm, PhotonArrays(normal, n_blockers, start, ray_tris),
                                                          groups, 0.7, 4, max_hits, True)
    n_pen = 0
    for i in range(50):
        agree = [j for j in nbr[i] if j >= 0 and normal[j, 2] > 0.7]
        shadow = [j for j in agree if n_blockers[j]]
        assert counts[i].tolist() == [len(agree) - len(shadow), len(shadow)]
        if case[i] != CASE_PENUMBRA:
            assert offsets[i + 1] == offsets[i]
            continue
        n_pen += 1
        recorded = group[np.concatenate([ray_tris[start[j]:start[j] + n_blockers[j]] for j in shadow])]
        ids, freq = np.unique(recorded, return_counts=True)
        expected = ids[np.argsort(-freq, kind="stable")]
        assert tris[offsets[i]:offsets[i + 1]].tolist() == groups.tris.reshape(-1, 2)[expected].ravel().tolist()
        assert unseen[i] == pytest.approx((freq == 1).sum() / len(recorded))
    assert n_pen > 10
