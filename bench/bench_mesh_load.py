"""Mesh-file loading, run by hand: `python3 bench/bench_mesh_load.py [--runs 5] [--subdivisions 8]`.

Writes a binary PLY of a subdivided icosphere (8 subdivisions: 1,310,720 triangles) to a temporary folder and
times, alternately in this process, probvis's reader (`probvis.scene.shapes.load_mesh`: `scene.ply`,
memory-mapped) and the whole scene load of an XML file around it (reader + transform + normals + validation), next
to Mitsuba 3 loading the same file (`scalar_rgb`, `mi.load_dict`), and a fresh process that imports probvis and
loads the scene (what a command pays: imports included). Medians of `--runs`. Then, where ../shared is beside the
project, the city's OBJ (30k triangles in 329 material groups; `scene.obj`) the same way, and the peak memory
(max RSS) of a fresh process that imports probvis and loads the city scene.
"""
import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

import probvis
from probvis.scene.shapes import load_mesh

SCENE = """<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film></sensor>
  <shape type="ply"><string name="filename" value="heavy.ply"/></shape>
  <emitter type="point"><point name="position" x="0" y="3" z="3"/></emitter>
</scene>"""


def timed(fn):
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def fresh_process(xml):
    """Seconds of a new interpreter that imports probvis and loads the scene."""
    return timed(lambda: subprocess.run([sys.executable, "-c", f"import probvis; probvis.load_scene({str(xml)!r})"],
                                        check=True))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--subdivisions", type=int, default=8)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        mesh = trimesh.creation.icosphere(subdivisions=args.subdivisions)
        mesh.export(folder / "heavy.ply")
        (folder / "heavy.xml").write_text(SCENE)
        size = (folder / "heavy.ply").stat().st_size
        print(f"binary PLY: {len(mesh.faces):,} triangles, {len(mesh.vertices):,} vertices, {size / 2**20:.1f} MiB")
        try:
            import mitsuba as mi

            mi.set_variant("scalar_rgb")
        except ImportError:
            mi = None
        times = {"probvis load_mesh": [], "probvis load_scene (XML)": [], "Mitsuba 3 load_dict": [],
                 "fresh process: import probvis + load_scene": []}
        for _ in range(args.runs):
            times["probvis load_mesh"].append(timed(lambda: load_mesh(folder / "heavy.ply")))
            times["fresh process: import probvis + load_scene"].append(fresh_process(folder / "heavy.xml"))
            times["probvis load_scene (XML)"].append(timed(lambda: probvis.load_scene(folder / "heavy.xml")))
            if mi is not None:
                times["Mitsuba 3 load_dict"].append(
                    timed(lambda: mi.load_dict({"type": "ply", "filename": str(folder / "heavy.ply")})))
        for what, ts in times.items():
            if ts:
                print(f"{what}: median {statistics.median(ts):.3f} s (min {min(ts):.3f}, max {max(ts):.3f}, "
                      f"{len(ts)} runs)")
        assert np.array_equal(load_mesh(folder / "heavy.ply").faces, mesh.faces)
    city = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "city.xml"
    if city.exists():
        obj = city.parent.parent / "data" / "meshes" / "microcity.obj"
        times = {"city OBJ: probvis load_mesh": [], "city: probvis load_scene (XML)": [],
                 "city: Mitsuba 3 load_file": [], "city: fresh process: import probvis + load_scene": []}
        for _ in range(args.runs):
            times["city: fresh process: import probvis + load_scene"].append(fresh_process(city))
            times["city OBJ: probvis load_mesh"].append(timed(lambda: load_mesh(obj)))
            times["city: probvis load_scene (XML)"].append(timed(lambda: probvis.load_scene(city)))
            if mi is not None:
                times["city: Mitsuba 3 load_file"].append(timed(lambda: mi.load_file(str(city))))
        for what, ts in times.items():
            if ts:
                print(f"{what}: median {statistics.median(ts):.3f} s (min {min(ts):.3f}, max {max(ts):.3f}, "
                      f"{len(ts)} runs)")
        code = (f"import probvis; probvis.load_scene({str(city)!r}); "
                "print(open('/proc/self/status').read().split('VmHWM:')[1].split()[0])")
        peak = int(subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout)
        print(f"city: peak memory of a process that loads it: {peak / 1024:.0f} MiB")


if __name__ == "__main__":
    main()
