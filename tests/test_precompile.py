import os
import signal
import subprocess
import sys
import time

from numba import types

from probvis import integrator, precompile
from probvis.visibility import estimator_class


def test_discovery_types_each_kernel_as_its_dispatcher_does():
    """The plain-Python run finds the warm-up's kernels with the argument types Numba gives them: each is one
    of the signatures the same warm-up, compiled, loads; the fused kernel, the largest, comes first."""
    cls = estimator_class("exact")
    jobs = precompile._discover([(integrator.warm_up_render, (cls, {}))])
    integrator.warm_up_render(cls, {})
    assert len(jobs) >= 10
    for module, name, argtypes, _ in jobs:
        kernel = sys.modules[module]
        for part in name.split("."):
            kernel = getattr(kernel, part)
        assert argtypes in kernel.signatures, (module, name)
    assert (jobs[0][0], jobs[0][1]) == ("probvis.fused_exact", "_shade_blocks")
    assert [j[3] for j in jobs] == sorted((j[3] for j in jobs), reverse=True)


def test_discovery_follows_the_options_that_choose_kernels():
    """The probabilistic estimator's warm-up groups lists: its kernels include the grouping, exact's do not."""
    def names(visibility, options):
        return {j[1] for j in precompile._discover([(integrator.warm_up_render, (estimator_class(visibility),
                                                                                  options))])}

    assert {"_group_pairs", "_classify_chunks"} <= names("probvis", {"verify": "off"})
    assert "_group_pairs" not in names("exact", {})


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
    monkeypatch.setattr(integrator, "render_pass", lambda scene, settings, estimator: seen.append(estimator))
    integrator.warm_up_render(estimator_class("occlusion-map"), {"photons": 10**6, "neighbours": 7})
    assert (seen[0].params.photons, seen[0].params.neighbours) == (4096, 7)


def test_the_first_run_s_progress_bar_starts():
    """On a terminal a cold first run shows a bar over Numba's compile events (it failed Numba's check that a
    listener is an `event.Listener`) and the workers' kernels."""
    with integrator._CompileProgress() as shown:
        shown.bar.reset(total=2)
        shown.bar.update(1)
        assert shown.bar.n == 1
