"""Fractions against brute force: each part alone on a finer grid, the overlap rule applied.

A label's fraction in a voxel is the share of the voxel that its part covers and no part that
wins over it does. The truth here samples that directly: every part is voxelised alone (its
own inside test, as labels use it: parity where closed, the winding number of a repaired copy
where open) on a grid ``K`` times finer across the rays, at the coverage's own sub-ray
positions, and ``M`` times finer along them; the rule is applied sample by sample and the
samples averaged per voxel. Along a ray the samples resolve a crossing to ``1 / M`` of a
voxel, so the two agree within a crossing's share of that.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_labels import assembly, rule_order

import geovox
from geovox import labels as L
from geovox.grid import make_grid

K, M = 3, 24


def brute_fractions(mesh, grid, overlap, axis=2):
    """(nx, ny, nz, L) float64: the rule's fractions from each part alone, supersampled."""
    n = len(mesh.parts)
    fine_shape = tuple(s * (M if a == axis else K) for a, s in enumerate(grid.shape))
    owner = np.zeros(fine_shape, np.int16)  # the winning part + 1 per sample
    for k in rule_order(mesh, overlap):  # the winner paints last
        part = L.part_mesh(mesh, np.flatnonzero(mesh.face_part == k), mesh.parts[k])
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            occ = geovox.voxelize(part, shape=fine_shape, bounds=np.r_[grid.lo, grid.hi],
                                  axis=axis).occupancy
        owner[occ] = k + 1
    f = [M if a == axis else K for a in range(3)]
    blocks = owner.reshape(grid.shape[0], f[0], grid.shape[1], f[1], grid.shape[2], f[2])
    return np.stack([(blocks == k + 1).mean(axis=(1, 3, 5)) for k in range(n)], axis=-1)


@pytest.mark.parametrize("overlap", L.OVERLAPS)
def test_fractions_of_closed_and_open_parts_are_the_brute_force_coverage(overlap):
    m = assembly(open_part=True)  # an open cup among overlapping closed bodies
    grid = make_grid(m.bounds, shape=(26, 19, 15))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        v = geovox.voxelize(m, shape=grid.shape, labels="part", fractions=True,
                            overlap=overlap, supersample=K, density_dtype="float32")
    want = brute_fractions(m, grid, overlap)
    err = np.abs(v.fractions - want)
    # A sub-ray crosses a part's surface at most twice in a voxel here: within 2 / M.
    assert err.max() <= 2.0 / M + 1e-6, (err.max(), np.unravel_index(err.argmax(), err.shape))
    # And on the whole the error is the along-ray sampling's (a quarter of 1 / M on average
    # where a surface passes), not a part's.
    for k, name in enumerate(m.parts):
        assert abs(v.fractions[..., k].sum() - want[..., k].sum()) <= 0.02 * want[..., k].sum() \
            + 1.0, name
    assert want[..., 4].sum() > 100  # the cup holds something to compare
