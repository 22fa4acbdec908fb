"""The study's report: a self-contained folder with `index.html`, images, plots, `results.csv`, `results.json` and
`results.md`.

The page uses no network resource: images are PNG files beside it, the interactive comparison's float images
are float16 data in `data/*.js` files loaded by plain script tags (so the page also works from file://), and
the viewer's script and style are copied from the package.
"""
import base64
import csv
import html
import io
import json
import logging
import math
import os
import shutil
import sys
import warnings
from importlib import resources
from pathlib import Path

import numpy as np

from ..errors import ProbvisError, checked_call, expect_record, is_path
from ..io.atomic import atomic_path, staged_writes
from ..io.image import tonemap_srgb, utf8_path, write_png
from .config import MADE_BY, Experiment, file_stem
from .results import UNSTEADY, Results
from .runner import RunSummary

STATIC = ("viewer.js", "report.css")
NAME_MAX = 255  # bytes in a file name: what Linux's and macOS's file systems hold
REPORT_TITLE = "probvis experiment: "  # how its index.html begins: a folder holding another index.html is not replaced
SECONDS_NOTE = {"total": "", "render": " and without scene loading and BVH building (seconds = render)"}


def _write_text(path, text):
    with atomic_path(path) as tmp:  # a name of other bytes than UTF-8 (the command's file) shows as \xff escapes
        Path(tmp).write_text(text, encoding="utf-8", errors="backslashreplace")


def _fmt(x, digits=3):
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    if isinstance(x, float) and math.isinf(x):
        return "∞"
    if isinstance(x, int) or abs(x) >= 1000:  # counts, and their means over seeds
        return f"{round(x):,}"
    return f"{x:.{digits}g}"


def _change(x):
    return "–" if x is None else f"{x:+.1%}".replace("-", "−")


def _finite(obj):
    """`obj` with infinities (efficiency at zero error) and NaN (a ratio of two of them: a reference equal to a
    render) replaced by None: JSON has neither."""
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return None if isinstance(obj, float) and not math.isfinite(obj) else obj


def _pyplot():
    """matplotlib's pyplot on the Agg backend, whatever the environment says: the report draws PNG files only, so
    MPLBACKEND (which matplotlib validates as it loads: a bogus one is a ValueError) is set aside while it loads,
    and its logger's notes about an unusable MPLCONFIGDIR (it falls back to a temporary folder) are not shown."""
    backend = None
    if "matplotlib" not in sys.modules:
        logging.getLogger("matplotlib").setLevel(logging.ERROR)
        backend = os.environ.pop("MPLBACKEND", None)
    try:
        import matplotlib
    finally:
        if backend is not None:
            os.environ["MPLBACKEND"] = backend
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _bias(r):
    """The block-bias ratio of a summary row, marked where the method is biased by choice."""
    text = "–" if r["bias_ratio"] is None else _fmt(r["bias_ratio"], 2)
    return text + (" (biased)" if r["biased"] else "")


def _summary_cells(r, baseline):
    """A summary row's seconds, tests, relMSE, bias and efficiency as the paper-style table shows them."""
    mark = "†" if r["timing_unsteady"] else ""
    if baseline:
        return (f"{r['seconds']:.2f}{mark}", _fmt(r["triangle_tests"]), _fmt(r["relmse"]), _bias(r),
                _fmt(r["efficiency_time"]))
    return (f"{r['seconds']:.2f}{mark} ({_change(r['seconds_change'])})",
            f"{_fmt(r['triangle_tests'])} ({_change(r['tests_change'])})", _fmt(r["relmse"]), _bias(r),
            f"{_fmt(r['efficiency_time'])} (×{_fmt(r['efficiency_vs_baseline'], 2)})")


def _mib(n):
    return "–" if not n else f"{n / 2 ** 20:.1f} MiB"


def _geometry_cells(r):
    """A summary row's shadow-ray tests split by geometry (scene / proxy nodes and triangles, voxels walked in
    the shells' and the extinction grid) and the memory of the estimator's own structures beside the scene
    BVH's."""
    split = r["tests_by_geometry"]
    return (f"{_fmt(split['scene']['node'])} / {_fmt(split['proxy']['node'])}",
            f"{_fmt(split['scene']['triangle'])} / {_fmt(split['proxy']['triangle'])}",
            f"{_fmt(split['shell_voxels'])} / {_fmt(split['volume_voxels'])}", _mib(r["estimator_bytes"]),
            _mib(r["scene_bvh_bytes"]))


GEOMETRY_HEAD = ("method", "node tests (scene / proxy)", "triangle tests (scene / proxy)",
                 "voxels walked (shells / volume)",
                 "own memory", "scene BVH")
GEOMETRY_NOTE = ("Shadow-ray tests by the geometry they test (the scene's BVH — with shells, also the BVH of the "
                 "scene without its heavy meshes —, the proxies', and the voxels the walks of the shells' grid and "
                 "of volumetric proxies' extinction grid visited, which the tests columns elsewhere do not count; "
                 "means over seeds) and the bytes of the estimator's own structures as built (proxies and their "
                 "BVH, extinction grids, shells' grid and BVH, photons and kd-trees) beside the scene BVH's that "
                 "every method shares.")


def repeats_note(exp):
    """'3 repeats' or 'up to 5 repeats (fewer once they took 1 s together)': how a cell's seconds were taken."""
    n = exp.timing_repeats
    if n == 1 or exp.timing_seconds == math.inf:
        return f"{n} repeat{'s' if n > 1 else ''}"
    return f"up to {n} repeats (fewer once they took {exp.timing_seconds:g} s together)"


class Report:
    """Writes the report of one measured study into `folder`."""

    def __init__(self, exp, run, results, folder, command=""):
        self.exp, self.run, self.results, self.command = exp, run, results, command
        self.folder = Path(folder)
        self.seed = exp.seeds[0]
        self.images = {(t.scene, t.method.name, t.shadow_rays): run.renders[t.key] for t in run.tasks
                       if t.seed == self.seed}

    def write(self):
        _pyplot()  # matplotlib loaded for the PNG plots, whatever MPLBACKEND says
        for sub in ("images", "plots", "data"):
            (self.folder / sub).mkdir(parents=True, exist_ok=True)
        for name in STATIC:
            with atomic_path(self.folder / name) as tmp:
                shutil.copyfile(resources.files(__package__).joinpath(name), tmp)
        for spec in self.exp.scenes:
            self._scene_images(spec.name)
            self._viewer_data(spec.name)
            self._heat_maps(spec.name)
            self._convergence_plot(spec.name)
            self._cost_plot(spec.name)
            self._strip_figure(spec.name)
        self._csv()
        self._json()
        _write_text(self.folder / "results.md", self._markdown())
        _write_text(self.folder / "index.html", self._html())
        return self.folder / "index.html"

    # --- files -------------------------------------------------------------------------------------------
    @staticmethod
    def _image_path(scene, method=None, rays=None):
        name = "reference" if method is None else f"{file_stem(method)}-{rays}"
        return f"images/{file_stem(scene)}/{name}.png"

    def _scene_images(self, scene):
        (self.folder / "images" / file_stem(scene)).mkdir(exist_ok=True)
        write_png(self.folder / self._image_path(scene), self.run.reference_images[scene])
        for (s, m, rays), r in self.images.items():
            if s == scene:
                write_png(self.folder / self._image_path(scene, m, rays), r.image)

    def _viewer_data(self, scene):
        ref = self.run.reference_images[scene]
        h, w = ref.shape[:2]

        def enc(img):
            return base64.b64encode(np.asarray(img, dtype="<f2").tobytes()).decode()

        images = {"reference": enc(ref)}
        for (s, m, rays), r in self.images.items():
            if s == scene:
                images[f"{m}@{rays}"] = enc(r.image)
        payload = {"width": w, "height": h, "methods": [m.name for m in self.exp.methods],
                   "shadowRays": list(self.exp.shadow_rays), "images": images}
        _write_text(self.folder / "data" / f"{file_stem(scene)}.js",
                    f"window.PROBVIS_DATA = window.PROBVIS_DATA || {{}};\n"
                    f"window.PROBVIS_DATA[{json.dumps(scene)}] = {json.dumps(payload)};\n")

    def _savefig(self, fig, path):
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
        _pyplot().close(fig)
        with atomic_path(path) as tmp:
            Path(tmp).write_bytes(buf.getvalue())

    def _heat_maps(self, scene):
        """Per-pixel ray-triangle tests of every method at each shadow-ray count, one shared log colour scale."""
        from matplotlib.colors import LogNorm

        plt = _pyplot()

        methods, rays = self.exp.methods, self.exp.shadow_rays
        for sr in rays:
            maps = [self.images[(scene, m.name, sr)].tests for m in methods]
            hi = max(1.0, max(float(t.max()) for t in maps))
            fig, axes = plt.subplots(1, len(methods), figsize=(2.2 * len(methods) + 0.8, 2.6), squeeze=False)
            for ax, m, t in zip(axes[0], methods, maps):
                im = ax.imshow(np.maximum(t, 1.0), norm=LogNorm(1.0, hi), cmap="inferno")
                ax.set_title(f"{m.name}\nmean {t.mean():,.0f}", fontsize=8)
                ax.axis("off")
            fig.colorbar(im, ax=axes[0].tolist(), shrink=0.8, label="ray–triangle tests / pixel")
            fig.suptitle(f"{scene}: {sr} shadow ray{'s' if sr > 1 else ''} per camera sample", fontsize=9)
            self._savefig(fig, self.folder / "plots" / f"{file_stem(scene)}-tests-{sr}.png")

    def _convergence_plot(self, scene):
        fig, axes = _pyplot().subplots(1, 2, figsize=(10, 3.8))
        for m in self.exp.methods:
            rows = sorted((r for r in self.results.summary if r["scene"] == scene and r["method"] == m.name),
                          key=lambda r: r["shadow_rays"])
            for ax, key in zip(axes, ("seconds", "triangle_tests")):
                ax.loglog([r[key] for r in rows], [r["relmse"] for r in rows], marker="o", ms=3, label=m.name)
        target = self.results.targets[scene]["target_relmse"]
        for ax, label in zip(axes, ("render seconds (JIT excluded)", "shadow-ray triangle tests")):
            ax.axhline(target, color="grey", lw=0.8, ls="--")
            ax.set_xlabel(label)
            ax.set_ylabel("relMSE")
            ax.grid(True, which="both", lw=0.3)
        axes[1].legend(fontsize=7)
        fig.suptitle(f"{scene}: relMSE against cost, {', '.join(map(str, self.exp.shadow_rays))} shadow rays",
                     fontsize=9)
        fig.tight_layout()
        self._savefig(fig, self.folder / "plots" / f"{file_stem(scene)}-convergence.png")

    def _cost_plot(self, scene):
        """Seconds per camera sample against shadow rays per sample, one line per method: where a method's
        savings in tests outweigh what it costs per segment, the lines cross."""
        fig, ax = _pyplot().subplots(figsize=(5, 3.6))
        height, width = self.images[(scene, self.exp.methods[0].name, self.exp.shadow_rays[0])].image.shape[:2]
        samples = height * width * self.exp.spp
        for m in self.exp.methods:
            rows = sorted((r for r in self.results.summary if r["scene"] == scene and r["method"] == m.name),
                          key=lambda r: r["shadow_rays"])
            ax.loglog([r["shadow_rays"] for r in rows], [1e6 * r["seconds"] / samples for r in rows], marker="o",
                      ms=3, label=m.name)
        ax.set_xlabel("shadow rays per camera sample")
        ax.set_ylabel("µs per camera sample")
        ax.grid(True, which="both", lw=0.3)
        ax.legend(fontsize=7)
        ax.set_title(f"{scene}: cost per camera sample ({self.exp.spp} spp)", fontsize=9)
        fig.tight_layout()
        self._savefig(fig, self.folder / "plots" / f"{file_stem(scene)}-cost.png")

    def _strip_figure(self, scene):
        """The image strips as one labelled PNG (methods x shadow rays, reference first), for papers and READMEs."""
        rays, methods = self.exp.shadow_rays, self.exp.methods
        fig, axes = _pyplot().subplots(len(methods), len(rays) + 1, figsize=(1.3 * (len(rays) + 1), 1.3 * len(methods)),
                                 squeeze=False, gridspec_kw={"wspace": 0.04, "hspace": 0.04})
        for i, m in enumerate(methods):
            for j in range(len(rays) + 1):
                ax = axes[i][j]
                ax.set_xticks([])
                ax.set_yticks([])
                if j == 0:
                    ax.imshow(tonemap_srgb(self.run.reference_images[scene]) if i == 0 else
                              np.ones((1, 1, 3)))
                    ax.set_ylabel(m.name, fontsize=7)
                    for side in ax.spines.values():
                        side.set_visible(i == 0)
                else:
                    ax.imshow(tonemap_srgb(self.images[(scene, m.name, rays[j - 1])].image))
                if i == 0:
                    ax.set_title("reference" if j == 0 else f"{rays[j - 1]} rays", fontsize=7)
        self._savefig(fig, self.folder / "plots" / f"{file_stem(scene)}-strip.png")

    def _csv(self):
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(self.results.cells[0]) if self.results.cells else [])
        w.writeheader()
        for r in self.results.cells:
            w.writerow({k: json.dumps(v) if isinstance(v, dict) else v for k, v in r.items()})
        _write_text(self.folder / "results.csv", buf.getvalue())

    def _json(self):
        exp = self.exp
        doc = {"experiment": {"name": exp.name, "description": exp.description, "spp": exp.spp,
                              "shadow_rays": list(exp.shadow_rays), "seeds": list(exp.seeds),
                              "baseline": exp.baseline, "resolution": exp.resolution,
                              "reference": vars(exp.reference), "command": self.command,
                              "scenes": [vars(s) for s in exp.scenes],
                              "methods": [vars(m) for m in exp.methods]},
               "cells": self.results.cells, "summary": self.results.summary, "targets": self.results.targets,
               "report_files": report_files(exp)}
        _write_text(self.folder / "results.json", json.dumps(_finite(doc), indent=1, allow_nan=False))

    def _markdown(self):
        """The paper-style table as Markdown, per scene and method at the table's shadow-ray count."""
        exp, rays = self.exp, self.exp.table_shadow_rays
        lines = [f"At {exp.spp} spp × {rays} shadow rays per camera sample; seconds exclude JIT compilation, tests "
                 f"are shadow-ray triangle tests, efficiency = 1/(relMSE × seconds); changes against "
                 f"{exp.baseline}; seconds = wall time of the render{SECONDS_NOTE[exp.seconds]} (the fastest of "
                 f"{repeats_note(exp)}, median over seeds; † = repeats or seeds differ by more than {UNSTEADY:.0%}), which "
                 f"efficiency uses; bias = block-bias ratio of two seeds (about 1: converges to the reference; "
                 f"'biased': a shortcut chosen by its options).", "",
                 "| scene | method | seconds | tests | relMSE | bias | efficiency (× baseline) |",
                 "|---|---|---:|---:|---:|---:|---:|"]
        for spec in exp.scenes:
            for m in exp.methods:
                r = self.results.summary_row(spec.name, m.name, rays)
                cells = _summary_cells(r, m.name == exp.baseline)
                lines.append(f"| {_md(spec.name)} | {_md(m.name)} | {' | '.join(cells)} |")
        lines += ["", GEOMETRY_NOTE, "", "| scene | " + " | ".join(GEOMETRY_HEAD) + " |",
                  "|---|---|---:|---:|---:|---:|---:|"]
        for spec in exp.scenes:
            for m in exp.methods:
                r = self.results.summary_row(spec.name, m.name, rays)
                lines.append(f"| {_md(spec.name)} | {_md(m.name)} | {' | '.join(_geometry_cells(r))} |")
        lines += ["", "## Ranking", ""] + self._ranking()
        return "\n".join(lines) + "\n"

    def _ranking(self):
        """Markdown lines ranking the methods by the geometric mean, over every scene and shadow-ray count, of
        their efficiency as a multiple of the baseline's; per cell that multiple (best in bold), the cells where
        the method is the most efficient, its worst block-bias ratio; then each scene's seconds to a target
        relMSE."""
        exp = self.exp
        cells = [(spec.name, sr) for spec in exp.scenes for sr in exp.shadow_rays]
        best = {c: max((self.results.summary_row(*c[:1], m.name, c[1])["efficiency_vs_baseline"] or 0.0)
                       for m in exp.methods) for c in cells}
        ranked = []
        for m in exp.methods:
            rows = [self.results.summary_row(s, m.name, sr) for s, sr in cells]
            eff = [r["efficiency_vs_baseline"] for r in rows]
            logs = [math.log(x) for x in eff if x is not None and x > 0 and math.isfinite(x)]
            gmean = math.exp(sum(logs) / len(logs)) if len(logs) == len(cells) else None
            wins = sum(1 for c, x in zip(cells, eff) if x is not None and x == best[c])
            biases = [r["bias_ratio"] for r in rows if r["bias_ratio"] is not None]
            worst = (_fmt(max(biases), 2) if biases else "–") + (" (biased)" if any(r["biased"] for r in rows) else "")
            shown = [("**" + _fmt(x, 2) + "**" if x == best[c] else _fmt(x, 2)) if x is not None else "–"
                     for c, x in zip(cells, eff)]
            ranked.append((-(gmean or 0.0), m.name, gmean, wins, shown, worst))
        ranked.sort()
        head = ["rank", "method", "geo. mean"] + [f"{_md(s)} ×{sr}" for s, sr in cells] + ["best in", "worst bias"]
        lines = [f"Efficiency 1/(relMSE × seconds) as a multiple of {exp.baseline}'s, at {exp.spp} spp × the shadow "
                 f"rays shown; methods ranked by its geometric mean over these {len(cells)} cells; best per cell in "
                 f"bold; 'best in' counts those cells; worst bias = the largest block-bias ratio (about 1: "
                 f"converges; 'biased': biased by construction).", "",
                 "| " + " | ".join(head) + " |", "|" + "---|" * 2 + "---:|" * (len(head) - 2)]
        for k, (_, name, gmean, wins, shown, worst) in enumerate(ranked, 1):
            lines.append(f"| {k} | {_md(name)} | {_fmt(gmean, 2) if gmean else '–'} | {' | '.join(shown)} | {wins} | "
                         f"{worst} |")
        scenes = [spec.name for spec in exp.scenes]
        lines += ["", "Seconds to reach each scene's target relMSE (log–log interpolation between the shadow-ray "
                  "counts; – = not reached), in the same order:", "",
                  "| method | " + " | ".join(f"{_md(s)} ({self.results.targets[s]['target_relmse']:.3g})"
                                             for s in scenes)
                  + " |", "|---|" + "---:|" * len(scenes)]
        for _, name, *_ in ranked:
            lines.append(f"| {_md(name)} | " + " | ".join(_fmt(self.results.targets[s]["methods"][name]["seconds"])
                                                  for s in scenes) + " |")
        return lines

    # --- page --------------------------------------------------------------------------------------------
    def _reference_note(self, scene):
        spec = next(s for s in self.exp.scenes if s.name == scene)
        if spec.reference is not None:
            return f"file {html.escape(Path(spec.reference).name)}"
        st, r = self.run.reference_stats[scene], self.exp.reference
        sec = st["seconds"]["total"] - st["seconds"]["compile"]
        return f"{html.escape(r.visibility)}, {r.spp} spp × {r.shadow_rays} rays, {sec:.1f} s"

    def _paper_table(self):
        """The paper-style table, a row per scene and method (so it fits a page whatever the method count)."""
        exp, rays = self.exp, self.exp.table_shadow_rays
        e = html.escape
        head = ("<tr><th>scene</th><th>reference</th><th>method</th><th>seconds</th><th>tests</th><th>relMSE</th>"
                "<th>bias</th><th>efficiency</th></tr>")
        body = []
        for spec in exp.scenes:
            s = spec.name
            for k, m in enumerate(exp.methods):
                row = self.results.summary_row(s, m.name, rays)
                base = m.name == exp.baseline
                cells = "".join(f"<td>{c}</td>" for c in _summary_cells(row, base))
                first = (f"<td rowspan={len(exp.methods)}>{e(s)}</td><td rowspan={len(exp.methods)}>"
                         f"<img class=thumb src='{self._image_path(s)}' alt='reference'><br>"
                         f"<small>{self._reference_note(s)}</small></td>") if k == 0 else ""
                body.append(f"<tr class='{'base ' if base else ''}{'first' if k == 0 else ''}'>{first}"
                            f"<td class=method>{e(m.name)}{' (baseline)' if base else ''}</td>{cells}</tr>")
        return (f"<table class=paper id=paper-table><caption>At {exp.spp} spp × {rays} shadow rays: render seconds "
                f"and shadow-ray triangle tests with their change against the baseline ({e(exp.baseline)}), relMSE "
                f"against the reference (seconds: the render's wall time without JIT compilation{SECONDS_NOTE[exp.seconds]}, the fastest of "
                f"{e(repeats_note(exp))} (timing_repeats), median over "
                f"the seeds; it also sets the efficiency; † marks a setting whose repeats or seeds differ by more "
                f"than {UNSTEADY:.0%} — the machine was busy), bias (block means' error against the reference over their "
                f"seed-to-seed noise, two seeds: about 1 when the image converges to the reference, far more when "
                f"not; 'biased' marks a shortcut chosen by the method's options) and efficiency 1/(relMSE × "
                f"seconds) with its ratio to the baseline's.</caption>"
                f"<thead>{head}</thead><tbody>{''.join(body)}</tbody></table>")

    def _detail_table(self, scene):
        e = html.escape
        rows = []
        for sr in self.exp.shadow_rays:
            for m in self.exp.methods:
                r = self.results.summary_row(scene, m.name, sr)
                phases = ", ".join(f"{k} {v:.3f} s" for k, v in r["seconds_phases"].items())
                rows.append(
                    f"<tr{' class=base' if r['baseline'] else ''}><td>{sr}</td><td>{e(m.name)}</td>"
                    f"<td title='{e(phases)}'>{r['seconds']:.3f}</td><td>{_change(r['seconds_change'])}</td>"
                    f"<td>{_fmt(r['triangle_tests'])}</td><td>{_change(r['tests_change'])}</td>"
                    f"<td>{_fmt(r['relmse'])}</td><td>{_fmt(r['rmse'])}</td><td>{_bias(r)}</td>"
                    f"<td>{r['negative_pixel_share']:.1%}</td>"
                    f"<td>{_fmt(r['efficiency_time'])}</td><td>{_fmt(r['efficiency_vs_baseline'])}</td>"
                    f"<td>{_fmt(r['efficiency_tests'])}</td></tr>")
        head = ("<tr><th>rays</th><th>method</th><th>seconds</th><th>Δ</th><th>tests</th><th>Δ</th><th>relMSE</th>"
                "<th>RMSE</th><th>bias</th><th>neg. px</th><th>1/(relMSE·s)</th><th>× base</th><th>1/(relMSE·tests)</th></tr>")
        return f"<table class=detail><thead>{head}</thead><tbody>{''.join(rows)}</tbody></table>"

    def _geometry_table(self):
        """Tests split by geometry and the estimators' memory, a row per scene and method at the table's rays."""
        e, rays = html.escape, self.exp.table_shadow_rays
        rows = []
        for spec in self.exp.scenes:
            for m in self.exp.methods:
                r = self.results.summary_row(spec.name, m.name, rays)
                rows.append(f"<tr{' class=base' if r['baseline'] else ''}><td>{e(spec.name)}</td><td>{e(m.name)}</td>"
                            + "".join(f"<td>{c}</td>" for c in _geometry_cells(r)) + "</tr>")
        head = "<tr><th>scene</th>" + "".join(f"<th>{e(h)}</th>" for h in GEOMETRY_HEAD) + "</tr>"
        return (f"<table class=detail id=geometry-table><caption>At {rays} shadow rays: {e(GEOMETRY_NOTE)}"
                f"</caption><thead>{head}</thead><tbody>{''.join(rows)}</tbody></table>")

    def _target_table(self, scene):
        t = self.results.targets[scene]
        rows = "".join(f"<tr><td>{html.escape(m)}</td><td>{_fmt(v['seconds'])}</td><td>{_fmt(v['triangle_tests'])}"
                       f"</td></tr>" for m, v in t["methods"].items())
        return (f"<table class=detail><caption>Cost to reach relMSE {t['target_relmse']:.3g} (log–log interpolation "
                f"between shadow-ray counts; – = not reached)</caption><thead><tr><th>method</th><th>seconds</th>"
                f"<th>tests</th></tr></thead><tbody>{rows}</tbody></table>")

    def _strip(self, scene):
        e = html.escape
        head = "<tr><th></th>" + "".join(f"<th>{sr}</th>" for sr in self.exp.shadow_rays) + "</tr>"
        rows = [f"<tr><th>reference</th><td colspan={len(self.exp.shadow_rays)}><img class=strip "
                f"src='{self._image_path(scene)}' alt='reference'></td></tr>"]
        for m in self.exp.methods:
            rows.append(f"<tr><th>{e(m.name)}</th>" + "".join(
                f"<td><img class=strip src='{self._image_path(scene, m.name, sr)}' alt='{e(m.name)} {sr}'></td>"
                for sr in self.exp.shadow_rays) + "</tr>")
        return f"<table class=strip><thead>{head}</thead><tbody>{''.join(rows)}</tbody></table>"

    def _viewer(self, scene):
        return (f"<div class=viewer data-scene='{html.escape(scene)}'></div>"
                f"<script src='data/{file_stem(scene)}.js'></script>")

    def _html(self):
        exp, e = self.exp, html.escape
        sections = []
        for spec in exp.scenes:
            s, slug = spec.name, file_stem(spec.name)
            heat = "".join(f"<img class=plot src='plots/{slug}-tests-{sr}.png' alt='tests {sr}'>"
                           for sr in exp.shadow_rays)
            sections.append(
                f"<section id='scene-{slug}'><h2>{e(s)}</h2>"
                f"<h3>Interactive comparison</h3>{self._viewer(s)}"
                f"<h3>Image strips (seed {self.seed}; columns: shadow rays per camera sample)</h3>{self._strip(s)}"
                f"<p>As one figure: <a href='plots/{slug}-strip.png'>plots/{slug}-strip.png</a></p>"
                f"<h3>All settings</h3>{self._detail_table(s)}{self._target_table(s)}"
                f"<h3>Convergence</h3><img class=plot src='plots/{slug}-convergence.png' alt='convergence'>"
                f"<h3>Cost per camera sample</h3><img class=plot src='plots/{slug}-cost.png' alt='cost'>"
                f"<h3>Ray–triangle tests per pixel</h3><details><summary>heat maps</summary>{heat}</details>"
                f"</section>")
        methods = "".join(f"<li><b>{e(m.name)}</b>: {e(m.visibility)} {e(json.dumps(m.options, default=list))}"
                          f"{' (baseline)' if m.name == exp.baseline else ''}</li>" for m in exp.methods)
        return f"""<!doctype html>
<html lang=en><head><meta charset=utf-8><title>{REPORT_TITLE}{e(exp.name)}</title>
<link rel=stylesheet href=report.css></head><body>
<h1>probvis experiment: {e(exp.name)}</h1>
<p>{e(exp.description)}</p>
<p>{exp.spp} camera samples per pixel; shadow rays per camera sample {', '.join(map(str, exp.shadow_rays))};
seeds {', '.join(map(str, exp.seeds))}. relMSE = mean of (x − ref)² / (ref² + 0.01); tests are ray–triangle tests of
shadow rays; seconds exclude JIT compilation. Command: <code>{e(self.command)}</code>.
Data: <a href=results.csv>results.csv</a>, <a href=results.json>results.json</a>,
<a href=results.md>results.md</a>.</p>
<ul>{methods}</ul>
<h2>Results</h2>{self._paper_table()}
<h3>Tests by geometry and memory</h3>{self._geometry_table()}
{''.join(sections)}
<script src=viewer.js></script></body></html>
"""


def _md(name):
    """A scene or method name in a Markdown table cell: its '|' escaped, which would start another column."""
    return name.replace("\\", "\\\\").replace("|", "\\|")


def report_files(exp):
    """The files a study's report writes, relative to its folder."""
    files = [*STATIC, "results.csv", "results.json", "results.md", "index.html"]
    for spec in exp.scenes:
        slug = file_stem(spec.name)
        files += [f"data/{slug}.js", Report._image_path(spec.name)]
        files += [f"plots/{slug}-{kind}.png" for kind in ("convergence", "cost", "strip")]
        files += [f"plots/{slug}-tests-{sr}.png" for sr in exp.shadow_rays]
        files += [Report._image_path(spec.name, m.name, sr) for m in exp.methods for sr in exp.shadow_rays]
    return files


def _earlier_files(folder):
    """The images, plots and data files an earlier report in `folder` listed in its results.json (none if there is
    no such list): those the new report does not write again are removed once it is written."""
    try:
        listed = json.loads((folder / "results.json").read_text(encoding="utf-8")).get("report_files", [])
    except (OSError, ValueError, AttributeError):
        return []
    out = []
    for name in listed if isinstance(listed, list) else []:
        parts = Path(name).parts if isinstance(name, str) else ()
        if len(parts) >= 2 and parts[0] in ("images", "plots", "data") and ".." not in parts \
                and Path(name).suffix in (".png", ".js") and not Path(name).is_absolute():
            out.append(name)
    return out


def report_folders(exp):
    """The folders a report of `exp` writes in, relative to its own."""
    return ["images", "plots", "data"] + [f"images/{file_stem(spec.name)}" for spec in exp.scenes]


def report_problem(exp, folder, inputs=None):
    """What would stop the report's writing in `folder` half-way, or make it replace a file a scene reads, as an
    error message (None: nothing): a file where the report makes a folder, a folder where it writes a file, a
    report file that is one of `inputs` (per scene name, the files it was read from). Checked before any render."""
    folder = Path(folder)
    if not utf8_path(folder):
        return (f"cannot write the report in '{folder}': OpenEXR's writer (its images and the render cache) takes "
                "only folder names in UTF-8; give another folder")
    folders = report_folders(exp)
    files = report_files(exp)
    for name in folders + files:
        part = max(name.split("/"), key=lambda p: len(p.encode()))
        if len(part.encode()) > NAME_MAX:
            return (f"cannot write the report: a scene or method name makes its file name '{part[:40]}...' "
                    f"{len(part.encode())} bytes long, more than file systems hold ({NAME_MAX}): use shorter names")
    for name in folders:
        if os.path.islink(folder / name) and not (folder / name).exists():
            return (f"cannot write the report: '{folder / name}', where the report keeps a folder, is a symbolic "
                    "link that loops or points to nothing")
        if (folder / name).exists() and not (folder / name).is_dir():
            return f"cannot write the report: '{folder / name}' is a file, where the report keeps a folder"
    read = {Path(os.path.realpath(p)): scene for scene, paths in (inputs or {}).items() for p in paths}
    for name in files:
        if (folder / name).is_dir():
            return f"cannot write the report: '{folder / name}' is a folder, where the report writes a file"
        if (scene := read.get(Path(os.path.realpath(folder / name)))) is not None:
            return (f"cannot write the report: it would replace '{folder / name}', which scene '{scene}' reads; give "
                    "-o another folder")
    index = folder / "index.html"
    if index.is_file():
        try:
            with open(index, "rb") as fh:
                head = fh.read(4096).decode("utf-8", "replace")
        except OSError as exc:
            return f"cannot write the report: '{index}' cannot be read ({exc.strerror or exc})"
        if REPORT_TITLE not in head:
            return (f"'{folder}' holds an index.html that is not a probvis report, which the report would replace: "
                    "give -o a new folder, or a report's own")
        other = head.split(f"<title>{REPORT_TITLE}", 1)[-1].split("</title>", 1)[0]
        if other != html.escape(exp.name):  # the renders stay in the cache; the other study's pages do not
            warnings.warn(f"'{folder}' holds the report of study '{html.unescape(other)}': this one, "
                          f"'{exp.name}', replaces it (give -o another folder to keep both)", stacklevel=2)
    else:  # no report here: a file of the user's own under one of the report's names would be replaced
        theirs = next((name for name in files if (folder / name).exists()), None)
        if theirs is not None:
            cache = folder / "cache"
            kept = (f" (to reuse the renders cached in '{cache}', add --cache {cache})" if cache.is_dir() else "")
            return (f"'{folder}' holds '{theirs}' but no probvis report (its index.html), and the report would "
                    f"replace it: give -o a new folder, or a report's own{kept}")
    return None


@checked_call
def write_report(exp, run, results, folder, command=""):
    """Write the report; on failure (a full disk, say) say so — the renders stay in the cache — and leave none of
    the report's folders that this call made behind empty."""
    expect_record(exp, Experiment, "exp", MADE_BY)
    expect_record(run, RunSummary, "run", "the RunSummary run_experiment returns")
    expect_record(results, Results, "results", "the Results measure returns")
    if not is_path(folder):
        raise ProbvisError(f"folder must be the report's folder (a path), got {type(folder).__name__}")
    folder = Path(folder)
    planned = [folder, *folder.parents, *(folder / sub for sub in ("images", "plots", "data")),
               *(folder / "images" / file_stem(spec.name) for spec in exp.scenes)]
    made = [d for d in planned if not d.exists()]
    earlier = _earlier_files(folder)
    try:
        index = _write_report(exp, run, results, folder, command)
    except BaseException:
        for d in sorted(made, key=lambda p: len(p.parts), reverse=True):  # the deepest first
            try:
                d.rmdir()  # only if empty: a cache of renders inside stays
            except OSError:
                pass
        raise
    for name in set(earlier) - set(report_files(exp)):  # a renamed method's or scene's files: no longer shown
        try:
            if (folder / name).is_file() and not (folder / name).is_symlink():
                (folder / name).unlink()
        except OSError:
            pass
    return index


def _write_report(exp, run, results, folder, command):
    try:
        with warnings.catch_warnings():  # an exact method's relMSE of 0 has no place on a log axis: not plotted
            warnings.filterwarnings("ignore", message="Data has no positive values")
            warnings.filterwarnings("ignore", message="Glyph .* missing from font")  # the plots' own layout,
            warnings.filterwarnings("ignore", message="Tight layout not applied")  # nothing a user can act on
            with staged_writes():  # every file of the report or none of them (a full disk, ulimit -f)
                return Report(exp, run, results, folder, command).write()
    except OSError as exc:
        where = exc.filename or folder
        raise ProbvisError(f"cannot write the report to '{folder}' ('{where}'): {exc.strerror or exc}") from None
