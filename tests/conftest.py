import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import probvis

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
WARM_UP = """
import sys
import probvis
from probvis.scene.builtin import quad_shadow
for visibility in sys.argv[1:]:
    probvis.render(quad_shadow(res=4), spp=1, shadow_rays=2, visibility=visibility)
"""
WARM_UP_GROUPS = (("occlusion-map", "probvis"), ("exact", "nee++", "cache-cv", "ratio"))  # about even


def pytest_configure(config):
    """With the tests in parallel processes (pytest-xdist), fill Numba's on-disk cache first, the warm-ups'
    kernels compiled in one process per core (`precompile`), then the render paths warmed up split between two
    processes: otherwise every test process compiles the same kernels at once, for minutes on a fresh clone.
    With a warm cache this takes seconds."""
    if hasattr(config, "workerinput") or not config.pluginmanager.hasplugin("xdist"):
        return
    if config.getoption("numprocesses", None) in (None, 0):
        return
    from probvis import integrator, precompile, warm_up
    from probvis.visibility import estimator_class

    if warm_up.cold_cache():
        calls = [(integrator.warm_up_render, (estimator_class(v), {})) for group in WARM_UP_GROUPS for v in group]
        precompile.fill_cache(calls, min(4, os.cpu_count() or 1))  # what it misses, the warm-ups compile
    procs = [subprocess.Popen([sys.executable, "-c", WARM_UP, *group]) for group in WARM_UP_GROUPS]
    for p in procs:
        p.wait()


def relmse(x, ref):
    """The shared references' error metric: mean of (x - ref)^2 / (ref^2 + 0.01) over pixels and channels."""
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


@pytest.fixture
def shared():
    if not (SHARED / "scenes").is_dir():
        pytest.skip("../shared is not present")
    return SHARED


def write_scene(path, body, defaults=""):
    """A Mitsuba 3 XML scene file around `body`."""
    Path(path).write_text(f'<?xml version="1.0"?>\n<scene version="3.0.0">\n{defaults}\n{body}\n</scene>\n')
    return path


SENSOR = """
<sensor type="perspective">
    <float name="fov" value="{fov}"/>
    <transform name="to_world"><lookat origin="{origin}" target="{target}" up="{up}"/></transform>
    <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{w}"/><integer name="height" value="{h}"/>
        <rfilter type="box"/></film>
</sensor>
<integrator type="direct"><integer name="emitter_samples" value="{sr}"/><integer name="bsdf_samples" value="0"/></integrator>
"""


def sensor(origin="0, 0, 4", target="0, 0, 0", up="0, 1, 0", fov=40, spp=4, sr=4, w=16, h=16):
    return SENSOR.format(origin=origin, target=target, up=up, fov=fov, spp=spp, sr=sr, w=w, h=h)


def mitsuba_image(path, spp, seed):
    """Mitsuba 3's (scalar_rgb) render of a scene file; skips the test without Mitsuba."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    return np.array(mi.render(mi.load_file(str(path), spp=spp), seed=seed, spp=spp), dtype=np.float64)


def assert_matches_mitsuba(path, shadow_rays=4, reference_spp=512):
    """Our render at 16 spp has no more error against Mitsuba's converged image than Mitsuba's own renders at
    the same settings (1.5x their mean), and the same image mean within 1%."""
    ref = mitsuba_image(path, reference_spp, 100)
    noise = np.mean([relmse(mitsuba_image(path, 16, s), ref) for s in (1, 2)])
    ours = probvis.render(path, spp=16, shadow_rays=shadow_rays, seed=1).image
    assert relmse(ours, ref) <= 1.5 * noise
    np.testing.assert_allclose(ours.reshape(-1, 3).mean(0), ref.reshape(-1, 3).mean(0), rtol=0.01)


def without_permission_override(cmd):
    """`cmd` (a list) run so that file permissions apply: as is for a normal user; as root, under `setpriv`
    without the capabilities that bypass them. Skips the test where root cannot drop them."""
    import shutil

    if os.geteuid() != 0:
        return cmd
    if shutil.which("setpriv") is None:
        pytest.skip("root without setpriv reads any file")
    probe = subprocess.run(["setpriv", "--bounding-set", "-dac_override,-dac_read_search,-fowner", "--", "true"],
                           capture_output=True, text=True)
    if probe.returncode != 0:
        pytest.skip(f"setpriv cannot drop capabilities here: {probe.stderr.strip()}")
    return ["setpriv", "--bounding-set", "-dac_override,-dac_read_search,-fowner", "--"] + cmd
