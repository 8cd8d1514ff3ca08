"""The labelled scene of the documentation: a six-file phantom, one label per file.

    python docs/examples/labels_phantom.py [OUT.png]      (default: docs/labels_preview.png)

Writes six closed STL files (body, spine, liver, kidneys, a tumour inside the right kidney) into
``/tmp/phantom`` with trimesh, then runs the two commands a user runs::

    python -m geovox convert body.stl spine.stl liver.stl kidney_left.stl kidney_right.stl \\
        tumour.stl --labels file --overlap smallest -r 128 -o phantom.seg.nrrd
    python -m geovox preview phantom.seg.nrrd -o docs/labels_preview.png

``--overlap smallest``: the organs lie inside the body and the tumour inside a kidney, so the
smaller part wins where parts overlap, as it should for inclusions.
"""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FOLDER = Path("/tmp/phantom")


def _parts():
    """name -> closed trimesh.Trimesh, in the file order the labels take."""
    import numpy as np
    from trimesh.creation import capsule, cylinder, icosphere

    def ellipsoid(radii, centre):
        m = icosphere(subdivisions=3)
        m.apply_scale(radii)
        m.apply_translation(centre)
        return m

    body = capsule(height=2.0, radius=1.0, count=[48, 48])  # z from -2 to 2
    body.apply_transform(np.diag([1.0, 0.6, 1.0, 1.0]))
    spine = cylinder(radius=0.12, height=3.0, sections=48)
    spine.apply_translation([0.0, -0.38, 0.0])
    return {
        "body": body,
        "spine": spine,
        "liver": ellipsoid([0.45, 0.22, 0.25], [-0.1, 0.1, 0.9]),
        "kidney_left": ellipsoid([0.18, 0.13, 0.3], [-0.55, -0.1, 0.0]),
        "kidney_right": ellipsoid([0.18, 0.13, 0.3], [0.55, -0.1, 0.0]),
        "tumour": ellipsoid([0.08, 0.08, 0.08], [0.58, -0.08, 0.05]),
    }


def geovox(*args):
    subprocess.run([sys.executable, "-m", "geovox", *args], cwd=FOLDER, check=True)


def main(out=ROOT / "docs" / "labels_preview.png"):
    out = Path(out).resolve()
    FOLDER.mkdir(parents=True, exist_ok=True)
    names = []
    for name, mesh in _parts().items():
        assert mesh.is_watertight, name
        mesh.export(FOLDER / f"{name}.stl")
        names.append(f"{name}.stl")
    geovox("convert", *names, "--labels", "file", "--overlap", "smallest", "-r", "128",
           "-o", "phantom.seg.nrrd", "--overwrite")
    geovox("preview", "phantom.seg.nrrd", "-o", os.fspath(out))
    print(f"wrote {out}")


if __name__ == "__main__":
    main(*sys.argv[1:])
