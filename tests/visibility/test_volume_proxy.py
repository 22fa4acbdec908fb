"""Volumetric proxies (`probvis.transmittance`): the transmittance walk against closed forms, the extinction of a
random cloud of flat parts against its real visibility, and proxy visibility with them unbiased against exact
visibility, per segment and per image."""
import numpy as np
import pytest

import probvis
from probvis.accel import build_bvh, occluded_segments
from probvis.emitters import build_emitter_sampler
from probvis.integrator import Integrator
from probvis.proxies import build_proxies
from probvis.transmittance import ExtinctionGrid, extinction_grid, transmittances
from probvis.visibility import proxy_plan
from probvis.visibility.proxy import ProxyVisibility

from .test_proxy import blob_scene, segment_draws


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("PROBVIS_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(proxy_plan, "PILOT_BUDGET", np.inf)  # as in test_proxy: the pilot's plan under test


def box_lengths(org, d, lo, hi):
    """Length of each segment o + t d, t in [0, 1], inside the box [lo, hi] (slab method)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo - org) / d, (hi - org) / d
    t0 = np.clip(np.nanmax(np.minimum(ta, tb), axis=1), 0, 1)
    t1 = np.clip(np.nanmin(np.maximum(ta, tb), axis=1), 0, 1)
    return np.maximum(t1 - t0, 0) * np.linalg.norm(d, axis=1)


def test_optical_depth_matches_the_closed_form():
    """In a grid whose lower half (x < 0.5) has σ = 2 and upper half σ = 0.5, T = exp(-2 L_lo - 0.5 L_hi) for
    random segments, inside, crossing and missing the grid, axis-aligned ones included."""
    sigma = np.full((10, 10, 10), 0.5)
    sigma[:5] = 2.0
    grid = ExtinctionGrid(sigma, np.zeros(3), 0.1)
    rng = np.random.default_rng(3)
    org = rng.uniform(-0.5, 1.5, (2000, 3))
    d = rng.uniform(-1.5, 1.5, (2000, 3))
    d[:100, 1:] = 0.0  # along x
    d[100:200, :2] = 0.0  # along z
    lo = box_lengths(org, d, np.zeros(3), np.array([0.5, 1, 1]))
    hi = box_lengths(org, d, np.array([0.5, 0, 0]), np.ones(3))
    t, steps = transmittances(grid.arrays, org, d, np.ones(len(org)))
    np.testing.assert_allclose(t, np.exp(-2 * lo - 0.5 * hi), rtol=1e-9, atol=1e-12)
    assert np.all(steps[lo + hi == 0] <= 1) and steps.max() <= 30
    assert 0.1 < np.mean(lo + hi == 0) < 0.9


def test_the_grid_keeps_half_the_area_of_each_part():
    """Each triangle adds half its area (its mean projected area over all directions) to its centroid's voxel."""
    rng = np.random.default_rng(0)
    tris = rng.uniform(0, 1, (500, 1, 3)) + rng.normal(scale=0.01, size=(500, 3, 3))
    area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
    g = extinction_grid([tris[:200], tris[200:]], resolution=16)
    assert (g.sigma * g.pitch ** 3).sum() == pytest.approx(area.sum() / 2, rel=1e-9)
    cell = np.floor((tris[7].mean(0) - g.lo) / g.pitch).astype(int)
    assert g.sigma[tuple(cell)] * g.pitch ** 3 >= area[7] / 2 - 1e-15


def test_a_random_cloud_blocks_as_its_extinction_predicts():
    """40,000 small randomly oriented triangles uniformly in a unit cube: over random segments across it, the
    share the triangles really block (exact any-hit tests) equals 1 - mean transmittance through their grid,
    within 4 SE and 3% of the model (Cauchy's mean projected area, A / 2)."""
    rng = np.random.default_rng(5)
    n = 40_000
    tris = rng.uniform(0, 1, (n, 1, 3)) + rng.normal(scale=0.006, size=(n, 3, 3))
    g = extinction_grid([tris], resolution=24)
    m = 20_000
    org = np.column_stack([rng.uniform(0.1, 0.9, m), rng.uniform(0.1, 0.9, m), np.full(m, -0.2)])
    end = np.column_stack([rng.uniform(0.1, 0.9, m), rng.uniform(0.1, 0.9, m), np.full(m, 1.2)])
    d = end - org
    v = 1.0 - occluded_segments(build_bvh(tris), org, d, np.ones(m), np.arange(m))[0]
    t, _ = transmittances(g.arrays, org, d, np.ones(m))
    assert 0.2 < v.mean() < 0.8
    se = v.std(ddof=1) / np.sqrt(m)
    assert abs(v.mean() - t.mean()) < 4 * se + 0.03


def foliage(res=16):
    """The built-in canopy: 3,000 separate leaf triangles over the ground."""
    return probvis.load_scene("canopy", res=res, spp=2, shadow_rays=4)


OPTIONS = {"min_triangles": 1000}


def test_auto_prefilters_separate_parts_and_decimates_connected_meshes():
    leaves = build_proxies(foliage(), min_triangles=1000)
    assert [s["kind"] for s in leaves.shapes] == ["volume"] and leaves.n_volumes == 1
    assert leaves.volume.sigma.sum() > 0 and len(leaves.triangles) == foliage().n_triangles - 3000
    blob = build_proxies(blob_scene(), min_triangles=1000)
    assert [s["kind"] for s in blob.shapes] == ["mesh"] and blob.n_volumes == 0
    forced = build_proxies(blob_scene(), min_triangles=1000, kind="volume")
    assert forced.n_volumes == 1 and forced.n_decimated == 0


def test_each_segments_expectation_is_its_exact_visibility():
    """Ground-to-light segments through the leaves, 400 independent draws each with q = 0.3: every segment's
    mean estimate is within 5 SE of its exact V; V_P is a transmittance, strictly between 0 and 1 for most."""
    scene = foliage()
    bvh = build_bvh(scene.triangles)
    est = ProxyVisibility(q="0.3", **OPTIONS)
    emitters = build_emitter_sampler(scene)
    est.prepare(scene, bvh, emitters, scene.defaults, Integrator(scene, bvh, emitters))
    rng = np.random.default_rng(1)
    n = 3000
    org = np.column_stack([rng.uniform(-1.5, 1.5, n), np.full(n, 1e-3), rng.uniform(-1.5, 1.5, n)])
    end = np.column_stack([0.3 + rng.uniform(-0.8, 0.8, n), np.full(n, 2.999), -0.2 + rng.uniform(-0.8, 0.8, n)])
    d = end - org
    exact = 1.0 - occluded_segments(bvh, org, d, np.ones(n), np.arange(n))[0]
    mean, se = segment_draws(est, org, d)
    random = se > 0
    assert random.mean() > 0.5 and (exact == 0).any() and (exact == 1).any()
    assert np.all(np.abs(mean - exact)[random] < 5 * se[random] + 1e-12)
    np.testing.assert_array_equal(mean[~random], exact[~random])


@pytest.mark.parametrize("q", ["auto", "0.2"])
def test_images_are_unbiased(q):
    """Paired by seed with exact visibility, the image-mean difference averages to zero within 4 SE; the stats
    count the extinction grid's voxels walked."""
    scene = foliage()

    def mean(seed, **vis):
        return probvis.render(scene, seed=seed, **vis).image.mean()

    # q auto decides anew for every seed (no cached decision): the survey, the pilot and the plan under test
    options = dict(OPTIONS, q=q, kind="volume", cache=q != "auto")
    diff = np.array([mean(s, visibility="proxy", visibility_options=options) - mean(s) for s in range(12)])
    assert abs(diff.mean()) < 4 * np.std(diff, ddof=1) / np.sqrt(len(diff)) + 1e-12
    e = probvis.render(scene, visibility="proxy", visibility_options=options).stats["estimator"]
    assert e["proxies"][0]["kind"] == "volume" and e["volume_grid"] is not None
    used = not e["emitters"][0]["exact_only"]
    assert used or q == "auto"
    assert (e["tests"]["proxy"]["voxel"] > 0) == used
    assert e["memory_bytes"]["proxies"] >= 8 * np.prod(e["volume_grid"])


def test_a_bad_kind_names_the_option():
    with pytest.raises(probvis.ProbvisError, match="kind must be one of auto, mesh, volume, got 'leaves'"):
        probvis.render(foliage(8), visibility="proxy", visibility_options={"kind": "leaves"})
