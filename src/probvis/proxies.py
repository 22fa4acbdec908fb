"""Geometry proxies: simplified stand-ins of a scene's heavy meshes, for visibility estimators that test less
geometry and correct stochastically (Billen, Lagae and Dutré, "Probabilistic Visibility Evaluation using
Geometry Proxies", EGSR 2014).

Each shape of at least `min_triangles` triangles is welded into an indexed mesh and decimated by quadric error
(the `fast-simplification` package: Garland-Heckbert quadrics, the same fast algorithm as pyfqmr, maintained
by the PyVista project) to `ratio` of its triangles or to `triangles`; smaller shapes enter the proxy
geometry unchanged. A heavy shape made mostly of separate small parts (foliage: nothing for decimation to
collapse) is prefiltered into an extinction grid instead (`transmittance`), with `kind="auto"`; `kind`
"mesh" or "volume" forces one for every heavy shape. A shape the decimator cannot handle keeps its own
triangles, with a warning: a proxy is only ever an approximation that the estimator corrects, so a missing
one costs speed, never correctness. Proxies are cached on disk (`disk_cache`), keyed by a hash of the
shape's triangles and the decimation target.
"""
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .disk_cache import content_key, load_or_build
from .transmittance import ExtinctionGrid, extinction_grid, mostly_small_parts

MIN_TRIANGLES = 100_000  # shapes below this are cheap already (their BVH stays in cache): kept unchanged
CACHE_VERSION = 2
KINDS = ("auto", "mesh", "volume")


@dataclass
class ProxyGeometry:
    """The proxy triangles (decimated heavy shapes plus the other shapes as they are), the extinction grid of
    the heavy shapes prefiltered as volumes, and a report per heavy shape."""

    triangles: np.ndarray  # (m, 3, 3)
    shapes: list = field(default_factory=list)  # dicts: name, kind, triangles, proxy_triangles, seconds, cached
    volume: ExtinctionGrid = field(default_factory=ExtinctionGrid.none)
    seconds: float = 0.0
    # how far a proxy may stray from its mesh (the largest mean edge length of a decimated shape's proxy): a
    # segment starting on a heavy mesh ignores proxy geometry this close to its origin, where the proxy would
    # otherwise shadow the mesh's own lit surface
    clearance: float = 0.0

    @property
    def n_decimated(self):
        return sum(1 for s in self.shapes if s["kind"] == "mesh" and s["proxy_triangles"] is not None)

    @property
    def n_volumes(self):
        return sum(1 for s in self.shapes if s["kind"] == "volume")


def target_count(n, ratio=None, triangles=None):
    """Triangles a shape of n triangles is decimated to: `triangles` if given, else round(ratio n), at least 4."""
    return max(4, int(triangles) if triangles is not None else int(round(ratio * n)))


def weld(tris):
    """An indexed mesh (vertices, faces) of a triangle soup, equal corners merged."""
    flat = np.ascontiguousarray(tris.reshape(-1, 3))
    keys = flat.view(np.dtype((np.void, flat.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    return flat[first], inverse.reshape(-1, 3).astype(np.int64)


def decimate(tris, target):
    """The proxy triangles of one shape (a triangle soup) decimated to about `target` triangles, or None and why
    when the decimator cannot produce a valid, smaller mesh."""
    import fast_simplification

    vertices, faces = weld(tris)
    if len(faces) <= target:
        return None, f"it has no more than {target} triangles"
    try:
        pv, pf = fast_simplification.simplify(vertices.astype(np.float64), faces.astype(np.int32),
                                              target_reduction=1.0 - target / len(faces))
    except Exception as exc:  # the library raises various types on meshes it rejects
        return None, f"the decimator failed ({type(exc).__name__}: {exc})"
    pv, pf = np.asarray(pv, dtype=np.float64), np.asarray(pf, dtype=np.int64)
    if (pf.ndim != 2 or len(pf) == 0 or len(pf) >= len(faces) or pf.min() < 0 or pf.max() >= len(pv)
            or not np.all(np.isfinite(pv))):
        return None, "the decimator returned no valid smaller mesh"
    return np.ascontiguousarray(pv[pf]), None


def _cached_decimate(tris, digest, target, use_cache):
    """`decimate` through the on-disk cache (`digest`: the triangles' content key): (triangles or None, why not,
    whether it came from the cache)."""
    why = []

    def build():
        out, reason = decimate(tris, target)
        why.append(reason)
        return None if out is None else {"triangles": out}

    key = content_key(f"proxy v{CACHE_VERSION} target {target} of {digest}")
    out, cached = load_or_build("proxies", key, build, use_cache, {"triangles": ((None, 3, 3), "f")})
    return (None if out is None else out["triangles"]), (why[0] if why else None), cached


def _cached_small_parts(tris, digest, use_cache):
    """`transmittance.mostly_small_parts` of a triangle soup (`digest`: its content key), welded (seconds for a
    million triangles) once."""
    def build():
        return {"vertices": np.array(len(weld(tris)[0]))}

    out, _ = load_or_build("parts", content_key(f"welded vertices v{CACHE_VERSION} of {digest}"), build, use_cache,
                           {"vertices": ((), "iu")})
    return mostly_small_parts(int(out["vertices"]), len(tris))


def build_proxies(scene, ratio=0.01, triangles=None, min_triangles=MIN_TRIANGLES, use_cache=True,
                  kind="auto", only=None):
    """`ProxyGeometry` of a scene: shapes of at least `min_triangles` decimated to `ratio` of their triangles
    (or to `triangles` each) or, by `kind`, prefiltered into the extinction grid; the others kept. `only`: the
    first triangles of the shapes that may get proxies (None: all)."""
    t0 = time.perf_counter()
    parts, volumes, report, clearance = [], [], [], 0.0
    for shape in scene.shapes:
        tris = scene.triangles[shape.first_triangle:shape.first_triangle + shape.n_triangles]
        if (shape.n_triangles < min_triangles or shape.emitter >= 0
                or only is not None and shape.first_triangle not in only):
            parts.append(tris)
            continue
        t = time.perf_counter()
        digest = content_key("triangles", tris)  # hashed once: both cache keys derive from it
        if kind == "volume" or (kind == "auto" and _cached_small_parts(tris, digest, use_cache)):
            volumes.append(tris)
            report.append({"name": shape.name, "kind": "volume", "triangles": shape.n_triangles,
                           "proxy_triangles": None, "seconds": time.perf_counter() - t, "cached": None})
            continue
        target = target_count(shape.n_triangles, ratio, triangles)
        proxy, why, cached = _cached_decimate(tris, digest, target, use_cache)
        if proxy is None:
            warnings.warn(f"proxies: shape '{shape.name}' keeps its {shape.n_triangles} triangles: {why}",
                          stacklevel=2)
        parts.append(tris if proxy is None else proxy)
        if proxy is not None:
            edges = np.linalg.norm(proxy - np.roll(proxy, 1, axis=1), axis=2)
            clearance = max(clearance, float(edges.mean()))
        report.append({"name": shape.name, "kind": "mesh", "triangles": shape.n_triangles,
                       "proxy_triangles": None if proxy is None else len(proxy),
                       "seconds": time.perf_counter() - t, "cached": cached})
    if not report:  # no shape to simplify: the scene's own triangles, not a copy of them
        return ProxyGeometry(scene.triangles, report, ExtinctionGrid.none(), time.perf_counter() - t0, clearance)
    volume = extinction_grid(volumes) if volumes else ExtinctionGrid.none()
    if not parts:  # every shape prefiltered: a BVH needs a triangle, a degenerate one that nothing hits
        parts.append(np.repeat(volumes[0][:1, :1], 3, axis=1))
    return ProxyGeometry(np.ascontiguousarray(np.concatenate(parts)), report, volume, time.perf_counter() - t0,
                         clearance)
