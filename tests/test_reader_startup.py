"""A fresh `geovox convert` of OBJ, STL, PLY, glTF or GLB never imports trimesh (issue 36):
geovox reads those itself, and trimesh (with SciPy's spatial module behind it) costs
half a second of start-up."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

PROBE = """
import sys
from geovox.cli import main
status = main(["convert", sys.argv[1], "-o", sys.argv[2], "-r", "16", "-q"])
print(status, " ".join(sorted(sys.modules)))
"""


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    folder = tmp_path_factory.mktemp("models")
    box = trimesh.creation.box()
    paths = {}
    for ext, kw in [("obj", {}), ("stl", {}), ("ply", {}), ("glb", {}), ("gltf", {})]:
        path = folder / f"box.{ext}"
        if ext == "gltf":
            files = trimesh.Scene(box).export(file_type="gltf")
            for name, data in files.items():
                (folder / name).write_bytes(data)
            os.replace(folder / "model.gltf", path)
        else:
            box.export(path)
        paths[ext] = str(path)
    # an ASCII PLY with colours and UVs, and a textured GLB: the colour paths too
    uv = np.c_[box.vertices[:, :2] + 0.5]
    textured = trimesh.Trimesh(box.vertices, box.faces, process=False,
                               visual=trimesh.visual.TextureVisuals(uv=uv))
    path = folder / "uv.ply"
    path.write_bytes(textured.export(file_type="ply", encoding="ascii"))
    paths["ascii ply"] = str(path)
    return paths


@pytest.mark.parametrize("kind", ["obj", "stl", "ply", "glb", "gltf", "ascii ply"])
def test_convert_does_not_import_trimesh(models, kind, tmp_path):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", PROBE, models[kind], str(tmp_path / "v.raw")],
                         capture_output=True, text=True, env=env, cwd=ROOT, check=True)
    status, modules = out.stdout.split(" ", 1)
    assert status == "0", out.stderr
    loaded = set(modules.split())
    assert "trimesh" not in loaded, kind
    assert not {m for m in loaded if m.startswith(("scipy.spatial", "networkx", "lxml"))}
