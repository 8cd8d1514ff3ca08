"""Helpers shared by the benchmark scripts (not part of the package)."""

from __future__ import annotations

import os
import subprocess
import sys
import json

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
CORPUS = os.path.join(ROOT, "..", "shared", "corpus")
SPOT = os.path.join(ROOT, "data", "spot", "spot.obj")
BUNNY = os.path.join(CORPUS, "bunny_watertight", "upsampled_bunny_oded.obj")


def load_model(name):
    """A geovox Mesh for a benchmark model name."""
    import geovox

    if name == "spot":
        return geovox.load_mesh(SPOT)
    if name == "bunny105k":
        # 26,392-triangle watertight bunny, midpoint-subdivided once: 105,568
        # triangles, still closed.
        import trimesh

        m = trimesh.load(BUNNY, force="mesh", process=False)
        v, f = trimesh.remesh.subdivide(m.vertices, m.faces)
        return geovox.Mesh(v, f, source="bunny105k")
    if name.startswith("ico"):
        # icosphere with N subdivisions: 20 * 4**N triangles, closed.
        import trimesh

        m = trimesh.creation.icosphere(subdivisions=int(name[3:]))
        return geovox.Mesh(m.vertices, m.faces, source=name)
    raise ValueError(name)


def peak_rss() -> int:
    """Peak resident memory of this process so far, bytes (VmHWM)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) * 1024
    return 0


def reset_peak() -> None:
    """Reset VmHWM to the current RSS (Linux >= 4.0)."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
    except OSError:
        pass


def run_worker(script, *args) -> dict:
    """Run ``script --worker args`` in a fresh interpreter; return its JSON line."""
    out = subprocess.run([sys.executable, script, "--worker", *map(str, args)],
                         capture_output=True, text=True, check=False)
    if out.returncode != 0:
        return {"error": out.stderr.strip().splitlines()[-1] if out.stderr.strip() else "failed"}
    return json.loads(out.stdout.strip().splitlines()[-1])
