"""Make docs/spot_scan.nii.gz: a synthetic, oblique, anisotropic "scan" of spot for the README.

    python docs/make_oblique_scan.py data/spot/spot.obj docs/spot_scan.nii.gz

The grid is rotated about two axes (20 degrees about x, 35 about z) with voxels of
0.012 x 0.016 x 0.03 (spot's units); its intensities are spot's signed distance on that
grid (a bright rim inside the surface, a dimmer interior), blurred and with noise, so the
mask geovox makes onto it can be checked against what the "scanner" saw.
"""

import sys

import nibabel
import numpy as np
from scipy.ndimage import gaussian_filter

import geovox


def rotation(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    r = np.eye(3)
    i, j = (a for a in range(3) if a != axis)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def main(mesh_path: str, out: str) -> None:
    spacing = np.array([0.012, 0.016, 0.03])
    shape = np.array([150, 140, 70])
    lps = np.eye(4)
    lps[:3, :3] = rotation(0, np.radians(20)) @ rotation(2, np.radians(35)) * spacing
    centre = np.array([0.0, 0.1, 0.2])
    lps[:3, 3] = centre - lps[:3, :3] @ ((shape - 1) / 2)
    vol = geovox.voxelize(mesh_path, like=(lps, tuple(shape)), sdf=True, band=6.0)
    d = vol.sdf.astype(np.float64)
    inside = d < 0
    rim = np.exp(-np.abs(d) / 0.02)
    image = np.where(inside, 380.0 + 520.0 * rim, 40.0 + 60.0 * rim)
    image = gaussian_filter(image, 0.8) + np.random.default_rng(7).normal(0.0, 35.0, image.shape)
    ras = np.diag([-1.0, -1.0, 1.0, 1.0]) @ lps
    img = nibabel.Nifti1Image(image.astype(np.int16), ras)
    img.header.set_sform(ras, code=1)
    img.header.set_qform(ras, code=1)
    nibabel.save(img, out)
    print(f"wrote {out}: {tuple(shape)} voxels of {tuple(spacing)}, oblique")


if __name__ == "__main__":
    main(*sys.argv[1:3])
