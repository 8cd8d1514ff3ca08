"""The gallery's binary against coverage: the ½ iso-surface of each, spot at 64³.

    python docs/examples/coverage_spot.py [OUT.png]     (default: docs/spot_coverage_vs_binary.png)

Left, the iso-surface at ½ of the binary occupancy (stair-steps); right, of the K = 4 coverage
density (``density="coverage"``, each voxel's inside fraction from 4 × 4 rays per column), which
a renderer draws as a smooth surface. PyVista renders off screen (the ``view`` extra).
"""

import os
import sys
from pathlib import Path

import numpy as np
import pyvista as pv

import geovox

ROOT = Path(__file__).resolve().parents[2]
#: Relative to the repository root, so that the pictures show this path, not the machine's.
SPOT = "data/spot/spot.obj"


def image(vol, values):
    """Point data at the voxel centres, as geovox.view does."""
    img = pv.ImageData(dimensions=vol.shape, spacing=vol.spacing,
                       origin=np.asarray(vol.bounds[0]) + 0.5 * np.asarray(vol.spacing))
    img.point_data["v"] = np.asarray(values, dtype=np.float32).reshape(-1, order="F")
    return img.contour([0.5], scalars="v")


def main(out=ROOT / "docs" / "spot_coverage_vs_binary.png"):
    out = Path(out).resolve()  # before the chdir: a relative OUT is the caller's
    os.chdir(ROOT)
    vol = geovox.voxelize(SPOT, resolution=64,
                          density="coverage", supersample=4, density_dtype="float32")
    plotter = pv.Plotter(shape=(1, 2), off_screen=True, window_size=(1200, 600))
    for col, (title, values) in enumerate((("binary occupancy", vol.occupancy),
                                           ("coverage density, K = 4", vol.density))):
        plotter.subplot(0, col)
        plotter.add_text(title, font_size=10)
        plotter.add_mesh(image(vol, values), color="lightgrey", smooth_shading=True)
        plotter.view_isometric()
    plotter.link_views()
    plotter.screenshot(str(out))
    plotter.close()
    print("wrote", out)


if __name__ == "__main__":
    main(*sys.argv[1:])
