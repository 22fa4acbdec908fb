"""Mitsuba 3's tutorial scenes through probvis, run by hand:
`python3 bench/bench_tutorial_scenes.py DIR [--spp 16] [--res 128] [--ref-spp 1024]`.

DIR holds the tutorials' `cbox.xml` and `simple.xml` with their `meshes/` (a clone of mitsuba-tutorials'
`scenes/`). For each scene:

1. probvis loads the file unchanged; the warnings it gives (what it approximates) are printed.
2. Its direct illumination is compared with Mitsuba's at equal settings (`scalar_rgb`, the scene with its
   integrator replaced by `direct`, one emitter sample, no BSDF samples; one shadow ray in probvis): relMSE
   against a Mitsuba reference at `--ref-spp`, next to Mitsuba's own noise (two seeds at `--spp`). The
   comparison is made twice: on the scene as written (approximated BSDFs differ by construction) and on a
   copy where every approximated BSDF is replaced, for both renderers, by the diffuse colour probvis chose
   ("appearance inside the subset"), and where the film has a tent or gaussian filter once more with a box
   filter in both: probvis samples the filter (pbrt-v4's filter importance sampling, unbiased, one pixel per
   sample) where Mitsuba splats each sample into its neighbours, which is less noisy across a visible
   emitter's edge.
"""
import argparse
import re
import sys
import time
import warnings
from pathlib import Path

import numpy as np

import probvis

DIRECT = ('<integrator type="direct"><integer name="emitter_samples" value="1"/>'
          '<integer name="bsdf_samples" value="0"/></integrator>')
APPROXIMATED = re.compile(r"bsdf '(\w+)' rendered as diffuse with reflectance ([\d.e+-]+), ([\d.e+-]+), ([\d.e+-]+)")


def relmse(x, ref):
    return float(np.mean((x - ref) ** 2 / (ref ** 2 + 0.01)))


def variant(path, text, tag):
    """A copy of the scene beside it (so relative mesh paths hold) with `text` as its content."""
    out = path.with_name(f".bench-{tag}-{path.name}")
    out.write_text(text)
    return out


def as_direct(text):
    text = re.sub(r"<integrator\b[^>]*?/>|<integrator\b[^>]*>.*?</integrator>", DIRECT, text, count=1, flags=re.S)
    return re.sub(r'<default name="integrator"[^>]*/>', "", text)


def as_diffuse(text, colours):
    """Every approximated BSDF element replaced by a diffuse one of probvis's colour."""
    for kind, rgb in colours.items():
        text = re.sub(rf'<bsdf type="{kind}"([^>]*?)/>', rf'<bsdf type="diffuse"\1><rgb name="reflectance" '
                                                          rf'value="{rgb}"/></bsdf>', text)
    return text


def compare(mi, path, spp, res, ref_spp):
    ref = np.array(mi.render(mi.load_file(str(path), spp=ref_spp, res=res), seed=100, spp=ref_spp), float)
    noise = [relmse(np.array(mi.render(mi.load_file(str(path), spp=spp, res=res), seed=s, spp=spp), float), ref)
             for s in (1, 2)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        ours = probvis.render(str(path), spp=spp, shadow_rays=1, seed=1, resolution=(res, res)).image
        t = time.perf_counter() - t
    err = relmse(ours, ref)
    mean_ratio = ours.reshape(-1, 3).mean(0) / np.maximum(ref.reshape(-1, 3).mean(0), 1e-12)
    return err, float(np.mean(noise)), mean_ratio, t


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--ref-spp", type=int, default=1024)
    args = ap.parse_args()
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    print(f"probvis {probvis.__version__}, Mitsuba {mi.__version__} scalar_rgb; {args.res}x{args.res}, "
          f"{args.spp} spp x 1 emitter sample, reference {args.ref_spp} spp")
    for name in ("cbox.xml", "simple.xml"):
        path = args.folder / name
        if not path.is_file():
            print(f"{name}: not in {args.folder}, skipped")
            continue
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t = time.perf_counter()
            scene = probvis.load_scene(path)
            t = time.perf_counter() - t
        print(f"\n{name}: loaded unchanged in {t:.2f} s, {scene.n_triangles} triangles, {scene.n_emitters} emitters")
        for w in caught:
            print(f"  warning: {w.message}")
        colours = {m.group(1): f"{m.group(2)}, {m.group(3)}, {m.group(4)}"
                   for w in caught for m in [APPROXIMATED.search(str(w.message))] if m}
        text = path.read_text()
        copies = [("as written", variant(path, as_direct(text), "direct"))]
        if colours:
            diffuse = as_diffuse(as_direct(text), colours)
            copies.append(("approximated BSDFs as probvis's diffuse in both", variant(path, diffuse, "diffuse")))
            if re.search(r'<rfilter type="(tent|gaussian)"', diffuse):
                copies.append(("... and a box filter in both", variant(
                    path, re.sub(r'<rfilter type="(tent|gaussian)"', '<rfilter type="box"', diffuse), "box")))
        try:
            for label, copy in copies:
                err, noise, ratio, t = compare(mi, copy, args.spp, args.res, args.ref_spp)
                print(f"  {label}: relMSE {err:.4f} vs Mitsuba's noise {noise:.4f} = {err / noise:.2f}x; "
                      f"image mean ratio {', '.join(f'{r:.4f}' for r in ratio)}; probvis render {t:.2f} s")
        finally:
            for _, copy in copies:
                copy.unlink(missing_ok=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
