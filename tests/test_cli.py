"""The command line: outputs, one-line errors with non-zero exit, nothing half-written."""
import json
import re
import subprocess
import sys

import numpy as np
import pytest

import probvis
from probvis.cli import main
from probvis.errors import ProbvisError
from probvis.io import read_exr
from tests.conftest import sensor, write_scene


def test_render_writes_images_stats_and_test_counts(tmp_path, capsys):
    out = [tmp_path / "a.exr", tmp_path / "a.png", tmp_path / "a.pfm"]
    code = main(["render", "quad-shadow", "-D", "res=16", "--spp", "2", "--shadow-rays", "2", "--seed", "4",
                 "-o", str(out[0]), "-o", str(out[1]), "-o", str(out[2]), "--stats", str(tmp_path / "s.json"),
                 "--tests-image", str(tmp_path / "t.exr"), "--threads", "1"])
    assert code == 0
    assert all(p.stat().st_size > 0 for p in out)
    stats = json.loads((tmp_path / "s.json").read_text())
    assert stats["width"] == 16 and stats["spp"] == 2 and stats["seed"] == 4 and stats["threads"] == 1
    assert read_exr(out[0]).shape == (16, 16, 3)
    assert "tests       triangle" in capsys.readouterr().out
    assert not list(tmp_path.glob(".*"))


def test_user_mistakes_give_one_line_and_exit_2(tmp_path, capsys):
    bad = tmp_path / "bad.xml"
    bad.write_text("<scene version='3.0.0'>\n<shape type='sphere'\n</scene>")
    cases = [
        (["render", str(tmp_path / "missing.xml"), "-o", str(tmp_path / "x.exr")], "scene file not found"),
        (["render", str(bad), "-o", str(tmp_path / "x.exr")], "bad.xml:3: malformed XML"),
        (["render", "quad-shadow", "-o", str(tmp_path / "no" / "x.exr")], "does not exist"),
        (["render", "quad-shadow", "-o", str(tmp_path / "x.jpg")], "output must be a .exr, .pfm, .png file"),
        (["render", "quad-shadow", "-D", "res=0", "-o", str(tmp_path / "x.exr")],
         "parameter res (-D res=, res=) must be from 1"),
        (["render", "quad-shadow", "-D", "bogus", "-o", str(tmp_path / "x.exr")], "-D expects name=value"),
        (["info", "nope"], "neither a scene file"),
    ]
    for argv, message in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("probvis: error:") and message in err[0], err
    assert not (tmp_path / "x.exr").exists()


def test_scene_without_emitter(tmp_path, capsys):
    path = write_scene(tmp_path / "dark.xml", sensor() + "<shape type='cube'/>")
    assert main(["render", str(path), "-o", str(tmp_path / "d.exr")]) == 2
    assert "no emitter" in capsys.readouterr().err
    assert not (tmp_path / "d.exr").exists()


def test_info_and_scenes(capsys):
    assert main(["scenes"]) == 0
    assert "cornell-box" in capsys.readouterr().out
    assert main(["info", "cornell-box", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["triangles"] > 1000 and info["bvh"]["nodes"] > 0 and len(info["emitters"]) == 1


def test_console_script_bad_option_exits_non_zero_without_traceback():
    r = subprocess.run([sys.executable, "-m", "probvis.cli", "render", "quad-shadow", "--spp", "-3"],
                       capture_output=True, text=True)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "must be at least 1" in r.stderr


def test_images_are_signed_float32(tmp_path):
    from probvis.io import write_image

    img = np.array([[[-0.5, 0.0, 2.0]]])
    write_image(tmp_path / "n.exr", img)
    np.testing.assert_array_equal(read_exr(tmp_path / "n.exr"), img.astype(np.float32))


def test_occlusion_map_options_and_case_image(tmp_path, capsys):
    out, cases, stats = tmp_path / "o.exr", tmp_path / "cases.png", tmp_path / "s.json"
    code = main(["render", "quad-shadow", "-D", "res=16", "--spp", "2", "--shadow-rays", "2", "-o", str(out),
                 "--visibility", "occlusion-map", "--photons", "20000", "--neighbours", "16", "--radius", "0.2",
                 "--penumbra", "list", "--no-adaptive-photons", "--case-image", str(cases), "--stats", str(stats)])
    assert code == 0 and cases.stat().st_size > 0
    s = json.loads(stats.read_text())
    assert s["visibility"] == {"name": "occlusion-map", "photons": 20000, "neighbours": 16, "radius": 0.2,
                               "penumbra": "list", "adaptive_photons": False, "volumetric": True,
                               "verify": "auto", "cache": True}
    assert abs(sum(c["share"] for c in s["cases"].values()) - 1) < 1e-9
    assert s["estimator"]["list_length"]["max"] >= 2
    capsys.readouterr()
    for argv, message in ((["--photons", "5"], "does not apply to --visibility exact"),
                          (["--case-image", str(tmp_path / "c.png")], "--case-image needs"),
                          (["--visibility", "occlusion-map", "--estimator", "shifted"],
                           "--estimator does not apply to --visibility occlusion-map (it is an option of probvis")):
        assert main(["render", "quad-shadow", "-o", str(out)] + argv) == 2
        assert message in capsys.readouterr().err


def _stats_of(argv, tmp_path):
    stats = tmp_path / "s.json"
    assert main(argv + ["-o", str(tmp_path / "d.exr"), "--stats", str(stats), "-q"]) == 0
    return json.loads(stats.read_text())


def test_defines_set_any_scene_parameter_and_explicit_flags_win(tmp_path):
    """-D spp / shadow_rays / seed / res work as in Mitsuba on an XML scene that declares them and on a built-in
    scene; --spp, --shadow-rays and --seed win over -D."""
    defaults = ('<default name="spp" value="8"/><default name="sr" value="8"/><default name="res" value="20"/>'
                '<default name="seed" value="0"/>')
    body = sensor(spp="$spp", sr="$sr", w="$res", h="$res").replace(
        '<integer name="sample_count" value="$spp"/>',
        '<integer name="sample_count" value="$spp"/><integer name="seed" value="$seed"/>') + """
        <shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><bsdf type="diffuse"/></shape>
        <shape type="rectangle"><transform name="to_world"><rotate x="1" angle="180"/><translate z="1"/></transform>
            <emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"""
    xml = write_scene(tmp_path / "d.xml", body, defaults)
    for scene, rays in ((str(xml), "sr"), ("quad-shadow", "shadow_rays")):
        s = _stats_of(["render", scene, "-D", "res=12", "-D", "spp=2", "-D", f"{rays}=3", "-D", "seed=7"], tmp_path)
        assert (s["width"], s["height"], s["spp"], s["shadow_rays_per_sample"], s["seed"]) == (12, 12, 2, 3, 7), scene
        s = _stats_of(["render", scene, "-D", "res=12", "-D", "spp=2", "--spp", "3", "--shadow-rays", "1",
                       "--seed", "9"], tmp_path)
        assert (s["spp"], s["shadow_rays_per_sample"], s["seed"]) == (3, 1, 9), scene


def test_defines_on_a_shared_scene(shared, tmp_path):
    """The usage ../shared/README.md documents: 32x32 at 2 spp x 2 shadow rays."""
    s = _stats_of(["render", str(shared / "scenes" / "cornell-bunny.xml"), "-D", "res=32", "-D", "spp=2",
                   "-D", "shadow_rays=2"], tmp_path)
    assert (s["width"], s["height"], s["spp"], s["shadow_rays_per_sample"]) == (32, 32, 2, 2)


def test_unknown_define_on_an_xml_scene_is_a_warning(tmp_path, capsys):
    xml = write_scene(tmp_path / "w.xml", sensor() + """
        <shape type="rectangle"><bsdf type="diffuse"/></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="0.3"/><rotate x="1" angle="180"/>
            <translate z="1"/></transform><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""")
    assert main(["render", str(xml), "-D", "spp=2", "-o", str(tmp_path / "w.exr"), "-q"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "-D spp: the scene declares no such parameter" in err[0]
    assert err[0].endswith("; for the render's own setting give --spp 2")  # what was meant, most likely


@pytest.mark.parametrize("define, warned", [("a=0.5", True), ("ab=0.5", False)])
def test_a_define_that_no_value_reads_is_a_warning(tmp_path, capsys, define, warned):
    """`$ab` reads the parameter `ab`, not `a` then 'b': `-D a` changes nothing, which Mitsuba refuses."""
    xml = write_scene(tmp_path / "w.xml", "<default name='a' value='0.1'/><default name='ab' value='0.9'/>" + sensor()
                      + """<shape type="rectangle"><bsdf type="diffuse"><rgb name="reflectance" value="$ab"/></bsdf>
        </shape><shape type="rectangle"><transform name="to_world"><scale value="0.3"/><rotate x="1" angle="180"/>
            <translate z="1"/></transform><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""")
    assert main(["render", str(xml), "-D", define, "-o", str(tmp_path / "w.exr"), "-q"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ([f"probvis: warning: {xml}: -D a: the scene declares it but no value reads it ($name reads the "
                    "longest declared name), so the image is the same without"] if warned else [])


def test_estimators_lists_every_estimator_with_its_options(capsys):
    assert main(["estimators", "--json"]) == 0
    listed = {d["name"]: d for d in json.loads(capsys.readouterr().out)}
    assert set(listed) >= {"exact", "occlusion-map", "probvis"}
    flags = {o["flag"] for o in listed["probvis"]["options"]}
    assert {"--estimator", "--grouping", "--photons", "--adaptive-photons"} <= flags and "--penumbra" not in flags
    assert listed["exact"]["render_path"].startswith("The integrator's fused kernel")
    assert listed["probvis"]["render_path"].startswith("Its own kernel") and [o["flag"] for o in listed["exact"]["options"]] == [
        "--shells", "--min-triangles", "--cache"]
    assert [a["name"] for a in listed["occlusion-map"]["aovs"]] == ["cases"]
    assert {p["name"] for p in listed["probvis"]["phases"]} >= {"photons", "lookup", "grouping"}


def test_first_run_says_it_compiles_kernels(tmp_path, capsys, monkeypatch):
    """On a cold kernel cache the CLI says so before compiling (here the cache is warm: pretend it is not)."""
    from probvis import warm_up

    monkeypatch.setattr(warm_up, "cold_cache", lambda: True)
    monkeypatch.setattr(warm_up, "_warmed", set())
    assert main(["render", "quad-shadow", "-D", "res=8", "-o", str(tmp_path / "c.exr")]) == 0
    said = f"probvis: compiling kernels (first run only: {warm_up.COMPILE_TIME} on 2 cores)"
    assert said in capsys.readouterr().err
    monkeypatch.setattr(warm_up, "_warmed", set())
    assert main(["render", "quad-shadow", "-D", "res=8", "-o", str(tmp_path / "c.exr"), "-q"]) == 0
    assert "compiling" not in capsys.readouterr().err  # -q: nothing


@pytest.mark.parametrize("flags, expect", [([], "auto"), (["--shells"], "on"), (["--shells", "off"], "off"),
                                           (["--shells=auto"], "auto"), (["--no-shells"], "off"),
                                           (["--shells", "yes"], "on")])
def test_shells_is_a_tri_state_flag(tmp_path, flags, expect):
    stats = tmp_path / "s.json"
    code = main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "--shadow-rays", "1", "-o",
                 str(tmp_path / "o.exr"), "--stats", str(stats), *flags])
    assert code == 0 and json.loads(stats.read_text())["visibility"]["shells"] == expect


@pytest.mark.parametrize("flags", [["--shells", "maybe"], ["--shells=2"], ["--visibility", "proxy", "--shells", "x"]])
def test_a_bad_shells_value_is_one_line_naming_it(tmp_path, capsys, flags):
    code = main(["render", "quad-shadow", "-D", "res=8", "-o", str(tmp_path / "o.exr"), *flags])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "shells expects auto | on | off" in err
    assert not (tmp_path / "o.exr").exists()
    with pytest.raises(ProbvisError, match=re.escape("shells expects auto | on | off, got 'maybe'")):
        probvis.render("quad-shadow", visibility_options={"shells": "maybe"})


def test_exposure_without_a_png_is_said_to_be_ignored(tmp_path, capsys):
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "--exposure", "2", "-q",
                 "-o", str(tmp_path / "o.exr")]) == 0
    assert "--exposure applies to PNG outputs only" in capsys.readouterr().err
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "--exposure", "2", "-q",
                 "-o", str(tmp_path / "o.png")]) == 0
    assert "--exposure" not in capsys.readouterr().err


def test_an_output_that_is_one_of_the_scene_s_inputs_is_refused(tmp_path, capsys):
    from probvis.io import write_exr

    texture = tmp_path / "wood.exr"
    write_exr(texture, np.full((4, 4, 3), 0.5, np.float32))
    before = texture.read_bytes()
    body = sensor(w=8, h=8, sr=1) + """<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap"
        name="reflectance"><string name="filename" value="wood.exr"/></texture></bsdf></shape>
        <emitter type="point"><point name="position" x="0" y="0" z="3"/><rgb name="intensity" value="5"/></emitter>"""
    path = write_scene(tmp_path / "s.xml", body)
    assert main(["render", str(path), "--spp", "1", "-q", "-o", str(tmp_path / "out.png"), "-o", str(texture)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the scene reads this file" in err[0] and "wood.exr" in err[0], err
    assert texture.read_bytes() == before and not (tmp_path / "out.png").exists()
    result = probvis.render(str(path), spp=1)
    assert result.stats["inputs"] == [str(path.resolve()), str(texture.resolve())]


def _two_lights(tmp_path):
    """A textured floor under two area lights (so --case-image writes NAME-e0.png and NAME-e1.png)."""
    from probvis.io import write_png

    write_png(tmp_path / "tex.png", np.full((4, 4, 3), 0.5))
    light = """<shape type="rectangle"><transform name="to_world"><scale value="{s}"/><rotate x="1" angle="180"/>
        <translate x="{x}" z="1.5"/></transform><emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>"""
    body = sensor(w=8, h=8) + """<shape type="rectangle"><bsdf type="diffuse"><texture type="bitmap"
        name="reflectance"><string name="filename" value="$tex"/></texture></bsdf></shape>
        <shape type="cube"><transform name="to_world"><scale value="0.2"/><translate z="0.5"/></transform></shape>
        """ + light.format(s=0.3, x=0) + light.format(s=0.2, x=0.8)
    return write_scene(tmp_path / "two.xml", body, '<default name="tex" value="tex.png"/>')


@pytest.mark.parametrize("setup, message", [
    ("texture", "--case-image c.png (c-e0.png): the scene reads this file"),
    ("link to output", "with several emitters it writes c-e0.png, the same file as -o o.png"),
    ("link to texture", "--case-image c.png (c-e1.png): the scene reads this file"),
    ("folder", "cannot write 'c-e1.png': it is a folder"),
])
def test_each_emitter_s_case_image_is_planned_like_any_output(tmp_path, monkeypatch, capsys, setup, message):
    """With several emitters --case-image writes NAME-e<k>.ext: those files get every output check (a scene
    input, a link to another output or an input, a folder), and nothing is written when one fails."""
    import os

    scene = _two_lights(tmp_path)
    monkeypatch.chdir(tmp_path)
    defines = []
    if setup == "texture":
        (tmp_path / "c-e0.png").write_bytes((tmp_path / "tex.png").read_bytes())
        defines = ["-D", "tex=c-e0.png"]
    elif setup == "link to output":
        os.symlink("o.png", "c-e0.png")
    elif setup == "link to texture":
        os.symlink("tex.png", "c-e1.png")
    else:
        os.mkdir("c-e1.png")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    assert main(["render", str(scene), "--visibility", "occlusion-map", "--photons", "1000", "--spp", "1",
                 "--shadow-rays", "1", "-q", "--case-image", "c.png", "-o", "o.png", *defines]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    assert not (tmp_path / "o.png").exists()


def test_outputs_are_committed_all_or_none(tmp_path, monkeypatch):
    """`staged_writes`: when a later rename fails, the earlier ones are undone (a replaced file gets its old
    content back, a new one is removed)."""
    import os

    from probvis.io import atomic, image

    old = tmp_path / "a.png"
    old.write_bytes(b"old")
    real = os.replace

    def failing(src, dst):
        if str(dst).endswith("b.png"):
            raise OSError(28, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(atomic.os, "replace", failing)
    with pytest.raises(ProbvisError, match="cannot write '.*b.png': No space left on device"):
        with atomic.staged_writes():
            for name in ("a.png", "new.png", "b.png"):
                image.write_png(tmp_path / name, np.full((2, 2, 3), 0.5))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"] and old.read_bytes() == b"old"


def test_a_one_emitter_case_image_ignores_per_emitter_names(tmp_path, monkeypatch):
    """With one emitter --case-image writes NAME itself: a folder named NAME-e0.png beside it is no reason to
    refuse (it was, before the render)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "c-e0.png").mkdir()
    assert main(["render", "quad-shadow", "-D", "res=8", "--visibility", "occlusion-map", "--photons", "1000",
                 "--spp", "1", "--shadow-rays", "1", "-q", "--case-image", "c.png", "-o", "o.exr"]) == 0
    assert (tmp_path / "c.png").is_file() and (tmp_path / "c-e0.png").is_dir()


def test_output_names_of_any_bytes_and_length_the_file_system_takes(tmp_path, capsys):
    """A name of 250 bytes is written (the temporary file beside it has a short name of its own); a name that is
    not UTF-8 is written as PNG, and refused before the render as EXR, whose writer takes UTF-8 only."""
    import os

    long_name = tmp_path / ("a" * 246 + ".png")
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "-o", str(long_name), "-q"]) == 0
    assert long_name.is_file()
    odd = os.fsdecode(bytes(tmp_path) + b"/\xff\xfe")
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "-o", odd + ".png", "--stats",
                 odd + ".json", "-q"]) == 0
    assert os.path.isfile(odd + ".png") and os.path.isfile(odd + ".json")
    capsys.readouterr()
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "-o", odd + ".exr", "-q"]) == 2
    assert "OpenEXR's writer takes only file and folder names in UTF-8" in capsys.readouterr().err
    assert not os.path.exists(odd + ".exr") and not list(tmp_path.glob(".*"))


def test_a_long_case_image_name_of_a_one_emitter_scene_is_written(tmp_path):
    """With one emitter the case image is written under the name given (a check of NAME-e99 refused it)."""
    name = tmp_path / ("c" * 250 + ".exr")
    assert main(["render", "quad-shadow", "-D", "res=8", "--spp", "1", "--visibility", "occlusion-map", "--photons",
                 "2000", "-o", str(tmp_path / "o.exr"), "--case-image", str(name), "-q"]) == 0
    assert name.is_file()


def test_a_huge_value_quoted_in_an_error_keeps_the_line_readable(tmp_path, capsys):
    """A value of a megabyte (legal in size) was quoted whole: a one-line error of 50 MB."""
    from tests.conftest import sensor, write_scene

    body = sensor().replace('<float name="fov"', '<string name="fov_axis" value="$axis"/><float name="fov"', 1)
    path = write_scene(tmp_path / "s.xml", body, f"<default name='axis' value='{'x' * 1_000_000}'/>")
    assert main(["render", str(path), "-o", str(tmp_path / "o.exr"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and len(err) < 2200
    assert err.startswith(f"probvis: error: {path}:") and "characters ...]" in err and err.rstrip().endswith(")")


def test_the_command_skips_numba_s_blas_probe_and_nothing_else():
    """The console command's import hook keeps Numba's start-up BLAS probe from loading scipy.linalg (0.13 s of
    every start); scipy.linalg imported afterwards loads, and a kernel's linear algebra still finds BLAS."""
    code = ("import sys\n"
            "from probvis import __main__ as entry\n"
            "sys.meta_path.insert(0, entry._NoBlasProbe())\n"
            "import numba.np.arraymath as am\n"
            "print(am._HAVE_BLAS, 'scipy.linalg' in sys.modules)\n"
            "import scipy.linalg\n"
            "import numba, numpy as np\n"
            "print(float(numba.njit(lambda a: np.dot(a, a))(np.arange(3.0))))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "False", "5.0"]
