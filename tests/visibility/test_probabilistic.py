"""Probabilistic visibility: exact expectations by enumeration, sampled expectations of the kernel, the
tables against hand-derived variances, grouping balance, and convergence to the occlusion map's image."""
import json

import numpy as np
import pytest

import probvis
from probvis import ProbvisError
from probvis.accel import CandidateGeometry
from probvis.cli import main
from probvis.rng import make_key
from probvis.visibility import make_estimator
from probvis.visibility.probabilistic import power, shifted, standard
from probvis.visibility.probabilistic.mixture import choose
from probvis.visibility.probabilistic.decomposition import CONFIGS
from probvis.visibility.probabilistic.kernels import (GROUP_COUNT, GROUP_SOLID_ANGLE, GroupedLists, TermTables,
                                               evaluate_segments, group_lists, solid_angle)


def decompositions(rng):
    p = rng.dirichlet([1, 1, 1]) * 0.97 + 0.01
    p /= p.sum()
    s = rng.normal(size=3)
    s[2] = 1 - s[0] - s[1]
    return [standard(p), shifted(p, s), power(int(rng.integers(2, 12)), p)]


@pytest.mark.parametrize("seed", range(20))
def test_expectation_over_term_choices_is_the_product_in_all_configurations(seed):
    for d in decompositions(np.random.default_rng(seed)):
        coef = d.coefficients()
        for va, vb in CONFIGS:
            assert d.expectation(va, vb) == pytest.approx(va * vb, abs=1e-9), (d.name, va, vb)
            bilinear = coef[:, 0] + coef[:, 1] * va + coef[:, 2] * vb + coef[:, 3] * va * vb
            assert np.dot(d.p, bilinear) == pytest.approx(va * vb, abs=1e-9)


def test_adaptive_mixtures_are_unbiased_for_any_photon_statistics():
    rng = np.random.default_rng(3)
    counts = rng.integers(0, 30, size=(500, 4)).astype(float)
    counts[::2] = [0, 0, 0, 60]  # photons say: visible - a cheap single-group term has little variance there
    cdf, coef, mode, best = choose(counts, rng.integers(1, 40, 500), rng.integers(1, 40, 500))
    p = np.diff(np.concatenate([np.zeros((500, 1)), cdf], axis=1), axis=1)
    for va, vb in CONFIGS:
        e = np.einsum("nk,nk->n", p, coef[:, :, 0] + coef[:, :, 1] * va + coef[:, :, 2] * vb + coef[:, :, 3] * va * vb)
        np.testing.assert_allclose(e, va * vb, atol=1e-9)
    assert np.all(mode[best == 0, 0] == 4) and np.all(cdf[best == 0, 0] == 1.0)  # exact: one term, both groups


def test_tables_match_hand_derived_variances():
    """Hand-derived with p = 1/3: standard values (3V_A, 3V_B, 3(V̄_A V̄_B - 1)) have variance 0, 6, 6, 8;
    the shifted (alternative) one 2 everywhere; power 8: values -3V_A/254, -3V_B/254, 3(V_A+V_B)^8/254."""
    var = {d.name: [r["variance"] for r in d.rows()] for d in (standard(), shifted(), power(8))}
    np.testing.assert_allclose(var["standard"], [0, 6, 6, 8], atol=1e-12)
    np.testing.assert_allclose(var["shifted"], [2, 2, 2, 2], atol=1e-12)
    k = 254.0
    one = (2 * 9 / k ** 2) / 3  # E[x^2] with values 0, -3/254, 3/254 and mean 0
    both = (2 * 9 + 768 ** 2) / (3 * k ** 2) - 1
    np.testing.assert_allclose(var["power-8"], [0, one, one, both], rtol=1e-12)


def test_tables_cli_json(capsys):
    assert main(["tables", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [d["decomposition"] for d in out] == ["standard", "shifted", "power-8"]
    assert out[1]["rows"][0] == {"VA": 0, "VB": 0, "product": 0, "values": pytest.approx([-1, -1, 2]),
                                 "variance": pytest.approx(2)}
    assert main(["tables", "--shifts", "1,1,1"]) == 2
    assert "summing to 1" in capsys.readouterr().err


def test_shifts_that_sum_to_1_within_rounding_are_taken_as_exact():
    """A third typed to seven digits three times sums to 0.9999999: accepted as the user's check accepts it, the
    last shift taken as 1 - α - β so that the terms sum to V_A V_B exactly (an unbiased estimate)."""
    from probvis.visibility.probabilistic.shifted import shifted

    d = shifted(shifts=(0.3333333, 0.3333333, 0.3333333))
    for va, vb in ((0, 0), (0, 1), (1, 0), (1, 1)):
        assert d.f[:, va, vb].sum() == pytest.approx(va * vb, abs=1e-15)


def blockers(n_a, n_b, covered):
    """n_a + n_b small triangles around the segment from (0,0,0) to (0,0,1); `covered` says which cross it."""
    tris = []
    for k in range(n_a + n_b):
        z = 0.2 + 0.6 * k / max(1, n_a + n_b - 1)
        off = 0.0 if covered[k] else 5.0
        tris.append([[off - 1, -1, z], [off + 1, -1, z], [off, 1, z]])
    return np.array(tris, dtype=float)


@pytest.mark.parametrize("levels, cells", [(1, 1), (2, 1), (1, 2)])
@pytest.mark.parametrize("covered", [(0, 0, 0, 0), (1, 0, 0, 0), (0, 0, 1, 0), (1, 0, 0, 1), (1, 1, 1, 1)])
def test_kernel_estimates_are_unbiased_by_sampling(levels, cells, covered):
    """Sampled over many segment keys, the mean estimate equals the true visibility within 4 standard errors,
    for the standard, shifted and power decompositions, with recursive subdivision and cells along the ray."""
    tris = blockers(2, 2, covered)
    truth = 0.0 if any(covered) else 1.0
    n = 40000
    org, dirs = np.zeros((n, 3)), np.tile([0.0, 0.0, 1.0], (n, 1))
    offsets, ids = np.array([0, 4]), np.arange(4, dtype=np.int32)
    grouped, bounds, _ = group_lists(tris, np.zeros((1, 3)), offsets, ids, ids, 1, GROUP_COUNT, levels, cells, 0)
    keys = np.array([make_key(11, 1, i) for i in range(n)], dtype=np.uint64)
    for d in (standard((0.5, 0.3, 0.2)), shifted(), power(4)):
        value, tests, _, term = evaluate_segments(
            CandidateGeometry(tris, np.zeros(4, np.int8), np.zeros((4, 3))), org, dirs, np.ones(n),
            np.zeros(n, np.int64), keys, GroupedLists(grouped, bounds, levels, cells),
            TermTables(np.cumsum(d.p)[None], d.coefficients()[None], d.mode[None], False))
        se = value.std() / np.sqrt(n)
        assert abs(value.mean() - truth) < 4 * se + 1e-12, (d.name, value.mean(), truth, se)
        assert tests.max() <= 4 and set(np.unique(term)) <= {0, 1, 2}


def test_solid_angle_grouping_balances_the_accumulated_solid_angle():
    rng = np.random.default_rng(2)
    tris = rng.normal(size=(60, 1, 3)) * 0.1 + rng.normal(size=(60, 3, 3)) * 0.03 + [0, 0, 1]
    ids = np.arange(60, dtype=np.int32)
    grouped, bounds, balance = group_lists(tris, np.zeros((1, 3)), np.array([0, 60]), ids, ids, 1, GROUP_SOLID_ANGLE,
                                           1, 1, 0)
    w = np.array([solid_angle(tris, t, 0.0, 0.0, 0.0) for t in range(60)])
    a, b = grouped[:bounds[0, 1]], grouped[bounds[0, 1]:]
    assert sorted(grouped.tolist()) == list(range(60))
    assert abs(w[a].sum() - w[b].sum()) <= w.max() + 1e-12
    np.testing.assert_allclose(balance[0], [w[a].sum(), w[b].sum()])
    _, cb, _ = group_lists(tris, np.zeros((1, 3)), np.array([0, 60]), ids, ids, 1, GROUP_COUNT, 1, 1, 0)
    assert cb[0, 1] - cb[0, 0] == 30
    # a pair marked to skip (verified with certainty, its groups unused) keeps its list whole, unsplit
    kept, kb, kbal = group_lists(tris, np.zeros((1, 3)), np.array([0, 30, 60]), ids, ids, 1, GROUP_SOLID_ANGLE,
                                 1, 1, 0, np.array([False, True]))
    assert kb[1].tolist() == [30, 60, 60] and kept[30:].tolist() == list(range(30, 60)) and kbal[1].sum() == 0
    assert kb[0, 0] == 0 and 0 < kb[0, 1] < 30 and kbal[0].sum() > 0


def greedy_split(w):
    """The definition: units by descending solid angle (ties in list order), each to the lighter side so far."""
    side, sums = np.empty(len(w), int), [0.0, 0.0]
    for u in np.argsort(-w, kind="stable"):
        side[u] = 0 if sums[0] <= sums[1] else 1
        sums[side[u]] += w[u]
    return side


@pytest.mark.parametrize("n", [7, 64, 65, 200])  # ranked by comparisons up to 64 units, sorted beyond
def test_solid_angle_split_is_the_greedy_definition_with_ties(n):
    """Duplicated triangles tie in solid angle: the split equals the stable greedy definition, list order kept."""
    rng = np.random.default_rng(n)
    base = rng.normal(size=(n // 2 + 1, 1, 3)) * 0.1 + rng.normal(size=(n // 2 + 1, 3, 3)) * 0.03 + [0, 0, 1]
    tris = base[rng.integers(0, len(base), n)]  # about half the units tie with another
    ids = rng.permutation(n).astype(np.int32)
    grouped, bounds, _ = group_lists(tris, np.zeros((1, 3)), np.array([0, n]), ids, np.arange(n, dtype=np.int32),
                                     1, GROUP_SOLID_ANGLE, 1, 1, 0)
    w = np.array([solid_angle(tris, t, 0.0, 0.0, 0.0) for t in ids])
    side = greedy_split(w)
    assert grouped[:bounds[0, 1]].tolist() == ids[side == 0].tolist()
    assert grouped[bounds[0, 1]:].tolist() == ids[side == 1].tolist()


def test_blocker_groups_go_to_one_side_whole():
    """Candidates of one blocker group (a run of the list, here 20 groups of 3) land in the same group, A or B,
    keeping their order; the solid angle still balances to within the largest blocker group."""
    rng = np.random.default_rng(5)
    tris = rng.normal(size=(60, 1, 3)) * 0.1 + rng.normal(size=(60, 3, 3)) * 0.03 + [0, 0, 1]
    ids = np.arange(60, dtype=np.int32)
    unit = (ids // 3).astype(np.int32)
    grouped, bounds, balance = group_lists(tris, np.zeros((1, 3)), np.array([0, 60]), ids, unit, 1,
                                           GROUP_SOLID_ANGLE, 1, 1, 0)
    side = np.empty(60, int)
    side[grouped[:bounds[0, 1]]] = 0
    side[grouped[bounds[0, 1]:]] = 1
    assert all(len(set(side[unit == u])) == 1 for u in range(20))
    for part in (grouped[:bounds[0, 1]], grouped[bounds[0, 1]:]):
        assert list(part) == sorted(part)  # list order kept within a group
    w = np.array([solid_angle(tris, t, 0.0, 0.0, 0.0) for t in range(60)])
    per_unit = np.bincount(unit, weights=w)
    assert abs(balance[0, 0] - balance[0, 1]) <= per_unit.max() + 1e-12
    np.testing.assert_allclose(balance[0].sum(), w.sum())


def test_solid_angle_of_an_octant_triangle():
    tri = np.array([[[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]])
    assert solid_angle(tri, 0, 0.0, 0.0, 0.0) == pytest.approx(np.pi / 2)


def test_rendered_probvis_converges_to_the_occlusion_map_image():
    """Same candidate lists, different estimators: the image means agree within 4 standard errors."""
    kw = dict(resolution=(24, 24), spp=16, shadow_rays=8, seed=5, visibility_options=None)
    base = dict(photons=100_000)
    om = probvis.render("canopy", visibility="occlusion-map", **{**kw, "visibility_options": {**base, "penumbra": "list"}})
    for est in ("standard", "shifted", "adaptive"):
        pv = probvis.render("canopy", visibility="probvis", **{**kw, "visibility_options": {**base, "estimator": est}})
        n = kw["spp"]
        var = (pv.aovs["second_moment"] - pv.image ** 2 + om.aovs["second_moment"] - om.image ** 2) / n
        se = np.sqrt(np.maximum(var, 0).sum()) / var.size
        assert abs((pv.image - om.image).mean()) < 4 * se, est
        if est != "adaptive":
            assert pv.stats["negative_estimates"] > 0


def test_probvis_tests_fewer_triangles_than_the_lists_it_works_on():
    """The 2013 paper's claim, on the same unverified lists: a stochastic term tests fewer candidates."""
    kw = dict(resolution=(24, 24), spp=16, shadow_rays=8, seed=5)
    base = dict(photons=100_000, verify="off")
    om = probvis.render("canopy", visibility="occlusion-map", visibility_options={**base, "penumbra": "list"}, **kw)
    for est in ("standard", "shifted"):
        pv = probvis.render("canopy", visibility="probvis", visibility_options={**base, "estimator": est}, **kw)
        assert pv.stats["intersection_tests"]["shadow"]["triangle"] < om.stats["intersection_tests"]["shadow"][
            "triangle"]


def test_clamping_negative_pixels_is_reported_as_a_bias():
    kw = dict(resolution=(16, 16), spp=1, shadow_rays=1, seed=2, visibility="probvis",
              visibility_options={"estimator": "standard", "photons": 50_000})
    raw = probvis.render("canopy", **kw)
    clamped = probvis.render("canopy", clamp_negative=True, **kw)
    neg = raw.stats["negative_pixels"]
    assert neg["negative_pixel_share"] > 0 and not neg["clamped"]
    assert clamped.image.min() >= 0
    bias = clamped.stats["negative_pixels"]["mean_bias"]
    np.testing.assert_allclose(bias, (clamped.image - raw.image).reshape(-1, 3).mean(axis=0))
    assert min(bias) > 0


@pytest.mark.parametrize("options, message", [
    (dict(estimator="magic"), "estimator must be one of standard, shifted, power, adaptive"),
    (dict(grouping="colour"), "grouping must be"),
    (dict(probabilities=(0.5, 0.5, 0.5)), "must sum to 1"),
    (dict(probabilities=(1e-320, 0.5, 0.5)), "must each be at least 1e-06"),
    (dict(estimator="shifted", shifts=(1, 1, 1)), "summing to 1"),
    (dict(shifts=(0.2, 0.3, 0.5)), "shifted estimator only"),
    (dict(levels=0), "levels must be"),
    (dict(estimator="adaptive", levels=2), "adaptive estimator"),
    (dict(penumbra="bvh"), "visibility .probvis. has no option .penumbra."),
    (dict(levels=6), "levels must be .*from 1 to 5"),
    (dict(levels=5), r"could reach ±3.1e\+16 .*beyond 1e\+12; lower levels or cells"),
    (dict(levels=2, cells=8), r"could reach ±1.7e\+13"),
    (dict(probabilities=(1e-6, 0.5, 0.5), levels=5, cells=5), "beyond a double's range"),
])
def test_bad_probvis_options(options, message):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # one error, no warning before it (the reach overflowing a double warned)
        with pytest.raises(ProbvisError, match=message):
            make_estimator("probvis", **options)


def test_deep_subdivision_warns_that_the_image_will_be_noisy():
    """Levels or cells whose terms reach beyond NOISY_REACH render (unbiased) with a warning naming the reach;
    the defaults and shallow settings render without."""
    with pytest.warns(UserWarning, match=r"levels 3 and cells 1: one segment's estimate may reach ±5.8e\+03"):
        probvis.render("quad-shadow", spp=1, shadow_rays=1, resolution=(4, 4), visibility="probvis",
                       visibility_options={"levels": 3})
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        probvis.render("quad-shadow", spp=1, shadow_rays=1, resolution=(4, 4), visibility="probvis",
                       visibility_options={"levels": 2})


@pytest.mark.parametrize("estimator", ["standard", "shifted", "power"])
def test_the_reach_of_recursive_estimates_is_their_largest_value(estimator):
    """`Decomposition.reach` (what --levels and --cells are checked against) is the largest |estimate| of two
    levels, found by enumerating every leaf configuration and every term drawn at each split."""
    import itertools
    d = make_estimator("probvis", estimator=estimator).decomposition
    coef = d.coefficients()

    def values(leaves):
        if len(leaves) == 1:
            return {float(leaves[0])}
        half = len(leaves) // 2
        return {a + b * x + c * y + e * x * y for a, b, c, e in coef for x in values(leaves[:half])
                for y in values(leaves[half:])}

    largest = max(abs(v) for leaves in itertools.product((0, 1), repeat=4) for v in values(leaves))
    assert d.reach(2, 1) == pytest.approx(largest, rel=1e-12)
    assert d.reach(2, 3) == pytest.approx(largest ** 3, rel=1e-12)
