"""Bad input, as a user (or an adversary) gives it: each case runs `probvis` as a subprocess under resource
limits and must end with one line `probvis: error: ...` naming the problem, a non-zero exit, no traceback and
no output file, in bounded time and memory."""
import io
import os
import re
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import probvis
from probvis.cli import main
from tests.conftest import sensor, write_scene

MEMORY_LIMIT = 6 << 30  # address space of each case's process: far below what the bad settings would need
TIME_LIMIT = 300


def _limits():
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def run(args, cwd):
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "probvis.cli", *map(str, args)], capture_output=True, text=True,
                       cwd=cwd, timeout=TIME_LIMIT, preexec_fn=_limits)
    return r, time.perf_counter() - t0


def mesh_scene(tmp_path, mesh_bytes, name="m.obj"):
    (tmp_path / name).write_bytes(mesh_bytes)
    return write_scene(tmp_path / "mesh.xml", sensor() + f"""
        <shape type="obj"><string name="filename" value="{name}"/></shape>
        <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="180"/><translate z="1"/></transform>
            <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""")


CASES = [
    (["tables", "--power", "5000"], "argument --power: must be at most 64"),
    (["render", "quad-shadow", "--visibility", "probvis", "--estimator", "power", "--power", "100000"],
     "power must be from 2 to 64"),
    (["render", "quad-shadow", "--exposure", "1e308"], "argument --exposure: must be a number of stops"),
    (["render", "quad-shadow", "--exposure", "nan"], "argument --exposure: must be a number of stops"),
    (["render", "quad-shadow", "--seed", "9223372036854775808"], "argument --seed: must be at most"),
    (["render", "quad-shadow", "--spp", "1e400"], "argument --spp: expected a whole number"),
    (["render", "quad-shadow", "-o", "/proc/out.png"], "cannot write '/proc/out.png'"),
    (["render", "quad-shadow", "-o", "x" * 300 + ".png"], "File name too long"),
    (["render", "quad-shadow", "-D", "res=16384"], "this render needs about"),
    (["render", "quad-shadow", "-D", "res=32768"], "lower the resolution (-D res, or resolution= in Python)"),
    (["render", "quad-shadow", "-D", "res=1e9"], "parameter res must be an integer"),
    (["render", "quad-shadow", "-D", "res=0"], "parameter res (-D res=, res=) must be from 1 to 32768, got 0"),
    (["render", "quad-shadow", "-o", "a\nb.tiff"], "cannot write 'a\\nb.tiff'"),
    (["render", "quad-shadow", "-D", "res=8\x1b[2J"], "got '8\\x1b[2J'"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--photons", "1e8"], "lower --photons"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--neighbours", "100000000"],
     "neighbours must be from 1 to 1,024"),
    (["render", "quad-shadow", "--visibility", "probvis", "--probabilities", "0,0.5,0.5"],
     "probabilities must each be positive"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--radius", "1e300"],
     "radius 1e+300 is larger than the scene"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--radius", "inf"], "radius expects a finite number"),
    (["render", "quad-shadow", "--visibility", "probvis", "--estimator", "shifted", "--shifts", "nan,0,0"],
     "shifts expects 3 finite numbers, got 'nan,0,0'"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--verify", "0"], "verify must be auto, off or"),
    (["render", "quad-shadow", "--visibility", "probvis", "--verify", "nan"], "verify must be auto, off or"),
    (["render", "quad-shadow", "--verify", "0.5"], "--verify does not apply to --visibility exact"),
    (["render", "quad-shadow", "--threads", "100000"], "threads must be between 1 and"),
    (["render", "quad-shadow", "--visibility", "nowhere:Thing"], "cannot import 'nowhere'"),
    (["render", "quad-shadow", "--stats", "out.exr"], "--stats's output must be a .json file"),
    (["render", "quad-shadow", "--stats", "stats"], "--stats's output must be a .json file"),
    (["render", "quad-shadow", "-o", "a.exr", "--tests-image", "./a.exr"], "the same file as -o a.exr"),
    (["render", "quad-shadow", "-o", "good.exr", "-o", "out.json"], "-o's output must be a .exr, .pfm, .png file"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--case-image", "c.json"],
     "--case-image's output must be"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--visibility", "exact"],
     "--visibility given 2 times"),
    (["render", "/dev/zero"], "not a regular file"),
    (["render", "quad-shadow", "--visibility", "proxy", "--ratio", "0.2", "--triangles", "100"],
     "give ratio or triangles, not both (the command line's --ratio and --triangles)"),
    (["render", "quad-shadow", "-D", "res=8192"], "this render needs about"),  # under the 6 GiB RLIMIT_AS
    (["render", "quad-shadow", "--exposure", "-inf"], "argument --exposure: must be a number of stops"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "-o", "c-e1.exr", "--case-image", "c.exr"],
     "--case-image c.exr: with several emitters it writes c-e1.exr, the same file as -o c-e1.exr"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--radius", "1e-300"],
     "radius 1e-300 is below a billionth of the scene"),
    (["render", "quad-shadow", "--stats", "a.json", "--stats", "b.json"], "--stats given twice (a.json, b.json)"),
    (["render", "quad-shadow", "--tests-image", "a.exr", "--tests-image", "b.exr"], "--tests-image given twice"),
    (["render", "quad-shadow", "-o", "x.exr/"], "the name ends in '/'"),
    (["render", "quad-shadow", "-o", ".exr"], "cannot write '.exr': the name is an extension alone; give a name "
                                             "before it, such as 'out.exr'"),
    (["render", "quad-shadow", "--visibility", "cache-cv", "--q", "0.1", "--min-q", "0.9"],
     "give q or min_q, not both (the command line's --q and --min-q)"),
    (["render", "quad-shadow", "-D", "res=8", "-D", "res=64"], "-D res given twice (8, 64): give it once"),
    (["render", "quad-shadow", "--spp", "2", "--spp", "3"], "--spp given twice (2, 3): give it once"),
    (["render", "quad-shadow", "-D", "seed=-5"], "parameter seed (-D seed=, seed=) must be a whole number from 0"),
    (["render", "quad-shadow", "--exposure", "1", "--exposure=2"], "--exposure given twice (1.0, 2.0)"),
    (["render", "quad-shadow", "--seed", "1", "--seed", "2"], "--seed given twice"),
    (["experiment", "--quick", "-o", "a", "--output", "b"], "--output given twice (a, b)"),
    (["tables", "--power", "3", "--power", "4"], "--power given twice (3, 4)"),
    (["render", "quad-shadow", "--shells", "on", "--no-shells"], "--shells and --no-shells set the same option"),
    (["render", "quad-shadow", "--cache", "--no-cache"], "--cache and --no-cache set the same option"),
    (["render", "quad-shadow", "--spp", "1_0"], "argument --spp: expected a whole number, got '1_0'"),
    (["render", "quad-shadow", "--spp", "\u0662"], "argument --spp: expected a whole number"),
    (["render", "quad-shadow", "-D", "res=1_6"], "parameter res must be an integer, got '1_6'"),
    (["render", "quad-shadow", "--output="], "-o's output needs a file name (got an empty one)"),
    (["render", "quad-shadow", "--stats="], "--stats's output needs a file name (got an empty one)"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--case-image="], "--case-image's output needs a"),
    (["render", "quad-shadow", "--tests-image="], "--tests-image's output needs a file name"),
    (["render", "", "-o", "out.exr"], "the scene name is empty"),
    (["render", "x" * 5000, "-o", "out.exr"], "File name too long"),
    (["render", "quad-shadow", "-D", "=5"], "-D expects name=value, got '=5' (the name is empty)"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--verify", "1e-9"],
     "verify must be auto, off or a probability from 0.001 to 1, got '1e-9'"),
    (["render", "quad-shadow", "--visibility", "proxy", "--q", "1e-300"], "q must be auto or a probability from"),
    (["render", "quad-shadow", "--visibility", "probvis", "--probabilities", "-0.1,0.6,0.5"],
     "argument --probabilities: probabilities must be from 0 to 1, got '-0.1,0.6,0.5'"),
    (["tables", "--shifts", "1e300,-1e300,1"], "--shifts: shifts must be three numbers summing to 1, each within"),
    (["tables", "--probabilities", "0.5,0.5,0.5"], "--probabilities: probabilities must sum to 1"),
    (["experiment", "--quick", "--scheduler", "inproc://nothing"], "an inproc:// address names a scheduler"),
    (["experiment", "--quick", "--scheduler", ""], "--scheduler needs a Dask scheduler's address (tcp://host:port)"),
    (["estimators", ""], "the estimator's name is empty (leave it out to list every estimator)"),
    (["render", "quad-shadow", "--vis", "occlusion-map"], "unrecognized arguments: --vis occlusion-map (flags are "
                                                             "spelt out in full: did you mean --visibility?)"),
    (["render", "quad-shadow", "--visibility", "occlusion-map", "--photons", "1000", "--phot", "2000"],
     "did you mean --photons?"),
    (["render", "quad-shadow", "-o", "out.exr", ""], "unrecognized argument '' (an empty string"),
    (["render", "--", "quad-shadow", "--spp", "1", "-o", "out.exr"],
     "(after '--' every argument is a positional one: put the options before '--')"),
    (["scenes", "--json"], "(--json is an option of 'probvis info' and 'probvis estimators' and 'probvis tables', "
                           "not of 'probvis scenes')"),
    (["tables", "--seed", "3"], "(--seed is an option of 'probvis render', not of 'probvis tables')"),
    (["render", "d" * 300 + ".xml"], ": File name too long"),
    (["info", "d" * 300 + ".xml"], ": File name too long"),
    (["experiment", "--quick", "-o", ""], "-o needs a folder name (got an empty one)"),
    (["experiment", "--quick", "--cache", " "], "--cache needs a folder name (got an empty one)"),
    (["experiment", "--quick", "--cache", __file__], "test_bad_input.py' is a file, not a folder"),
    (["render", "quad-shadow", "--visibility", "probvis", "--estimator", "adaptive", "--levels", "3"],
     "levels does not apply to the adaptive estimator, which chooses its own probabilities and shifts on one A/B "
     "split: leave it out"),
    (["render", "quad-shadow", "--visibility", "probvis", "--estimator", "adaptive", "--cells", "2", "--shifts",
      "0.2,0.3,0.5"], "cells and shifts do not apply to the adaptive estimator"),
]


@pytest.mark.parametrize("args, message", CASES, ids=[" ".join(a)[:60] for a, _ in CASES])
def test_bad_input_is_one_line_and_writes_nothing(tmp_path, args, message):
    r, seconds = run(args + (["-o", "out.exr"] if args[0] == "render" and "-o" not in args else []), tmp_path)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2, r.stderr
    assert len(lines) == 1 and lines[0].startswith("probvis: error:") and message in lines[0], r.stderr
    assert "Traceback" not in r.stderr and not r.stdout.strip()
    assert not [p for p in tmp_path.iterdir()], "nothing may be written"
    assert seconds < TIME_LIMIT


def test_a_film_too_large_names_what_sets_its_size(tmp_path):
    """A scene file whose film is too large and that declares no `res`: the advice names the film's width and
    height in that file, not a -D res it does not have (sweep 37)."""
    scene = write_scene(tmp_path / "big.xml", sensor(w=30000, h=30000) + """
        <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""")
    r, _ = run(["render", scene, "-o", tmp_path / "o.exr"], tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "lower the resolution (the film's width and height in big.xml, or resolution= in Python)" in r.stderr
    assert not (tmp_path / "o.exr").exists()


def test_files_the_process_may_not_read_are_named_where_the_scene_names_them(tmp_path):
    """An included file the process may not read was 'cannot read scene file inc.xml' without the <include>'s
    line, and a mesh in a folder it may not search 'sub/m.obj: Permission denied' (sweep 38)."""
    from tests.conftest import without_permission_override

    (tmp_path / "inc.xml").write_text("<scene version='3.0.0'/>")
    (tmp_path / "inc.xml").chmod(0)
    scene = write_scene(tmp_path / "s.xml", sensor() + "<include filename='inc.xml'/>")
    r = subprocess.run(without_permission_override([sys.executable, "-m", "probvis.cli", "render", str(scene), "-o",
                                                    str(tmp_path / "o.exr")]), capture_output=True, text=True)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "s.xml:" in r.stderr and "<include>: cannot read included file 'inc.xml': Permission denied" in r.stderr
    (tmp_path / "sub").mkdir()
    scene = mesh_scene(tmp_path, b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "sub/m.obj")
    (tmp_path / "sub").chmod(0o600)
    try:
        r = subprocess.run(without_permission_override([sys.executable, "-m", "probvis.cli", "render", str(scene),
                                                        "-o", str(tmp_path / "o.exr")]), capture_output=True, text=True)
    finally:
        (tmp_path / "sub").chmod(0o755)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "mesh.xml:" in r.stderr and "<shape>: cannot read" in r.stderr and "Permission denied" in r.stderr
    assert not (tmp_path / "o.exr").exists()


def test_bad_meshes_are_named_with_file_and_line(tmp_path):
    scene = mesh_scene(tmp_path, os.urandom(3000))
    r, _ = run(["render", scene, "-o", tmp_path / "o.exr"], tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr
    assert "m.obj" in r.stderr and "module" not in r.stderr.lower()
    scene = mesh_scene(tmp_path, b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n# a comment\nf 1 2 7\n", "idx.obj")
    r, _ = run(["render", scene, "-o", tmp_path / "o.exr"], tmp_path)
    assert r.returncode == 2 and r.stderr.count("\n") == 1
    assert "idx.obj:6: face refers to vertex 7, but the file defines only 3 vertices" in r.stderr
    assert not (tmp_path / "o.exr").exists()


def test_broken_pipe_exits_quietly(monkeypatch, capsys):
    class Closed(io.StringIO):
        def write(self, text):
            raise BrokenPipeError

        def fileno(self):
            return os.open(os.devnull, os.O_WRONLY)

    monkeypatch.setattr(sys, "stdout", Closed())
    assert main(["tables"]) == 141
    assert capsys.readouterr().err == ""


def test_an_interrupt_inside_a_compiled_kernel_s_return_is_an_interrupt(monkeypatch, capsys):
    """A signal handled as a compiled kernel returns reaches Python as a SystemError caused by the
    KeyboardInterrupt (seen during the occlusion map's photon pass): one line and exit 130, as any interrupt."""
    import probvis.cli as cli

    def interrupted(args):  # one SystemError per compiled frame the interrupt crossed, each the next's cause
        inner = SystemError("<function _numba_unpickle> returned a result with an exception set")
        inner.__cause__ = KeyboardInterrupt()
        raise SystemError("CPUDispatcher(<function all_hits>) returned a result with an exception set") from inner

    monkeypatch.setattr(cli, "_cmd_scenes", interrupted)
    assert main(["scenes"]) == 130
    assert capsys.readouterr().err == "probvis: interrupted, nothing written\n"


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGHUP])
def test_ctrl_c_to_the_process_group_of_an_experiment(tmp_path, signum):
    """What Ctrl-C in a terminal, or closing it, sends: SIGINT or SIGHUP to the driver and its Dask workers alike.
    One line, exit 130, the finished renders kept (a hang-up killed multiprocessing's resource tracker, which came
    back without its records and printed six tracebacks)."""
    study = tmp_path / "s.toml"
    study.write_text('spp = 1\nshadow_rays = [1, 2, 3, 4, 5, 6, 7, 8]\nseeds = [0, 1, 2, 3]\nresolution = [32, 32]\n'
                     '[[scenes]]\nname = "c"\nsource = "canopy"\n'
                     '[[methods]]\nname = "om"\nvisibility = "occlusion-map"\n')
    proc = subprocess.Popen([sys.executable, "-m", "probvis.cli", "experiment", str(study), "-o", str(tmp_path / "r"),
                             "-q"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    cache = tmp_path / "r" / "cache"
    deadline = time.time() + 600
    while time.time() < deadline and not list(cache.glob("*.json")):
        time.sleep(0.2)
    assert list(cache.glob("*.json")), "no render finished in time"
    os.killpg(proc.pid, signum)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    lines = [line for line in err.strip().splitlines() if not line.startswith("experiment '")
             and not line.startswith("computing ")]
    assert len(lines) == 1 and "interrupted" in lines[0] and "Traceback" not in err, err


@pytest.mark.parametrize("output, limit", [("o.exr", 1024), ("o.png", 1024), ("o.exr", 0)])
def test_a_file_size_limit_is_one_line_and_leaves_nothing(tmp_path, output, limit):
    """Under `ulimit -f` (RLIMIT_FSIZE) the image's writer fails: one line naming the file, no temporary left.
    At 0, OpenEXR's writer reported nothing and left an empty file with exit 0; Numba warned over five lines."""
    def limits():
        _limits()
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    r = subprocess.run([sys.executable, "-m", "probvis.cli", "render", "quad-shadow", "-D", "res=64", "--spp", "1",
                        "-o", output], capture_output=True, text=True, cwd=tmp_path, timeout=TIME_LIMIT,
                       preexec_fn=limits)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    reasons = ("File too large", "nothing could be written (a full disk, or a file size limit")
    assert any(r.stderr.startswith(f"probvis: error: cannot write '{output}': {x}") for x in reasons), r.stderr
    assert not list(tmp_path.iterdir())


def test_one_failing_output_leaves_none_of_the_others(tmp_path):
    """Outputs appear together or not at all: under `ulimit -f` the small PNG is written, the EXR is not, and
    neither is left."""
    def limits():
        _limits()
        resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))

    r = subprocess.run([sys.executable, "-m", "probvis.cli", "render", "quad-shadow", "-D", "res=48", "--spp", "1",
                        "--shadow-rays", "1", "-o", "small.png", "-o", "big.exr"], capture_output=True, text=True,
                       cwd=tmp_path, timeout=TIME_LIMIT, preexec_fn=limits)
    assert r.returncode == 2 and r.stderr.startswith("probvis: error: cannot write 'big.exr'"), r.stderr
    assert not list(tmp_path.iterdir())


def test_a_symbolic_link_is_written_through_and_a_pipe_refused(tmp_path):
    (tmp_path / "real").mkdir()
    (tmp_path / "link.exr").symlink_to(tmp_path / "real" / "image.exr")
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "-q", "-o", str(tmp_path / "link.exr")]) == 0
    assert (tmp_path / "link.exr").is_symlink() and (tmp_path / "real" / "image.exr").is_file()
    (tmp_path / "dangling.exr").symlink_to(tmp_path / "nowhere" / "image.exr")
    r, _ = run(["render", "quad-shadow", "-o", "dangling.exr"], tmp_path)
    assert r.returncode == 2 and "folder" in r.stderr and "does not exist" in r.stderr, r.stderr
    os.mkfifo(tmp_path / "pipe.exr")
    r, _ = run(["render", "quad-shadow", "-o", "pipe.exr"], tmp_path)
    assert r.returncode == 2 and "it is not a regular file" in r.stderr and r.stderr.count("\n") == 1, r.stderr


def test_a_texture_too_large_to_read_is_one_line(tmp_path, monkeypatch):
    """A PNG above MAX_IMAGE_PIXELS is refused from its header, before decoding; a MemoryError anywhere is one line."""
    from PIL import Image

    import probvis
    from probvis.io import linear_rgb

    import imageio.v3 as iio

    Image.new("L", (64, 64)).save(tmp_path / "big.png")
    monkeypatch.setattr(linear_rgb, "MAX_IMAGE_PIXELS", 1000)
    monkeypatch.setattr(iio, "imread", None)  # decoding it would fail: the size must come from the header
    with pytest.raises(probvis.ProbvisError, match="image is 64x64 .* above the 0 Mpixel probvis reads"):
        linear_rgb.read_linear_rgb(tmp_path / "big.png")

    def out_of_memory(*args, **kwargs):
        raise MemoryError

    monkeypatch.setattr("probvis.integrator.render", out_of_memory)
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    assert main(["render", "quad-shadow", "-o", str(tmp_path / "o.exr")]) == 2
    assert err.getvalue().startswith("probvis: error: out of memory") and err.getvalue().count("\n") == 1
    assert "--spp" in err.getvalue()
    monkeypatch.setattr("probvis.scene.open_scene", out_of_memory)  # `info` has no resolution or sample counts
    err.truncate(0)
    err.seek(0)
    assert main(["info", "quad-shadow"]) == 2
    assert err.getvalue().startswith("probvis: error: out of memory") and "--spp" not in err.getvalue()


@pytest.mark.parametrize("mib", [200, 400])
def test_an_address_space_too_small_to_start_is_one_line(tmp_path, mib):
    """Under a small address-space limit (ulimit -v) the compiled libraries cannot load (200 MiB), or OpenBLAS's
    start-up retried a failing allocation for ever (400 MiB: a hang): one line naming the limit, before anything
    loads."""
    def limits():
        resource.setrlimit(resource.RLIMIT_AS, (mib << 20, mib << 20))

    r = subprocess.run([sys.executable, "-m", "probvis", "render", "quad-shadow", "-o", "o.exr"], capture_output=True,
                       text=True, cwd=tmp_path, timeout=60, preexec_fn=limits)
    assert r.returncode == 1 and r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith(f"probvis: error: the address-space limit of {mib} MiB (ulimit -v) is too small")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_an_interrupt_while_the_libraries_load_is_one_line(tmp_path, signum):
    """Ctrl-C or SIGTERM as soon as probvis's handlers are in place, while numpy and Numba load: one line, exit
    130. (A fixed 0.1 s could come before them on a busy machine, where the interpreter's own start takes longer:
    SIGTERM's default action then killed the process, as it kills any program that has not started yet.)"""
    proc = subprocess.Popen([sys.executable, "-m", "probvis", "render", "quad-shadow", "-o", "o.exr"], cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + TIME_LIMIT
    while time.monotonic() < deadline:  # SIGTERM caught: `probvis.__main__` set its handlers (SIGINT's first)
        status = Path(f"/proc/{proc.pid}/status").read_text()
        caught = int(next(line.split()[1] for line in status.splitlines() if line.startswith("SigCgt:")), 16)
        if caught >> (signal.SIGTERM - 1) & 1:
            break
        time.sleep(0.001)
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=TIME_LIMIT)
    assert proc.returncode == 130 and err == "probvis: interrupted, nothing written\n", err
    assert not list(tmp_path.iterdir())



def test_an_ignored_ctrl_c_stays_ignored(tmp_path):
    """A shell script's `probvis render ... &` starts with SIGINT ignored, so that Ctrl-C at the terminal spares
    it (Python leaves it so); probvis's own handlers took it over and stopped the render."""
    proc = subprocess.Popen([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=16", "-q", "-o",
                             "o.exr"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    for _ in range(3):
        time.sleep(0.15)
        proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=TIME_LIMIT)
    assert proc.returncode == 0 and err == "", err
    assert (tmp_path / "o.exr").is_file()

def test_a_stack_too_small_to_start_is_one_line(tmp_path):
    """A stack limit (ulimit -s) below what a render needs is refused at the start, in one line, before numpy
    loads (below about 90 KiB its import crashes the interpreter; below about 76 KiB the interpreter itself)."""
    def limits():
        resource.setrlimit(resource.RLIMIT_STACK, (256 << 10, resource.getrlimit(resource.RLIMIT_STACK)[1]))

    r = subprocess.run([sys.executable, "-m", "probvis", "render", "quad-shadow", "-o", "o.exr"], capture_output=True,
                       text=True, cwd=tmp_path, timeout=TIME_LIMIT, preexec_fn=limits)
    assert r.returncode == 1 and r.stderr == ("probvis: error: the stack limit of 256 KiB (ulimit -s) is too small: "
                                              "probvis needs at least 1024 KiB (the usual default is 8192)\n")
    assert not list(tmp_path.iterdir())


def test_an_open_file_limit_too_small_to_start_is_one_line(tmp_path):
    """Under `ulimit -n 5` the start's checks could not make their pipe, and their handler could not load the
    `resource` module to say why: a chained traceback. The smallest limits at which the interpreter itself starts
    (its own failure is not probvis's to word) give one line naming the limit, or render."""
    said = []
    for n in range(4, 12):
        def limits():
            resource.setrlimit(resource.RLIMIT_NOFILE, (n, n))

        r = subprocess.run([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=8", "--spp", "1",
                            "-q", "-o", "o.exr"], capture_output=True, text=True, cwd=tmp_path, timeout=TIME_LIMIT,
                           preexec_fn=limits, close_fds=True)
        if r.returncode == 0:
            assert (tmp_path / "o.exr").is_file()
            break
        if "Fatal Python error" in r.stderr or r.returncode == 127:  # the interpreter did not start
            continue
        assert r.returncode == 1 and r.stderr == (f"probvis: error: cannot start under the open-file limit of {n} "
                                                  "(ulimit -n): too many open files; raise the limit\n"), r.stderr
        assert not list(tmp_path.iterdir())
        said.append(n)
    assert said and r.returncode == 0, said


@pytest.mark.parametrize("stdout", ["full", "closed"])
def test_a_standard_output_that_fails_is_one_line(tmp_path, stdout):
    """`probvis scenes > /dev/full` was an OSError traceback; `>&-` printed nothing with exit 0."""
    target = open("/dev/full", "w") if stdout == "full" else None
    try:
        r = subprocess.run([sys.executable, "-m", "probvis", "scenes"], stdout=target if target else None,
                           stderr=subprocess.PIPE, text=True, cwd=tmp_path, timeout=TIME_LIMIT,
                           preexec_fn=None if target else (lambda: os.close(1)))
    finally:
        if target:
            target.close()
    reason = "No space left on device" if stdout == "full" else "it is closed"
    assert r.returncode == 1 and r.stderr == f"probvis: error: cannot write to the standard output: {reason}\n"


@pytest.mark.parametrize("args, flag", [
    (["render", "quad-shadow", "--strict=yes"], "--strict"), (["render", "quad-shadow", "--clamp-negative", "true"],
                                                             "--clamp-negative"),
    (["render", "quad-shadow", "--filter-importance=1"], "--filter-importance"),
    (["render", "quad-shadow", "-q", "true"], "-q"), (["info", "quad-shadow", "--json=true"], "--json"),
    (["render", "quad-shadow", "--quiet=1"], "--quiet"),
])
def test_an_on_only_switch_given_a_value_says_it_is_a_switch(args, flag, capsys):
    """`--strict=yes` was argparse's 'ignored explicit argument', `-q true` 'unrecognized arguments: true': neither
    said the flag takes no value."""
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.endswith(f"({flag} is a switch: give {flag} alone, without a value, or leave it out)\n"), err


def test_an_on_off_switch_given_a_value_names_both_forms(capsys):
    assert main(["render", "quad-shadow", "--no-cache=1"]) == 2
    assert capsys.readouterr().err.endswith("(--cache is a switch: give --cache or --no-cache, without a value)\n")


def test_a_non_ascii_name_under_an_ascii_locale_is_escaped(tmp_path):
    """With PYTHONIOENCODING=ascii the summary's 'wrote sortie-é.exr' was a UnicodeEncodeError after the render."""
    r = subprocess.run([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=8", "--spp", "1",
                        "-o", "sortie-\u00e9.exr"], capture_output=True, cwd=tmp_path, timeout=TIME_LIMIT,
                       env={**os.environ, "PYTHONIOENCODING": "ascii"})
    assert r.returncode == 0 and b"sortie-\\xe9.exr" in r.stdout, r.stderr


def test_a_switch_given_a_value_says_it_is_a_switch(capsys):
    """`--adaptive-photons false` was 'unrecognized arguments: false', and `probvis estimators` listed the flag as
    taking true/false."""
    assert main(["render", "quad-shadow", "--visibility", "occlusion-map", "--adaptive-photons", "false"]) == 2
    assert capsys.readouterr().err == ("probvis: error: unrecognized arguments: false (--adaptive-photons is a switch: "
                                       "give --adaptive-photons or --no-adaptive-photons, without a value)\n")
    assert main(["estimators", "occlusion-map"]) == 0
    assert "--adaptive-photons / --no-adaptive-photons  (a switch; true/false in the API" in capsys.readouterr().out


def _c_locale():
    """The environment of a C locale with Python's UTF-8 mode off: file names are ASCII to Python."""
    return {**os.environ, "LC_ALL": "C", "LANG": "C", "PYTHONUTF8": "0", "PYTHONIOENCODING": "ascii"}


def test_names_under_a_locale_that_cannot_encode_them(tmp_path):
    """Under the C locale a UTF-8 EXR name was refused as 'not UTF-8' (PNG and PFM were written), and a
    non-ASCII name inside a scene file was a UnicodeEncodeError traceback."""
    name = "sortie-\u00e9.exr"
    r = subprocess.run([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=8", "--spp", "1",
                        "-o", os.fsencode(name)], capture_output=True, cwd=tmp_path, timeout=TIME_LIMIT,
                       env=_c_locale())
    assert r.returncode == 0 and (tmp_path / name).stat().st_size > 0, r.stderr
    scene = write_scene(tmp_path / "s.xml", sensor() + '<emitter type="envmap"><string name="filename" '
                        'value="\u00e9nv.exr"/></emitter>')
    r = subprocess.run([sys.executable, "-m", "probvis", "render", str(scene), "-o", "o.exr"], capture_output=True,
                       text=True, cwd=tmp_path, timeout=TIME_LIMIT, env=_c_locale(), errors="replace")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "Traceback" not in r.stderr, r.stderr
    assert "the file system's encoding here (ascii, from the locale) cannot represent this name" in r.stderr


def test_a_closed_standard_error_does_not_stop_a_render(tmp_path):
    """With `2>&-` a render exited 1 without a word and wrote nothing (sys.stderr was None)."""
    r = subprocess.run([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=8", "--spp", "1",
                        "-o", "o.exr"], stdout=subprocess.PIPE, cwd=tmp_path, timeout=TIME_LIMIT,
                       preexec_fn=lambda: os.close(2))
    assert r.returncode == 0 and (tmp_path / "o.exr").stat().st_size > 0


@pytest.mark.parametrize("flag", ["--help", "--version"])
def test_help_on_a_full_standard_output_is_one_line(flag):
    """`probvis --help > /dev/full` exited 0 with the text lost."""
    with open("/dev/full", "w") as full:
        r = subprocess.run([sys.executable, "-m", "probvis", flag], stdout=full, stderr=subprocess.PIPE, text=True,
                           timeout=TIME_LIMIT)
    assert r.returncode == 1
    assert r.stderr == "probvis: error: cannot write to the standard output: No space left on device\n"


@pytest.mark.parametrize("name, value, message", [
    ("NUMBA_NUM_THREADS", "0", "is not a thread count"), ("NUMBA_NUM_THREADS", "abc", "is not a thread count"),
    ("NUMBA_NUM_THREADS", "99999", "is not a thread count from 1 to 1024"),
    ("NUMBA_THREADING_LAYER", "bogus", "is not one of Numba's threading layers"),
    ("NUMBA_OPT", "abc", "is not an optimisation level"),
    ("OMP_NUM_THREADS", "abc", "is not a value OpenMP (libgomp) accepts"),
    ("NUMBA_DEBUG", "abc", "is not a value Numba can read"), ("NUMBA_DISABLE_JIT", "abc", "is not a value Numba"),
    ("GOMP_SPINCOUNT", "abc", "is not a value OpenMP (libgomp) accepts"),
    ("GOMP_STACKSIZE", "abc", "is not a value OpenMP (libgomp) accepts"), ("PROBVIS_CACHE_DIR", " ", "is not a folder"),
    ("OMP_PLACES", "{garbage}", "is not a value OpenMP (libgomp) accepts"),
    ("NUMBA_THREADING_LAYER_PRIORITY", "bogus", "is not an order of tbb, omp and workqueue"),
    ("PROBVIS_CACHE_DIR", "~nosuchuser-probvis/pc", "is not a folder: it names the home of a user"),
])
def test_an_environment_setting_the_libraries_cannot_use_is_one_line(tmp_path, name, value, message):
    """NUMBA_NUM_THREADS=0 was Numba's traceback at import, 'abc' its warning then a render, 99999 a crash
    (SIGSEGV); a bogus threading layer a traceback, NUMBA_OPT=abc a warning with a traceback's text, libgomp's
    settings a line of the library's own, then a render."""
    if "OMP" in name:
        import ctypes

        try:
            ctypes.CDLL("libgomp.so.1")
        except OSError:
            pytest.skip("no libgomp here: Numba's OpenMP layer is not what runs")
    r = subprocess.run([sys.executable, "-m", "probvis", "render", "quad-shadow", "-o", "o.exr"], capture_output=True,
                       text=True, cwd=tmp_path, timeout=TIME_LIMIT, env={**os.environ, name: value})
    assert r.returncode == 1 and r.stderr.startswith(f"probvis: error: {name}='{value}' {message}") \
        and r.stderr.count("\n") == 1, r.stderr
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("value", ["-1", "99999", "1.5"])
def test_the_cli_module_checks_the_environment_as_the_command_does(tmp_path, value):
    """`python -m probvis.cli` skipped the command's checks: NUMBA_NUM_THREADS=-1 was Numba's traceback, 99999 a
    segmentation fault, 1.5 a warning with a traceback's text and then a render."""
    r = subprocess.run([sys.executable, "-m", "probvis.cli", "render", "quad-shadow", "-o", "o.exr"],
                       capture_output=True, text=True, cwd=tmp_path, timeout=TIME_LIMIT,
                       env={**os.environ, "NUMBA_NUM_THREADS": value})
    assert r.returncode == 1 and r.stderr == (f"probvis: error: NUMBA_NUM_THREADS='{value}' is not a thread count from "
                                              "1 to 1024: unset it or correct it (--threads bounds a render's "
                                              "threads)\n"), r.stderr
    assert not list(tmp_path.iterdir())


def test_an_output_under_a_file_is_named_as_such(tmp_path):
    (tmp_path / "f.txt").write_text("")
    r, _ = run(["render", "quad-shadow", "-o", "f.txt/out.exr"], tmp_path)
    assert r.returncode == 2 and r.stderr == ("probvis: error: cannot write 'f.txt/out.exr': folder 'f.txt' is a "
                                              "file, not a folder\n"), r.stderr


def test_a_deleted_working_folder_is_one_line(tmp_path):
    """It was blamed on the estimator ("cannot import probvis.visibility.exact: FileNotFoundError")."""
    gone = tmp_path / "gone"
    gone.mkdir()
    r = subprocess.run(f"cd '{gone}' && rmdir '{gone}' && exec '{sys.executable}' -m probvis render quad-shadow "
                       "-o out.exr", shell=True, capture_output=True, text=True, timeout=TIME_LIMIT)
    assert r.returncode == 2 and r.stderr == ("probvis: error: the current folder no longer exists (it was deleted): "
                                              "cd to an existing folder\n"), r.stderr


def _integrator_scene(tmp_path, integrator):
    return write_scene(tmp_path / "s.xml", sensor().split("<integrator")[0] + integrator + """
        <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""")


def test_integrator_messages_name_the_parameter(tmp_path, capsys):
    for integrator, message in (('<integrator type="direct"><integer name="shading_samples" value="-3"/>'
                                 '</integrator>', "<integer>: shading_samples must be from 1 to 65536, got -3"),
                                ('<integrator type="path"><integer name="max_depth" value="-7"/></integrator>',
                                 "max_depth must be -1"),
                                ('<integrator type="path"><integer name="rr_depth" value="0"/></integrator>',
                                 "rr_depth must be positive, got 0")):
        assert main(["render", str(_integrator_scene(tmp_path, integrator)), "-o", str(tmp_path / "o.exr")]) == 2
        assert message in capsys.readouterr().err


@pytest.mark.parametrize("value, message", [(-5.0, "values must be finite, non-negative"),
                                            (3e38, "values must be finite, non-negative")])
def test_an_environment_map_out_of_range_is_refused_at_its_line(tmp_path, capsys, value, message):
    """An envmap texel of -5 rendered without a word; one of 3e38 rendered inf pixels with exit 0."""
    import numpy as np

    from probvis.io import write_exr

    image = np.full((4, 8, 3), 0.5)
    image[1, 2] = value
    write_exr(tmp_path / "env.exr", image)
    scene = write_scene(tmp_path / "s.xml", sensor() + """
        <emitter type="envmap"><string name="filename" value="env.exr"/></emitter>
        <shape type="sphere"/>""")
    assert main(["render", str(scene), "-o", str(tmp_path / "o.exr")]) == 2
    err = capsys.readouterr().err
    assert "s.xml:" in err and message in err and not (tmp_path / "o.exr").exists()


def test_an_image_beyond_float32_is_refused_and_nothing_written(tmp_path):
    import numpy as np

    from probvis.errors import ProbvisError
    from probvis.io import staged_writes, write_exr, write_image

    with pytest.raises(ProbvisError, match="beyond what a float32 file holds"):
        with staged_writes():
            write_image(tmp_path / "a.pfm", np.ones((2, 2, 3)))
            write_exr(tmp_path / "b.exr", np.full((2, 2, 3), 1e39))
    assert not list(tmp_path.iterdir())


def test_a_symbolic_link_that_loops_is_one_line(tmp_path, capsys):
    (tmp_path / "loop.exr").symlink_to("loop.exr")
    assert main(["render", "quad-shadow", "-D", "res=8", "-o", str(tmp_path / "loop.exr")]) == 2
    assert "symbolic link that loops" in capsys.readouterr().err


def test_a_standard_output_that_fails_leaves_no_image(tmp_path, monkeypatch, capsys):
    """The summary is printed before the files appear: a run whose summary cannot be written wrote nothing."""
    monkeypatch.setattr(sys, "stdout", None)
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "-o", str(tmp_path / "o.exr")]) == 1
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("clip", ['near_clip" value="100', 'far_clip" value="0.5'])
def test_clip_planes_that_leave_out_the_scene_are_refused(tmp_path, capsys, clip):
    scene = write_scene(tmp_path / "s.xml", sensor().replace('<float name="fov"', f'<float name="{clip}"/>'
                                                              '<float name="fov"') + """
        <shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""")
    assert main(["render", str(scene), "-o", str(tmp_path / "o.exr")]) == 2
    assert "leaves out the whole scene" in capsys.readouterr().err


def test_ply_face_indices_that_are_not_integers_are_refused(tmp_path, capsys):
    ply = (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
           b"element face 1\nproperty list uchar float vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n"
           b"3 0.5 1 2\n")
    (tmp_path / "m.ply").write_bytes(ply)
    scene = write_scene(tmp_path / "s.xml", sensor() + """
        <shape type="ply"><string name="filename" value="m.ply"/></shape>
        <shape type="rectangle"><transform name="to_world"><translate z="2"/></transform>
            <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""")
    assert main(["render", str(scene), "-o", str(tmp_path / "o.exr")]) == 2
    assert "vertex indices are integers" in capsys.readouterr().err


def test_numpy_numbers_are_numbers_for_estimator_options():
    import numpy as np

    from probvis.visibility import estimator_class

    assert estimator_class("occlusion-map")(photons=np.int64(2000)).params.photons == 2000


def test_kernels_run_as_python_do_not_warn_of_their_hashes_wrapping(tmp_path):
    """Under NUMBA_DISABLE_JIT=1 the random hashes' uint64 arithmetic warned six times of overflow."""
    r = subprocess.run([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=4", "--spp", "1", "-q",
                        "-o", "o.exr"], capture_output=True, text=True, cwd=tmp_path, timeout=TIME_LIMIT,
                       env={**os.environ, "NUMBA_DISABLE_JIT": "1"})
    assert r.returncode == 0 and r.stderr == "", r.stderr


def test_a_closed_terminal_stops_a_render_as_ctrl_c_does(tmp_path):
    """SIGHUP during a render or its write killed the process (status 129) with no line and, during the write, a
    hidden temporary file left behind."""
    proc = subprocess.Popen([sys.executable, "-m", "probvis", "render", "quad-shadow", "-D", "res=1024", "--spp",
                             "256", "-o", "o.exr", "-o", "o.png"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    time.sleep(3)
    proc.send_signal(signal.SIGHUP)
    _, err = proc.communicate(timeout=TIME_LIMIT)
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == "probvis: interrupted, nothing written", err
    assert not list(tmp_path.iterdir())


def test_messages_say_what_is_wrong(tmp_path, monkeypatch):
    """Messages that misled: a PLY without z is not 'truncated'; a built-in given as a Path is named as such; an
    array of probabilities is three numbers; an unknown --verify word gets no note about tiny probabilities; the
    thread limit says where it comes from."""
    from pathlib import Path

    import numba

    import probvis
    from probvis import ProbvisError
    from probvis.visibility.occlusion_map.verification import parse_verify

    ply = tmp_path / "m.ply"
    ply.write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nelement face 1\n"
                   "property list uchar int vertex_indices\nend_header\n0 0\n1 0\n0 1\n3 0 1 2\n")
    from probvis.scene.shapes import load_mesh

    with pytest.raises(ProbvisError, match="its vertex element has no 'z' property"):
        load_mesh(ply)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ProbvisError, match="a built-in scene is named by a string: 'cornell-box'"):
        probvis.render(Path("cornell-box"), spp=1)
    r = probvis.render("quad-shadow", spp=1, shadow_rays=2, defines={"res": 8}, visibility="probvis",
                       visibility_options={"probabilities": np.array([0.5, 0.25, 0.25])})
    assert list(r.stats["visibility"]["probabilities"]) == [0.5, 0.25, 0.25]
    assert "below" not in parse_verify("AUTO") and "below, each correction" in parse_verify("1e-9")
    monkeypatch.setenv("NUMBA_NUM_THREADS", str(numba.config.NUMBA_NUM_THREADS))
    with pytest.raises(ProbvisError, match=rf"between 1 and {numba.config.NUMBA_NUM_THREADS} \(NUMBA_NUM_THREADS="):
        probvis.render("quad-shadow", spp=1, defines={"res": 8}, threads=numba.config.NUMBA_NUM_THREADS + 1)


def test_the_command_s_warnings_stay_warnings_and_jit_may_be_off(tmp_path):
    """PYTHONWARNINGS=error made probvis's own warnings tracebacks; NUMBA_DISABLE_JIT=1 (a valid value: the
    kernels run as Python) was an AttributeError before the render."""
    path = write_scene(tmp_path / "s.xml", sensor(w=8, h=8, sr=1) + """<emitter type="point"><point name="position" x="0"
        y="0" z="3"/><rgb name="intensity" value="5"/></emitter><shape type="rectangle"/>""")
    for env, args in (({"PYTHONWARNINGS": "error"}, ["-D", "foo=1"]), ({"NUMBA_DISABLE_JIT": "1"}, [])):
        r = subprocess.run([sys.executable, "-m", "probvis", "render", str(path), "--spp", "1", "--shadow-rays", "1",
                            "-q", "-o", "o.exr", *args], capture_output=True, text=True, cwd=tmp_path,
                           timeout=4 * TIME_LIMIT, env={**os.environ, **env})
        assert r.returncode == 0 and (tmp_path / "o.exr").exists() and "Traceback" not in r.stderr, r.stderr
        assert not args or r.stderr.strip() == (f"probvis: warning: {path}: -D foo: the scene declares no such "
                                                "parameter (its parameters: none)"), r.stderr
        (tmp_path / "o.exr").unlink()


def test_a_scene_changed_beyond_what_the_reader_accepts_is_refused(tmp_path):
    """Finite values the scene reader bounds, set through the API: a point light at 1e300 rendered NaN pixels,
    a zero spot axis black, triangles scaled by 1e200 NumPy warnings and a black image, a Gaussian filter of
    1e-300 a ZeroDivisionError."""
    import dataclasses

    import probvis
    from probvis import ProbvisError

    path = write_scene(tmp_path / "s.xml", sensor(w=8, h=8) + """<emitter type="spot"><transform name="to_world">
        <lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform><rgb name="intensity" value="5"/>
        </emitter><shape type="rectangle"/>""")
    for change, message in ((lambda s: s.emitter_position.__setitem__(0, 1e300), "scene.emitter_position must lie"),
                            (lambda s: s.emitter_axis.__setitem__(0, 0.0), "scene.emitter_axis must not be zero"),
                            (lambda s: setattr(s, "triangles", s.triangles * 1e200), "scene.triangles must lie"),
                            (lambda s: setattr(s, "camera", dataclasses.replace(s.camera, rfilter="gaussian",
                                                                                filter_stddev=1e-300)),
                             "camera.rfilter must be one of box, tent, gaussian, mitchell")):
        scene = probvis.load_scene(path)
        change(scene)
        with pytest.raises(ProbvisError, match=message):
            probvis.render(scene, spp=1, shadow_rays=1)


def test_a_finished_command_leaves_at_once_with_its_status(monkeypatch, capsys):
    """The interpreter's teardown after a command (Dask's, Numba's, LLVM's modules: tenths of a second) ran with
    Python's default signal handlers back, so a SIGTERM in it killed a finished study (exit 143, no message):
    the console command now flushes its output and leaves with the command's status."""
    from probvis import __main__ as entry

    left = []

    def leave(status):
        left.append(status)
        raise SystemExit(status)

    monkeypatch.setattr(entry.os, "_exit", leave)
    monkeypatch.setattr(sys, "argv", ["probvis", "scenes"])
    with pytest.raises(SystemExit):
        entry.main()
    assert left == [0] and "cornell-box" in capsys.readouterr().out
    monkeypatch.setattr(sys, "argv", ["probvis", "render", "no-such-scene"])
    with pytest.raises(SystemExit):
        entry.main()
    assert left == [0, 2] and "probvis: error:" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["m.obj", "m.PLY", "m.serialized"])
def test_a_mesh_given_as_the_scene_is_named_as_a_mesh(tmp_path, name):
    """A mesh file for the scene was "malformed XML: syntax error" at its line 1."""
    (tmp_path / name).write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(probvis.ProbvisError, match=re.escape(f"{name} is a mesh, not a scene: a scene is a Mitsuba "
                                                             "XML file that places it (a <shape type=")):
        probvis.load_scene(tmp_path / name)


@pytest.mark.parametrize("name, message", [
    ("e.toml", "is an experiment file, not a scene: run it with `probvis experiment"),
    ("i.exr", "is an image, not a scene"), ("i.PNG", "is an image, not a scene")])
def test_an_image_or_experiment_given_as_the_scene_is_named_as_such(tmp_path, name, message):
    """They were "malformed XML: not well-formed (invalid token)"."""
    (tmp_path / name).write_bytes(b"\x89PNG\r\n" if name != "e.toml" else b'name = "x"\n')
    with pytest.raises(probvis.ProbvisError, match=re.escape(f"{name} {message}")):
        probvis.load_scene(tmp_path / name)


@pytest.mark.parametrize("visibility", ["occlusion-map", "probvis"])
def test_one_neighbour_gives_a_radius_not_numpy_warnings(visibility):
    """With --neighbours 1 (its minimum) the photon radius came from each probe photon's nearest one, itself:
    0, then NumPy's divide-by-zero warnings and an occlusion map that told nothing."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        r = probvis.render("quad-shadow", spp=1, shadow_rays=2, defines={"res": 16}, visibility=visibility,
                           visibility_options={"neighbours": 1})
    assert np.isfinite(r.image).all() and r.stats["estimator"]["radius"] > 0


@pytest.mark.parametrize("emitter", ['<shape type="rectangle"><transform name="to_world"><translate z="2"/></transform>'
                                     '<emitter type="area"><rgb name="radiance" value="0"/></emitter></shape>',
                                     '<emitter type="point"><point name="position" x="0" y="0" z="2"/>'
                                     '<rgb name="intensity" value="0"/></emitter>'])
def test_emitters_that_all_emit_nothing_say_what_to_give(tmp_path, emitter, capsys):
    """Emitters of zero radiance or intensity: refused (nothing to sample by power; Mitsuba renders black) at the
    first emitter's element, with what would come of it and what to change, where it was the bare fact."""
    body = sensor(spp=1, sr=1, w=8, h=8) + '<shape type="rectangle"><bsdf type="diffuse"/></shape>\n' + emitter
    path = write_scene(tmp_path / "dark.xml", body)
    line = next(i for i, text in enumerate(path.read_text().splitlines(), 1) if "<emitter" in text)
    assert main(["render", str(path), "-o", str(tmp_path / "out.exr")]) == 2
    assert capsys.readouterr().err == (
        f"probvis: error: {path}:{line}: <emitter>: the scene's 1 emitter has zero power (a radiance, intensity or "
        "irradiance of 0, or a scale of 0): the image would be black (as Mitsuba renders it); give an emitter a "
        "positive one\n")
    assert not (tmp_path / "out.exr").exists()
    # an area emitter on a shape without area is no emitter of the scene: not the one named
    dark = '<shape type="sphere"><float name="radius" value="0"/><emitter type="area"/></shape>\n'
    path = write_scene(tmp_path / "dark.xml", body.replace(emitter, dark + emitter))
    assert main(["render", str(path), "-o", str(tmp_path / "out.exr")]) == 2
    assert f"dark.xml:{line + 1}: <emitter>: the scene's 1 emitter has zero power" in capsys.readouterr().err
