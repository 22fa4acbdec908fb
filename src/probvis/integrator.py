"""Direct illumination, run stage by stage over batches of whole pixels (wavefront style):

camera rays -> closest hits -> shading points and emitter samples -> visibility estimator -> film.

Exact visibility takes a fused last stage instead (`shade_exact`: sample, trace and sum a shading point's
segments while they are in cache), with the staged path's numbers bit for bit.

Each camera sample emits `shadow_rays` emitter samples (emitter by power, triangle by area, uniform point)
with a Lambertian BRDF; one-sided diffuse surfaces are black from behind and emitters emit from their
front side only, as in Mitsuba 3.
"""
import math
import time
from dataclasses import dataclass, field

import numba
import numpy as np
from numba import njit, prange

from . import __version__
from .accel import MAX_PACKET, build_bvh, nearest_hits, occluded_packet, packet_work, root_record
from .camera import camera_params, camera_rays
from .errors import ProbvisError
from .geometry import unit_normals
from .interrupts import deferred_interrupts
from .lights import build_emitter_sampler, choose_emitter, emitter_irradiance, sample_on_emitter, sampled_share
from .parallel import spread
from .rng import mix64, uniform
from .scene import Scene, load_scene
from .visibility import CASE_LIT, CASE_NAMES, CASE_UNKNOWN, N_CASES, ShadingPoints, ShadowQuery, make_estimator

SHADOW_EPSILON = 1e-6  # segments stop this fraction short of the emitter point
TARGET_SLOTS = 1 << 18  # shadow-ray slots per batch (bounds memory, keeps progress and Ctrl-C prompt)
POINTS_PER_BLOCK = 64  # shading points per parallel work item of the emitter sampling
N_COUNTS = 5  # per-pixel counts kept by `accumulate`
PIXELS_PER_BLOCK = 4  # pixels per parallel work item of `shade_exact`


@dataclass
class RenderResult:
    """`image` is (height, width, 3) float64 radiance; `aovs` holds per-pixel images such as test counts."""

    image: np.ndarray
    stats: dict
    aovs: dict = field(default_factory=dict)


@njit(cache=True, parallel=True, error_model="numpy")
def surface(geom, prim, b1, b2, dirs):
    """Shading points of the camera hits: emitted radiance seen directly, position, shading normal turned
    to the camera's side, and the material (-1 where nothing is reflected: a miss or a one-sided back face)."""
    triangles, vnormals, fnormals, tri_mat, tri_emit, refl, twosided, radiance = geom
    n = prim.shape[0]
    emitted = np.zeros((n, 3))
    pos = np.zeros((n, 3))
    nrm = np.zeros((n, 3))
    mat = np.full(n, -1, np.int32)
    for i in prange(n):
        tri = prim[i]
        if tri < 0:
            continue
        c1, c2 = b1[i], b2[i]
        c0 = 1.0 - c1 - c2
        sx = c0 * vnormals[tri, 0, 0] + c1 * vnormals[tri, 1, 0] + c2 * vnormals[tri, 2, 0]
        sy = c0 * vnormals[tri, 0, 1] + c1 * vnormals[tri, 1, 1] + c2 * vnormals[tri, 2, 1]
        sz = c0 * vnormals[tri, 0, 2] + c1 * vnormals[tri, 1, 2] + c2 * vnormals[tri, 2, 2]
        inv = 1.0 / math.sqrt(sx * sx + sy * sy + sz * sz)
        sx, sy, sz = sx * inv, sy * inv, sz * inv
        cos_i = -(sx * dirs[i, 0] + sy * dirs[i, 1] + sz * dirs[i, 2])
        em = tri_emit[tri]
        if em >= 0 and cos_i > 0.0:
            for k in range(3):
                emitted[i, k] = radiance[em, k]
        m = tri_mat[tri]
        if cos_i <= 0.0:
            if not twosided[m]:
                continue
            sx, sy, sz = -sx, -sy, -sz
        for k in range(3):
            pos[i, k] = c0 * triangles[tri, 0, k] + c1 * triangles[tri, 1, k] + c2 * triangles[tri, 2, k]
        nrm[i, 0], nrm[i, 1], nrm[i, 2] = sx, sy, sz
        mat[i] = m
    return emitted, pos, nrm, mat


@njit(cache=True, error_model="numpy", inline="always")
def _emitter_segment(slot, le, scale, rgb, u, table, triangles, fnormals, p, s, gn, eps, contrib, s_org, s_dir,
                     s_emit, active):
    """Fill shadow slot `slot` with a point sampled on emitter `le` (random numbers `u`) seen from shading
    point p (shading normal s, geometric normal gn): segment, contribution `rgb` x `scale` x cos cos / d^2
    (`scale` holds area / (pdf of the emitter x samples x pi)) and the active flag. No branches: the slot is
    written whether or not the emitter point faces p, and `active` says which."""
    lt, yx, yy, yz = sample_on_emitter(le, table, triangles, u[0], u[1], u[2])
    wx, wy, wz = yx - p[0], yy - p[1], yz - p[2]
    d2 = wx * wx + wy * wy + wz * wz
    # cosines times |w|: their signs need no square root, and cos_x cos_y / d2 = dot_x dot_y / d2^2
    dot_x = s[0] * wx + s[1] * wy + s[2] * wz
    dot_y = -(fnormals[lt, 0] * wx + fnormals[lt, 1] * wy + fnormals[lt, 2] * wz)
    g = dot_x * dot_y * scale / (d2 * d2)
    off = eps if gn[0] * wx + gn[1] * wy + gn[2] * wz > 0.0 else -eps
    ox, oy, oz = p[0] + off * gn[0], p[1] + off * gn[1], p[2] + off * gn[2]
    contrib[slot, 0], contrib[slot, 1], contrib[slot, 2] = rgb[0] * g, rgb[1] * g, rgb[2] * g
    s_org[slot, 0], s_org[slot, 1], s_org[slot, 2] = ox, oy, oz
    s_dir[slot, 0], s_dir[slot, 1], s_dir[slot, 2] = yx - ox, yy - oy, yz - oz
    s_emit[slot] = le
    active[slot] = (dot_x > 0.0) & (dot_y > 0.0)


@njit(cache=True, error_model="numpy", inline="always")
def _point_samples(i, triangles, fnormals, refl, radiance, pmf, area, table, prim, pos, nrm, mat, cases, keys,
                   n_shadow, base, s_org, s_dir, contrib, s_emit, active, dense):
    """Direct light at shading point `i`, per emitter as the visibility estimator's `cases` say:

    lit (case 1) emitters are integrated analytically (Lambert's polygon formula, no noise, no rays),
    shadowed (case 2) ones contribute nothing, and the others are sampled: `n_shadow` emitter samples (emitter
    by power among the sampled ones, point uniform by area) in slots base..base + n_shadow - 1. Fills, per
    slot, segment origin and direction, the unoccluded contribution (already divided by pdf and n_shadow), the
    emitter id and the active flag (the other outputs of an inactive slot are meaningless). With `dense` (a
    constant in each caller) only the active samples are kept, in slots base..base + m - 1 (a sample is
    written at base + m and kept by advancing m). Returns the analytic radiance and m (0 without `dense`).
    """
    offsets, etris = table[0], table[1]
    inv_pi = 1.0 / math.pi
    a0 = a1 = a2 = 0.0
    m = 0
    mi = mat[i]
    if mi < 0:
        for j in range(n_shadow):
            active[base + j] = False
        return a0, a1, a2, m
    tri = prim[i]
    p = (pos[i, 0], pos[i, 1], pos[i, 2])
    s = (nrm[i, 0], nrm[i, 1], nrm[i, 2])
    for e in range(pmf.shape[0]):
        if cases[i, e] == CASE_LIT:
            f = emitter_irradiance(e, offsets, etris, triangles, p[0], p[1], p[2], s[0], s[1], s[2]) * inv_pi
            a0 += refl[mi, 0] * radiance[e, 0] * f
            a1 += refl[mi, 1] * radiance[e, 1] * f
            a2 += refl[mi, 2] * radiance[e, 2] * f
    total, only = sampled_share(pmf, cases, i)
    if total <= 0.0:
        for j in range(n_shadow):
            active[base + j] = False
        return a0, a1, a2, m
    gn = (fnormals[tri, 0], fnormals[tri, 1], fnormals[tri, 2])
    eps = 1e-9 * (1.0 + max(abs(p[0]), abs(p[1]), abs(p[2])))
    key = keys[i]
    if only >= 0:  # a single emitter: no choice (its random dimension is simply not drawn)
        scale = area[only] * inv_pi / n_shadow
        rgb = (refl[mi, 0] * radiance[only, 0], refl[mi, 1] * radiance[only, 1], refl[mi, 2] * radiance[only, 2])
        for j in range(n_shadow):
            u = (uniform(key, 3 + 4 * j), uniform(key, 4 + 4 * j), uniform(key, 5 + 4 * j))
            slot = base + m if dense else base + j
            _emitter_segment(slot, only, scale, rgb, u, table, triangles, fnormals, p, s, gn, eps, contrib, s_org,
                             s_dir, s_emit, active)
            if dense:
                m += active[slot]
        return a0, a1, a2, m
    for j in range(n_shadow):
        le, p_e = choose_emitter(pmf, cases, i, total, uniform(key, 2 + 4 * j))
        rgb = (refl[mi, 0] * radiance[le, 0], refl[mi, 1] * radiance[le, 1], refl[mi, 2] * radiance[le, 2])
        u = (uniform(key, 3 + 4 * j), uniform(key, 4 + 4 * j), uniform(key, 5 + 4 * j))
        slot = base + m if dense else base + j
        _emitter_segment(slot, le, area[le] * inv_pi / (p_e * n_shadow), rgb, u, table, triangles, fnormals, p, s,
                         gn, eps, contrib, s_org, s_dir, s_emit, active)
        if dense:
            m += active[slot]
    return a0, a1, a2, m


@njit(cache=True, parallel=True, error_model="numpy")
def sample_lights(geom, es, prim, pos, nrm, mat, cases, keys, n_shadow, s_org, s_dir, contrib, s_emit, active):
    """`_point_samples` of every shading point, point i in slots i * n_shadow onwards; returns the analytic
    radiance per point."""
    triangles, vnormals, fnormals, tri_mat, tri_emit, refl, twosided, radiance = geom
    pmf, area, table = es
    n = prim.shape[0]
    analytic = np.zeros((n, 3))
    n_blocks = (n + POINTS_PER_BLOCK - 1) // POINTS_PER_BLOCK
    for it in prange(n_blocks):
        blk = spread(it, n_blocks)
        for i in range(blk * POINTS_PER_BLOCK, min(n, (blk + 1) * POINTS_PER_BLOCK)):
            analytic[i, 0], analytic[i, 1], analytic[i, 2] = _point_samples(
                i, triangles, fnormals, refl, radiance, pmf, area, table, prim, pos, nrm, mat, cases, keys,
                n_shadow, i * n_shadow, s_org, s_dir, contrib, s_emit, active, False)[:3]
    return analytic


@njit(cache=True, parallel=True, error_model="numpy")
def compact(active, s_org, s_dir, s_emit, keys, n_shadow, org, dirs, point, emit, rkey):
    """Gather the active shadow slots into the front of the dense arrays, in slot order.

    Returns `offsets`: `offsets[i]:offsets[i + 1]` is the dense range of camera sample i (so `accumulate`
    can walk it) and `offsets[-1]` the number of segments.
    """
    n = keys.shape[0]
    counts = np.zeros(n + 1, np.int64)
    for i in prange(n):
        c = 0
        for j in range(n_shadow):
            c += active[i * n_shadow + j]
        counts[i + 1] = c
    offsets = np.cumsum(counts)
    for i in prange(n):
        k = offsets[i]
        for j in range(n_shadow):
            slot = i * n_shadow + j
            if active[slot]:
                for c in range(3):
                    org[k, c] = s_org[slot, c]
                    dirs[k, c] = s_dir[slot, c]
                point[k] = i
                emit[k] = s_emit[slot]
                rkey[k] = mix64(keys[i] + np.uint64(j + 1))
                k += 1
    return offsets


@njit(cache=True, error_model="numpy", inline="always")
def _add_sample(img, m2, q, l0, l1, l2):
    """Add one camera sample's radiance to pixel q's sum and sum of squares."""
    img[q, 0] += l0
    img[q, 1] += l1
    img[q, 2] += l2
    m2[q, 0] += l0 * l0
    m2[q, 1] += l1 * l1
    m2[q, 2] += l2 * l2


@njit(cache=True, error_model="numpy", inline="always")
def _pixel_mean(img, m2, q, spp):
    """Turn pixel q's sums over its spp samples into means (box filter)."""
    for c in range(3):
        img[q, c] /= spp
        m2[q, c] /= spp


@njit(cache=True, parallel=True, error_model="numpy")
def accumulate(emitted, contrib, active, offsets, value, cam_node, cam_tri, sh_node, sh_tri, spp, n_shadow, n_pix):
    """Pixel means (box filter), per-pixel second moment of the sample radiance, and per-pixel counts:
    camera-ray triangle and node tests, shadow-ray triangle and node tests, negative visibility estimates."""
    img = np.zeros((n_pix, 3))
    m2 = np.zeros((n_pix, 3))
    counts = np.zeros((n_pix, N_COUNTS), np.int64)
    for q in prange(n_pix):
        for s in range(spp):
            i = q * spp + s
            counts[q, 0] += cam_tri[i]
            counts[q, 1] += cam_node[i]
            l0, l1, l2 = emitted[i, 0], emitted[i, 1], emitted[i, 2]
            k = offsets[i]
            for j in range(n_shadow):
                slot = i * n_shadow + j
                if active[slot]:
                    v = value[k]
                    l0 += contrib[slot, 0] * v
                    l1 += contrib[slot, 1] * v
                    l2 += contrib[slot, 2] * v
                    counts[q, 2] += sh_tri[k]
                    counts[q, 3] += sh_node[k]
                    counts[q, 4] += v < 0.0
                    k += 1
            _add_sample(img, m2, q, l0, l1, l2)
        _pixel_mean(img, m2, q, spp)
    return img, m2, counts


@njit(cache=True, parallel=True, error_model="numpy")
def shade_exact(geom, es, bvh, prim, pos, nrm, mat, cases, keys, emitted, cam_node, cam_tri, spp, n_shadow, n_pix):
    """`sample_lights`, exact visibility and `accumulate` fused, pixel by pixel: a shading point's segments are
    made, traced as packets and summed while they are in cache, with no batch-sized slot or segment arrays.
    The arithmetic and the packets are those of the staged path, so image and counts are identical.
    Returns `accumulate`'s outputs and the number of segments per pixel."""
    triangles, vnormals, fnormals, tri_mat, tri_emit, refl, twosided, radiance = geom
    pmf, area, table = es
    root2 = root_record(bvh[2])
    depth = bvh[5]
    img = np.zeros((n_pix, 3))
    m2 = np.zeros((n_pix, 3))
    counts = np.zeros((n_pix, N_COUNTS), np.int64)
    n_seg = np.zeros(n_pix, np.int64)
    n_blocks = (n_pix + PIXELS_PER_BLOCK - 1) // PIXELS_PER_BLOCK
    for it in prange(n_blocks):
        blk = spread(it, n_blocks)
        org, dirs, contrib = np.empty((n_shadow, 3)), np.empty((n_shadow, 3)), np.empty((n_shadow, 3))
        s_emit = np.empty(n_shadow, np.int32)
        active = np.empty(n_shadow, np.bool_)
        tmin = np.zeros(n_shadow)
        tmax = np.full(n_shadow, 1.0 - SHADOW_EPSILON)
        occ = np.empty(n_shadow, np.bool_)
        sh_node = np.empty(n_shadow, np.int32)
        sh_tri = np.empty(n_shadow, np.int32)
        work = packet_work(depth)
        for q in range(blk * PIXELS_PER_BLOCK, min(n_pix, (blk + 1) * PIXELS_PER_BLOCK)):
            for s in range(spp):
                i = q * spp + s
                counts[q, 0] += cam_tri[i]
                counts[q, 1] += cam_node[i]
                a0, a1, a2, m = _point_samples(i, triangles, fnormals, refl, radiance, pmf, area, table, prim, pos,
                                               nrm, mat, cases, keys, n_shadow, 0, org, dirs, contrib, s_emit, active,
                                               True)
                for lo in range(0, m, MAX_PACKET):
                    occluded_packet(bvh, root2, org, dirs, tmin, tmax, lo, min(MAX_PACKET, m - lo), work, occ,
                                    sh_node, sh_tri)
                l0, l1, l2 = emitted[i, 0] + a0, emitted[i, 1] + a1, emitted[i, 2] + a2
                for k in range(m):
                    v = 1.0 - np.float64(occ[k])
                    l0 += contrib[k, 0] * v
                    l1 += contrib[k, 1] * v
                    l2 += contrib[k, 2] * v
                    counts[q, 2] += sh_tri[k]
                    counts[q, 3] += sh_node[k]
                n_seg[q] += m
                _add_sample(img, m2, q, l0, l1, l2)
            _pixel_mean(img, m2, q, spp)
    return img, m2, counts, n_seg


class _Buffers:
    """Shadow-slot and segment arrays reused by every batch of a render: fresh multi-megabyte arrays per
    batch cost more in page faults than the kernels that fill them."""

    def __init__(self, n_slots):
        self.s_org, self.s_dir, self.contrib = (np.empty((n_slots, 3)) for _ in range(3))
        self.s_emit = np.empty(n_slots, np.int32)
        self.active = np.empty(n_slots, np.bool_)
        self.org, self.dirs = np.empty((n_slots, 3)), np.empty((n_slots, 3))
        self.point = np.empty(n_slots, np.int64)
        self.emit = np.empty(n_slots, np.int32)
        self.key = np.empty(n_slots, np.uint64)
        self.tmax = np.full(n_slots, 1.0 - SHADOW_EPSILON)

    def slots(self, m):
        return self.s_org[:m], self.s_dir[:m], self.contrib[:m], self.s_emit[:m], self.active[:m]

    def segments(self):
        return self.org, self.dirs, self.point, self.emit, self.key


def scene_arrays(scene):
    """The scene as the kernels take it (with unit face normals, computed once per render)."""
    return (scene.triangles, scene.vertex_normals, unit_normals(scene.triangles), scene.tri_material,
            scene.tri_emitter, scene.reflectance, scene.twosided, scene.emitter_radiance)


_warmed = set()


def _warm_up(estimator_name, options):
    """Compile (or load from numba's cache) every kernel of the pipeline on a tiny scene; returns seconds."""
    key = (estimator_name, repr(sorted(options.items())))
    if key in _warmed:
        return 0.0
    from .scene.builtin import quad_shadow

    t0 = time.perf_counter()
    _render_prepared(quad_shadow(res=4, spp=1, shadow_rays=2), make_estimator(estimator_name, **options),
                     progress=False, warmup=True)
    _warmed.add(key)
    return time.perf_counter() - t0


def _render_prepared(scene, estimator, progress, warmup=False):
    t_build = time.perf_counter()
    bvh = build_bvh(scene.triangles)
    emitters = build_emitter_sampler(scene)
    estimator.prepare(scene, bvh, emitters)
    t_render = time.perf_counter()
    build_seconds = t_render - t_build

    cam = camera_params(scene.camera)
    geom = scene_arrays(scene)
    es = emitters.arrays
    width, height = scene.camera.width, scene.camera.height
    n_pix_total = width * height
    spp, n_shadow = scene.spp, scene.shadow_rays
    per_batch = max(1, min(n_pix_total, TARGET_SLOTS // (spp * n_shadow)))
    # exact visibility samples, traces and sums in one kernel; other estimators get batches of segments
    fused = estimator.any_hit_only
    buffers = None if fused else _Buffers(per_batch * spp * n_shadow)
    image = np.zeros((n_pix_total, 3))
    moment2 = np.zeros((n_pix_total, 3))
    counts = np.zeros((n_pix_total, N_COUNTS), np.int64)
    totals = dict(shadow_rays=0, camera_hits=0, cases=[0] * N_CASES)
    case_counts = None
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_pix_total, unit="px", unit_scale=True, desc=f"render {scene.name}", leave=False)
    with deferred_interrupts() as check_interrupt:  # Ctrl-C stops between batches, not inside a kernel
        try:
            for p0 in range(0, n_pix_total, per_batch):
                check_interrupt()
                p1 = min(n_pix_total, p0 + per_batch)
                org, dirs, tmin, tmax, keys = camera_rays(cam, spp, scene.seed, p0, p1)
                prim, _, b1, b2, cam_node, cam_tri = nearest_hits(bvh, org, dirs, tmin, tmax)
                emitted, pos, nrm, mat = surface(geom, prim, b1, b2, dirs)
                points = ShadingPoints(pos, nrm, np.where(mat >= 0, prim, -1))
                cases = estimator.classify(points)
                if cases is None:
                    cases = np.full((len(prim), scene.n_emitters), CASE_UNKNOWN, np.int8)
                else:
                    if case_counts is None:
                        case_counts = np.zeros((n_pix_total, scene.n_emitters, N_CASES), np.int32)
                    shaded = mat >= 0
                    per_px = cases.reshape(p1 - p0, spp, -1)
                    for c in range(N_CASES):
                        case_counts[p0:p1, :, c] = (per_px == c).sum(axis=1)
                        totals["cases"][c] += int((cases[shaded] == c).sum())
                if fused:
                    img, m2, cnt, n_seg = shade_exact(geom, es, bvh.arrays, prim, pos, nrm, mat, cases, keys, emitted,
                                                      cam_node, cam_tri, spp, n_shadow, p1 - p0)
                    n_q = int(n_seg.sum())
                else:
                    s_org, s_dir, contrib, s_emit, active = buffers.slots(len(prim) * n_shadow)
                    emitted += sample_lights(geom, es, prim, pos, nrm, mat, cases, keys, n_shadow,
                                             s_org, s_dir, contrib, s_emit, active)
                    offsets = compact(active, s_org, s_dir, s_emit, keys, n_shadow, *buffers.segments())
                    n_q = int(offsets[-1])
                    query = ShadowQuery(origin=buffers.org[:n_q], direction=buffers.dirs[:n_q],
                                        tmax=buffers.tmax[:n_q], point=buffers.point[:n_q],
                                        emitter=buffers.emit[:n_q], key=buffers.key[:n_q], points=points)
                    res = estimator.evaluate(query)
                    img, m2, cnt = accumulate(emitted, contrib, active, offsets, res.value, cam_node, cam_tri,
                                              res.node_tests, res.triangle_tests, spp, n_shadow, p1 - p0)
                image[p0:p1], moment2[p0:p1], counts[p0:p1] = img, m2, cnt
                totals["shadow_rays"] += n_q
                totals["camera_hits"] += int((prim >= 0).sum())
                if bar is not None:
                    bar.update(p1 - p0)
        finally:
            if bar is not None:
                bar.close()
    render_seconds = time.perf_counter() - t_render
    totals.update(zip(("cam_tri", "cam_node", "sh_tri", "sh_node", "negative"), map(int, counts.sum(axis=0))))
    shape = (height, width)
    aovs = {
        "triangle_tests": (counts[:, 0] + counts[:, 2]).reshape(shape),
        "node_tests": (counts[:, 1] + counts[:, 3]).reshape(shape),
        "second_moment": moment2.reshape(shape + (3,)),
    }
    if case_counts is not None:
        aovs["cases"] = (case_counts / spp).reshape(shape + case_counts.shape[1:])
    return image.reshape(shape + (3,)), aovs, totals, bvh, build_seconds, render_seconds


def _case_stats(counts):
    """Shading point x emitter pairs per occlusion case, for estimators that classify."""
    total = max(1, sum(counts))
    return {name: {"count": c, "share": c / total} for name, c in zip(CASE_NAMES, counts)}


def render(scene, *, spp=None, shadow_rays=None, seed=None, resolution=None, visibility="exact",
           visibility_options=None, threads=None, progress=False, clamp_negative=False, **defaults):
    """Render `scene` (a `Scene`, a Mitsuba XML path or a built-in name) with direct illumination.

    `spp`, `shadow_rays` (emitter samples per camera sample), `seed` and `resolution` (width, height)
    override the scene's settings; extra keyword arguments are passed to `load_scene` as `<default>`
    overrides. `clamp_negative` sets negative pixels (from probabilistic visibility) to zero: biased, the
    image gets too bright on average; the stats report by how much. `visibility` names the estimator (see
    `probvis.visibility.ESTIMATORS`). Returns a `RenderResult` whose `.image` is linear RGB radiance and whose
    `.stats` is JSON-serialisable.
    """
    t_start = time.perf_counter()
    if not isinstance(scene, Scene):
        scene = load_scene(scene, **defaults)
    elif defaults:
        raise ProbvisError(f"scene parameters {sorted(defaults)} apply only when loading a scene from a file")
    load_seconds = time.perf_counter() - t_start
    w, h = resolution if resolution is not None else (None, None)
    scene = scene.with_settings(spp=spp, shadow_rays=shadow_rays, seed=seed, width=w, height=h)
    if threads is not None:
        if not 1 <= threads <= numba.config.NUMBA_NUM_THREADS:
            raise ProbvisError(f"threads must be between 1 and {numba.config.NUMBA_NUM_THREADS}, got {threads}")
        numba.set_num_threads(threads)
    options = dict(visibility_options or {})
    estimator = make_estimator(visibility, **options)
    compile_seconds = _warm_up(estimator.name, options)
    image, aovs, tot, bvh, build_s, render_s = _render_prepared(scene, estimator, progress)
    negative = image < 0
    clamp = {"negative_pixel_share": float(negative.any(axis=-1).mean()),
             "negative_value_share": float(negative.mean()), "clamped": bool(clamp_negative)}
    if clamp_negative:
        clamped = np.maximum(image, 0.0)
        clamp["mean_bias"] = [float(x) for x in (clamped - image).reshape(-1, 3).mean(axis=0)]
        image = clamped
    total = time.perf_counter() - t_start
    cam = scene.camera
    n_cam = cam.width * cam.height * scene.spp
    stats = {
        "probvis_version": __version__,
        "scene": scene.name,
        "source": scene.source,
        "width": cam.width,
        "height": cam.height,
        "spp": scene.spp,
        "shadow_rays_per_sample": scene.shadow_rays,
        "seed": scene.seed,
        "threads": numba.get_num_threads(),
        "visibility": {"name": estimator.name, **estimator.options()},
        "seconds": {"total": total, "load": load_seconds, "compile": compile_seconds, "build": build_s,
                    "render": render_s},
        "triangles": scene.n_triangles,
        "dropped_degenerate_triangles": scene.dropped_degenerate,
        "emitters": scene.n_emitters,
        "camera_rays": n_cam,
        "camera_hits": tot["camera_hits"],
        "shadow_rays": tot["shadow_rays"],
        "negative_estimates": tot["negative"],
        "negative_estimate_share": tot["negative"] / max(1, tot["shadow_rays"]),
        "negative_pixels": clamp,
        "cases": _case_stats(tot["cases"]) if "cases" in aovs else None,
        "intersection_tests": {
            "triangle": tot["cam_tri"] + tot["sh_tri"],
            "node": tot["cam_node"] + tot["sh_node"],
            "camera": {"triangle": tot["cam_tri"], "node": tot["cam_node"]},
            "shadow": {"triangle": tot["sh_tri"], "node": tot["sh_node"],
                       "triangle_per_ray": tot["sh_tri"] / max(1, tot["shadow_rays"]),
                       "node_per_ray": tot["sh_node"] / max(1, tot["shadow_rays"])},
        },
        "shadow_rays_per_second": tot["shadow_rays"] / render_s if render_s > 0 else None,
        "image_mean": [float(x) for x in image.reshape(-1, 3).mean(axis=0)],
        "bvh": bvh.stats(),
        "estimator": estimator.stats(),
    }
    return RenderResult(image, stats, aovs)
