"""The density-and-distance page's figure: spot's distance on its middle slice.

Left, ``--sdf`` (band 3): exact within 3 voxels of the surface, clamped beyond;
right, ``--sdf --band inf``: exact everywhere. Run from the repository root
(needs the ``docs`` extra, for matplotlib)::

    python docs/make_distance_figure.py docs/img/spot_distance_slice.png
"""

import math
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import geovox  # noqa: E402


def main(out):
    kw = dict(resolution=160, sdf=True)
    band = geovox.voxelize("data/spot/spot.obj", **kw)
    full = geovox.voxelize("data/spot/spot.obj", band=math.inf, **kw)
    h = float(np.min(full.grid.spacing))
    k = full.shape[0] // 2  # the middle slice across x (spot's side view)
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.2), constrained_layout=True)
    far = float(np.abs(full.sdf[k]).max()) / h
    for ax, vol, lim, step, title in (
            (axes[0], band, 3.0, 1, "--sdf (band 3): exact within 3 voxels, ±3 beyond"),
            (axes[1], full, far, 5, "--sdf --band inf: exact everywhere")):
        s = vol.sdf[k].T / h  # (z, y), in voxels
        im = ax.imshow(s, origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax.contour(s, levels=np.arange(-60, 61, step), colors="k", linewidths=0.4)
        ax.contour(s, levels=[0], colors="k", linewidths=1.6)
        ax.set_title(title)
        ax.set_xlabel("y (voxels)")
        ax.set_ylabel("z (voxels)")
        fig.colorbar(im, ax=ax, shrink=0.75, label="distance (voxels); negative inside")
    fig.savefig(out, dpi=90)


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "docs/img/spot_distance_slice.png")
