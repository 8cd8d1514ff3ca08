"""Big grids: time and peak memory of a conversion to HDF5, fresh process each.

Each case runs twice: `geovox.convert_to` on a loaded mesh in a fresh process (time without
loading, peak RSS), and the command line end to end (`python -m geovox convert MODEL.obj -o v.h5
-r N -q`: wall time including interpreter start, imports and reading the OBJ).

Usage: python benchmarks/bench_scale.py [--cases spot:1024 bunny105k:1024 spot:2048 spot:1024:color]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

CHILD = """
import sys, json, time
sys.path.insert(0, {here!r})
from common import load_model
import geovox
model, res, color, out = sys.argv[1], int(sys.argv[2]), sys.argv[3] == "1", sys.argv[4]
mesh = load_model(model)
t = time.perf_counter()
info = geovox.convert_to(mesh, out, resolution=res, color=color)
dt = time.perf_counter() - t
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]
print(json.dumps({{"time": dt, "peak_kib": int(hwm), "slabs": info["slabs"], "inside": info["inside"]}}))
"""


def model_obj(name, folder):
    """A path to the model as an OBJ file (the generated ones written once)."""
    from common import SPOT, load_model

    if name == "spot":
        return SPOT
    import trimesh

    mesh = load_model(name)
    path = os.path.join(folder, f"{name}.obj")
    trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(path)
    return path


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--cases", nargs="+",
                   default=["spot:128", "spot:256", "spot:512", "spot:1024", "bunny105k:1024",
                            "spot:2048", "spot:512:color", "spot:1024:color"])
    args = p.parse_args()
    tmp_root = tempfile.TemporaryDirectory()
    print(f"# bench_scale {datetime.date.today()}")
    print("| model | grid | colour | time to .h5 (s) | CLI end to end (s) | peak RSS (GiB) | slabs "
          "| file (MiB) | inside |")
    print("|---|---|---|---|---|---|---|---|---|")
    objs = {}
    for case in args.cases:
        parts = case.split(":")
        model, res, color = parts[0], int(parts[1]), len(parts) > 2
        with tempfile.TemporaryDirectory() as tmp:
            out = os.path.join(tmp, "v.h5")
            r = subprocess.run([sys.executable, "-c", CHILD.format(here=HERE), model, str(res),
                                "1" if color else "0", out], capture_output=True, text=True)
            if r.returncode:
                print(f"| {model} | {res}³ | {'yes' if color else 'no'} | failed: "
                      f"{r.stderr.strip().splitlines()[-1]} | | | | |", flush=True)
                continue
            info = json.loads(r.stdout.strip().splitlines()[-1])
            size = os.path.getsize(out) / 2**20
            os.remove(out)
            obj = objs.get(model) or objs.setdefault(model, model_obj(model, tmp_root.name))
            cmd = [sys.executable, "-m", "geovox", "convert", obj, "-o", out, "-r", str(res), "-q"]
            t = time.perf_counter()
            r = subprocess.run(cmd + (["--color"] if color else []), capture_output=True, text=True)
            wall = time.perf_counter() - t
            cli = f"{wall:.2f}" if r.returncode == 0 else "failed"
        print(f"| {model} | {res}³ | {'yes' if color else 'no'} | {info['time']:.2f} | {cli} | "
              f"{info['peak_kib'] / 2**20:.2f} | {info['slabs']} | {size:.1f} | {info['inside']:,} |",
              flush=True)


if __name__ == "__main__":
    main()
