from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


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
