"""Error and efficiency measures against closed forms."""
import math

import numpy as np
import pytest

from probvis.experiments import metrics


def test_relmse_and_rmse_closed_form():
    ref = np.full((2, 2, 3), 0.3)
    img = ref + 0.1
    assert metrics.relmse(img, ref) == pytest.approx(0.01 / (0.09 + 0.01))
    assert metrics.rmse(img, ref) == pytest.approx(0.1)


def test_efficiency():
    assert metrics.efficiency(0.5, 4.0) == pytest.approx(0.5)
    assert metrics.efficiency(0.0, 4.0) == math.inf
    assert metrics.efficiency(None, 1.0) is None


def test_time_to_target_is_exact_on_a_power_law():
    costs = [1.0, 4.0, 16.0, 64.0]
    errors = [0.3 / c for c in costs]  # error ~ 1/cost: a straight line in log-log
    assert metrics.time_to_target(costs, errors, 0.3 / 10.0) == pytest.approx(10.0)
    assert metrics.time_to_target(costs, errors, 1.0) == 1.0
    assert metrics.time_to_target(costs, errors, 1e-4) is None
    assert metrics.time_to_target(costs[::-1], errors[::-1], 0.3 / 32.0) == pytest.approx(32.0)


def test_report_numbers_print_counts_and_their_seed_means_in_full():
    from probvis.experiments.report import _fmt

    assert _fmt(11592345.67) == "11,592,346"  # a mean test count over seeds, not 1.16e+07
    assert _fmt(727769) == "727,769"
    assert _fmt(0.09551) == "0.0955" and _fmt(97.24) == "97.2"
    assert _fmt(math.inf) == "∞" and _fmt(None) == "–"


def test_block_bias_ratio_tells_noise_from_bias():
    """Two seeds of an unbiased image: about 1; a 10% offset on a smooth reference: far more."""
    import numpy as np

    rng = np.random.default_rng(3)
    ref = np.broadcast_to(np.linspace(0.2, 1.0, 64)[None, :, None], (64, 64, 3))
    a, b = (ref * (1 + 0.2 * rng.standard_normal(ref.shape)) for _ in range(2))
    assert 0.5 < metrics.block_bias_ratio(a, b, ref) < 2
    assert metrics.block_bias_ratio(a * 1.1, b * 1.1, ref) > 15
    # the reference's own noise counts where a method has none (an analytically lit region)
    assert metrics.block_bias_ratio(ref, ref, ref + 0.001, reference_noise=0.01) < 1


def test_render_seconds_leave_out_loading_and_the_bvh():
    """`seconds = "render"` counts the render and the estimator's preparation only."""
    from types import SimpleNamespace

    import numpy as np

    from probvis.experiments.config import MethodSpec
    from probvis.experiments.results import cell_row

    stats = {"seconds": {"total": 10.0, "compile": 1.0, "load": 2.0, "bvh": 3.0, "prepare": 0.5, "render": 3.5,
                         "repeats": [9.0, 8.5], "repeats_render": [3.75, 3.5]},
             "intersection_tests": {"shadow": {"triangle": 10, "node": 20}, "triangle": 11, "node": 22},
             "camera_rays": 1, "shadow_rays": 1, "negative_pixels": {"negative_pixel_share": 0.0},
             "negative_estimate_share": 0.0, "bvh": {"bytes": 1000}}
    render = SimpleNamespace(stats=stats, image=np.ones((2, 2, 3)))
    task = SimpleNamespace(scene="s", method=MethodSpec("e", "exact"), shadow_rays=1, spp=1, seed=0)
    assert cell_row(task, render, np.ones((2, 2, 3)), "e")["seconds"] == 8.5
    assert cell_row(task, render, np.ones((2, 2, 3)), "e", "render")["seconds"] == 3.5
    for key in ("repeats", "repeats_render"):  # one render, without the repeats' lists
        del stats["seconds"][key]
    assert cell_row(task, render, np.ones((2, 2, 3)), "e")["seconds"] == 9.0
    assert cell_row(task, render, np.ones((2, 2, 3)), "e", "render")["seconds"] == 4.0


def test_tests_split_by_geometry_add_up_to_the_shadow_totals():
    """Proxy tests come from the estimator's split, the scene's are the rest of the totals, shell and extinction-grid voxels apart;
    an estimator without a split tested the scene only."""
    from probvis.experiments.results import tests_by_geometry

    stats = {"intersection_tests": {"shadow": {"triangle": 100, "node": 400}},
             "estimator": {"tests": {"proxy": {"node": 150, "triangle": 30, "voxel": 90},
                                     "scene": {"node": 0, "triangle": 0}, "shells": {"voxel": 70}}}}
    assert tests_by_geometry(stats) == {"scene": {"node": 250, "triangle": 70}, "proxy": {"node": 150, "triangle": 30},
                                        "shell_voxels": 70, "volume_voxels": 90}
    stats["estimator"] = {"seconds": {}}
    assert tests_by_geometry(stats) == {"scene": {"node": 400, "triangle": 100}, "proxy": {"node": 0, "triangle": 0},
                                        "shell_voxels": 0, "volume_voxels": 0}
