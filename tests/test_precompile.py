import functools
import os
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import pytest
from numba import types

import probvis
from probvis import integrator, precompile, warm_up
from probvis.scene import builtin
from probvis.visibility import estimator_class


def test_discovery_types_each_kernel_as_its_dispatcher_does():
    """The plain-Python run finds the warm-up's kernels with the argument types Numba gives them: each is one
    of the signatures the same warm-up, compiled, loads; the fused kernel and the shells' kernel (exact's warm-up
    for any scene), the largest, come first."""
    cls = estimator_class("exact")
    jobs = precompile._discover([(integrator.warm_up_render, (cls, {}))])
    integrator.warm_up_render(cls, {})
    assert len(jobs) >= 10
    for module, name, argtypes, _ in jobs:
        kernel = sys.modules[module]
        for part in name.split("."):
            kernel = getattr(kernel, part)
        assert argtypes in kernel.signatures, (module, name)
    assert {(j[0], j[1]) for j in jobs[:2]} == {("probvis.fused_exact", "_shade_blocks"),
                                                 ("probvis.visibility.proxy_kernel", "shade_proxy")}
    assert [j[3] for j in jobs] == sorted((j[3] for j in jobs), reverse=True)


def test_discovery_follows_the_options_that_choose_kernels():
    """The probabilistic estimator's warm-up groups lists: its kernels include the grouping, exact's do not."""
    def names(visibility, options):
        return {j[1] for j in precompile._discover([(integrator.warm_up_render, (estimator_class(visibility),
                                                                                  options))])}

    assert {"_group_pairs", "_classify_chunks"} <= names("probvis", {"verify": "off"})
    assert "_group_pairs" not in names("exact", {})


ONE_SIGNATURE_EACH = """
import gc, sys, warnings
import numba
import probvis
warnings.simplefilter("ignore")
for visibility in ("exact", "occlusion-map", "cache-cv"):
    for scene in sys.argv[1:]:
        probvis.render(scene, spp=1, shadow_rays=2, visibility=visibility, resolution=(4, 4))
kernels = [o for o in gc.get_objects() if isinstance(o, numba.core.registry.CPUDispatcher)]
print(len(kernels), [o.py_func.__qualname__ for o in kernels if len(o.signatures) > 1])
"""


def test_scenes_unlike_the_warm_up_s_give_its_kernels_the_same_types(tmp_path):
    """A kernel called with other argument types compiles again, for up to a minute: an environment map's
    rotation (a transposed view once), a tent filter, a cache whose pilot met no emitter samples (an empty
    count, typed int64 once) and the built-in scenes give each kernel one signature."""
    from probvis.io.image import write_exr
    from tests.conftest import sensor, write_scene
    from tests.test_environment import CAMERA, CONSTANT, ENVMAP, GROUND, sky

    write_exr(tmp_path / "sky.exr", sky())
    spp = '<default name="spp" value="1"/>'
    env = write_scene(tmp_path / "env.xml", sensor(**CAMERA) + GROUND + ENVMAP, spp)
    tent = write_scene(tmp_path / "tent.xml", sensor(**CAMERA).replace('"box"', '"tent"') + GROUND + CONSTANT, spp)
    out = subprocess.run([sys.executable, "-c", ONE_SIGNATURE_EACH, "quad-shadow", str(env), str(tent),
                          "cornell-box"], capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr
    count, several = out.stdout.split(" ", 1)
    assert int(count) >= 20 and several.strip() == "[]", out.stdout


def test_the_children_do_not_import_from_the_working_folder(tmp_path, monkeypatch):
    """A `numba.py` in the folder the render runs in is not what the children import (they run with -P)."""
    (tmp_path / "numba.py").write_text(f"open({str(tmp_path / 'imported')!r}, 'w').close()\n")
    monkeypatch.chdir(tmp_path)
    assert precompile._discover([(integrator.warm_up_render, (estimator_class("exact"), {}))])
    assert not (tmp_path / "imported").exists()


def test_a_class_the_child_cannot_import_leaves_the_warm_up_to_compile():
    class Local(estimator_class("exact")):
        pass

    assert precompile.fill_cache([(integrator.warm_up_render, (Local, {}))], 2) == 0


def test_workers_fill_an_empty_cache(tmp_path, monkeypatch):
    """A worker compiles a job into Numba's cache (here an empty NUMBA_CACHE_DIR); a job that cannot compile
    is counted out, not raised."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    ok = ("probvis.geometry", "unit_normals", (types.Array(types.float64, 3, "C"),), 1)
    bad = ("probvis.geometry", "no_such_kernel", (types.float64,), 1)
    assert precompile._compile([ok, bad], 2, None) == 1
    assert list(tmp_path.rglob("geometry.unit_normals-*.nbi"))


def test_an_interrupt_ends_the_workers(tmp_path):
    """SIGTERM while the workers compile a first run's kernels: the render exits 130 at once and takes its child
    processes with it."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    proc = subprocess.Popen([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=8", "--threads",
                             "2", "-o", str(tmp_path / "q.exr")], env=env, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not _children(proc.pid, "compile"):
        time.sleep(0.2)
    workers = _children(proc.pid, "precompile")
    assert workers, "no compile workers started"
    proc.send_signal(signal.SIGTERM)
    t0 = time.monotonic()
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 130 and time.monotonic() - t0 < 10
    assert err.decode().strip().splitlines()[-1].startswith("probvis:")
    assert "Traceback" not in err.decode()
    assert not any(os.path.exists(f"/proc/{pid}") for pid in workers) and not (tmp_path / "q.exr").exists()


def _children(pid, word):
    """Processes whose parent is `pid` and whose command line holds `word`."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
                with open(f"/proc/{entry}/cmdline", "rb") as f:
                    cmd = f.read().replace(b"\0", b" ").decode()
            except OSError:
                continue
            if ppid == pid and word in cmd:
                found.append(int(entry))
    return found


def test_the_warm_up_uses_the_sizes_options_declare(monkeypatch):
    """The occlusion map's photons are a size, not a choice of kernels: the warm-up shoots its declared few,
    whatever the render asks for."""
    seen = []
    done = SimpleNamespace(bvh=SimpleNamespace(stats=dict))
    monkeypatch.setattr(integrator, "render_pass", lambda scene, settings, estimator: seen.append(estimator) or done)
    integrator.warm_up_render(estimator_class("occlusion-map"), {"photons": 10**6, "neighbours": 7})
    assert (seen[0].params.photons, seen[0].params.neighbours) == (4096, 7)


def test_the_first_run_s_progress_bar_starts():
    """On a terminal a cold first run shows a bar over Numba's compile events (it failed Numba's check that a
    listener is an `event.Listener`) and the workers' kernels."""
    with warm_up.CompileProgress() as shown:
        shown.bar.reset(total=2)
        shown.bar.update(1)
        assert shown.bar.n == 1


@pytest.mark.parametrize("visibility, options", [
    ("occlusion-map", {"radius": 50.0}), ("occlusion-map", {"radius": 1e-10}), ("probvis", {"radius": 50.0}),
    ("proxy", {"triangles": 1000}), ("proxy", {"triangles": 1000, "min_triangles": 4}),
])
def test_the_warm_up_leaves_out_what_fits_only_the_real_scene(visibility, options):
    """A radius for a 100 m scene, or one for a 3 mm one, and a proxy size below a real scene's heavy mesh are
    the user's: the warm-up's own scene (a diagonal of 11.5) was refused them before the render began."""
    integrator.warm_up_render(estimator_class(visibility), options)


def test_the_warm_up_runs_every_kernel_a_render_of_heavy_meshes_runs(tmp_path, monkeypatch):
    """What a first render's kernels are compiled by is the warm-up: a render of scenes with and without heavy
    meshes (shells, decimated and volumetric proxies, the fused kernel) calls no kernel the warm-up did not
    for that scene (a first proxy render compiled for 40 s inside its prepare and render). Kernels are found as
    the parallel compile finds them; an empty disk cache so that every build runs."""
    monkeypatch.setenv("PROBVIS_CACHE_DIR", str(tmp_path))
    scan = builtin.heavy_scan(res=8, spp=1, shadow_rays=4, subdivisions=3)
    leaves = builtin.canopy(res=8, spp=1, shadow_rays=4, leaves=1500, leaf_size=0.02)
    city = builtin.box_city(res=8, spp=1, shadow_rays=4, blocks=6)

    def kernels(call):
        return {(module, name, argtypes) for module, name, argtypes, _ in precompile._discover([call])}

    warmed = {}  # by the warm-up's runs: one discovery for the scenes that warm up alike
    for visibility, options, scenes in [("exact", {}, (scan, city)), ("proxy", {}, (scan, city)),
                                         ("proxy", {"q": "0.5"}, (scan, leaves))]:
        options, cls = {**options, "min_triangles": 1000}, estimator_class(visibility)
        for scene in scenes:
            largest = warm_up.largest_mesh(scene)
            key = (visibility, repr(cls.warm_ups(options, largest)))
            if key not in warmed:
                warmed[key] = kernels((integrator.warm_up_render, (cls, options, largest)))
            ran = kernels((functools.partial(probvis.render, scene, visibility=visibility,
                                             visibility_options=options), ()))
            missing = ran - warmed[key]
            assert ran and not missing, (visibility, options, scene.name, sorted(k[:2] for k in missing))


def test_a_scene_without_heavy_meshes_warms_up_no_heavy_mesh_kernels():
    """A first `exact` render of the Cornell box waits for no shell or proxy kernel: the warm-up renders heavy
    meshes only for a scene that has one (by the estimator's min_triangles), and it is keyed by that."""
    small = warm_up.largest_mesh(builtin.cornell_box(res=4))
    for name in ("exact", "proxy"):
        cls = estimator_class(name)
        assert [run["min_triangles"] for run in cls.warm_ups({}, small)] == [cls().params.min_triangles]
        assert len(cls.warm_ups({}, 10**6)) >= 2 and len(cls.warm_ups({"min_triangles": small}, small)) >= 2
    assert len(estimator_class("exact").warm_ups({"shells": "off"}, 10**6)) == 1


def test_scenes_that_warm_up_alike_share_one_warm_up(monkeypatch):
    """The warm-up was keyed by the scene's largest mesh: every scene of another size rendered the warm-up again
    (and counted its kernels in the memory estimate) though it would run the same renders."""
    monkeypatch.setattr(warm_up, "_warmed", set())
    ran = []
    cls = estimator_class("exact")
    for largest in (12, 500, 10 ** 6, 2 * 10 ** 6):  # two below min_triangles, two above
        warm_up.ensure_warm(lambda *args: ran.append(args[2]), cls, {}, largest, False)
    assert ran == [12, 10 ** 6]
    assert warm_up.is_warm(cls, {}, 800) and not warm_up.is_warm(cls, {"shells": "off"}, 800)
