"""The splatting film against Mitsuba 3 at equal samples, and what splatting costs, run by hand:
`python3 bench/bench_films.py [--spp 16] [--res 128] [--ref-spp 1024] [--runs 5] [--variant scalar_rgb]`.

Scenes (written to a temporary folder, from ../shared):
- `cornell-bunny.xml` with its film's filter replaced by a tent (radius 1) and by Mitsuba's default Gaussian;
- a teapot on a checkerboard floor under a generated sky environment map (a sun blob over a gradient), with
  the default Gaussian: the case of a Mitsuba tutorial scene with an envmap; once more with a box filter, which
  isolates the environment's sampling from the film.

For each: relMSE against Mitsuba's reference at `--ref-spp` of probvis and of Mitsuba at `--spp` (two seeds
each, one shadow ray per camera sample, as Mitsuba's `direct` with one emitter sample), their ratio, and the image
means' ratio. Then the cost: probvis's render phase (stats seconds.render) with the scene's filter against the
same scene with a box filter, `--runs` runs interleaved, medians and their ratio; and, steadier on a shared
machine, the film's own seconds (stats film.seconds) in each: the box render plus the splat's extra time.
"""
import argparse
import re
import statistics
import tempfile
from pathlib import Path

import numpy as np

import probvis
from probvis.io.image import write_exr

SHARED = Path(__file__).resolve().parents[2] / "shared"


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def with_filter(text, rfilter):
    return re.sub(r"<rfilter[^>]*/>|<rfilter\b.*?</rfilter>", rfilter, text, count=1, flags=re.S)


def sky(path, w=256, h=128):
    """An equirectangular sky: a gradient from a bright horizon to a blue zenith, a small bright sun."""
    theta = (np.arange(h) + 0.5) / h * np.pi
    phi = (np.arange(w) + 0.5) / w * 2 * np.pi
    t, p = np.meshgrid(theta, phi, indexing="ij")
    up = np.clip(np.cos(t), 0.0, 1.0)[..., None]
    img = (1 - up) * np.array([1.0, 0.95, 0.85]) + up * np.array([0.3, 0.5, 1.0])
    img *= np.where(t[..., None] < np.pi / 2, 1.0, 0.2)
    sun = np.exp(-((t - 0.7) ** 2 + (p - 1.2) ** 2) / (2 * 0.05 ** 2))[..., None] * 400.0
    write_exr(str(path), (img + sun).astype(np.float32))


def teapot_scene(folder, spp, res):
    sky(folder / "sky.exr")
    return f"""<?xml version="1.0"?><scene version="3.0.0">
<default name="spp" value="{spp}"/><default name="res" value="{res}"/>
<integrator type="direct"><integer name="emitter_samples" value="1"/><integer name="bsdf_samples" value="0"/></integrator>
<sensor type="perspective"><float name="fov" value="40"/>
  <transform name="to_world"><lookat origin="0, 2.5, 5" target="0, 0.5, 0" up="0, 1, 0"/></transform>
  <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
  <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film></sensor>
<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>
<shape type="obj"><string name="filename" value="{SHARED / 'data/meshes/teapot.obj'}"/>
  <transform name="to_world"><scale value="0.35"/></transform>
  <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.3, 0.2"/></bsdf></shape>
<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="-90"/><scale value="8"/></transform>
  <bsdf type="diffuse"><texture type="checkerboard" name="reflectance"><rgb name="color0" value="0.2"/>
  <rgb name="color1" value="0.7"/><transform name="to_uv"><scale value="8"/></transform></texture></bsdf></shape>
</scene>"""


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--variant", default="scalar_rgb")
    args = ap.parse_args()
    import mitsuba as mi

    mi.set_variant(args.variant)
    folder = Path(tempfile.mkdtemp(prefix="bench-films-"))
    bunny = (SHARED / "scenes/cornell-bunny.xml").read_text().replace(
        'value="$shadow_rays"', 'value="1"').replace("../data/", f"{SHARED}/data/")
    scenes = {"cornell-bunny tent": with_filter(bunny, '<rfilter type="tent"/>'),
              "cornell-bunny gaussian": with_filter(bunny, '<rfilter type="gaussian"/>'),
              "teapot envmap gaussian": teapot_scene(folder, args.spp, args.res)}
    scenes["teapot envmap box"] = scenes["teapot envmap gaussian"].replace("</film>", '<rfilter type="box"/></film>')
    print(f"probvis {probvis.__version__}, Mitsuba {mi.__version__} {args.variant}; {args.res}x{args.res}, "
          f"{args.spp} spp x 1 emitter sample, reference {args.ref_spp} spp")
    for name, text in scenes.items():
        path = folder / (name.replace(" ", "-") + ".xml")
        path.write_text(text)
        box = folder / (name.replace(" ", "-") + "-box.xml")
        box.write_text(re.sub(r"</film>", '<rfilter type="box"/></film>', text, count=1)
                       if "<rfilter" not in text else with_filter(text, '<rfilter type="box"/>'))

        def mitsuba(spp, seed):
            scene = mi.load_file(str(path), spp=spp, res=args.res)
            return np.array(mi.render(scene, seed=seed, spp=spp), dtype=np.float64)

        ref = mitsuba(args.ref_spp, 100)
        theirs = [relmse(mitsuba(args.spp, s), ref) for s in (1, 2)]
        ours = [probvis.render(path, spp=args.spp, shadow_rays=1, seed=s, defines={"res": str(args.res)})
                for s in (1, 2)]
        fis = probvis.render(path, spp=args.spp, shadow_rays=1, seed=1, defines={"res": str(args.res)},
                             filter_importance=True)
        r_ours = float(np.mean([relmse(r.image, ref) for r in ours]))
        means = ours[0].image.reshape(-1, 3).mean(0) / ref.reshape(-1, 3).mean(0)
        print(f"{name}: relMSE probvis {r_ours:.5f}, Mitsuba {np.mean(theirs):.5f}: {r_ours / np.mean(theirs):.2f}x "
              f"(filter importance sampling {relmse(fis.image, ref) / np.mean(theirs):.2f}x); image mean ratio "
              f"{', '.join(f'{m:.4f}' for m in means)}")
        if "box" in name:
            continue
        secs = {"filter": [], "box": [], "film filter": [], "film box": []}
        for _ in range(args.runs):
            for kind, p in (("filter", path), ("box", box)):
                r = probvis.render(p, spp=args.spp, shadow_rays=1, seed=1, defines={"res": str(args.res)})
                secs[kind].append(r.stats["seconds"]["render"])
                secs["film " + kind].append(r.stats["film"]["seconds"])
        med = {k: statistics.median(v) for k, v in secs.items()}
        print(f"  render phase, median of {args.runs} interleaved: splatting {med['filter']:.3f} s, box "
              f"{med['box']:.3f} s: {med['filter'] / med['box']:.2f}x; of it the film {med['film filter']:.3f} s "
              f"and {med['film box']:.3f} s: box + the splat's extra = "
              f"{(med['box'] + med['film filter'] - med['film box']) / med['box']:.2f}x")


if __name__ == "__main__":
    main()
