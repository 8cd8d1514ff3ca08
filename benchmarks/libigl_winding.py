"""libigl's fast winding number on the grid of ``geovox convert FILE -r N`` (for the whole-process timings).

The mesh as read (not repaired), every voxel centre of the N³ grid over its
bounding box, inside where the winding number is above 1/2; the occupancy is
saved as a (N, N, N) bool .npy so it can be compared with geovox's.

Usage: python benchmarks/libigl_winding.py FILE N OUT.npy
"""

import sys

import igl
import numpy as np


def main(path, n, out):
    v, f = igl.read_triangle_mesh(path)
    v = np.asarray(v, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    c = [lo[a] + (np.arange(n) + 0.5) * (hi[a] - lo[a]) / n for a in range(3)]
    q = np.stack(np.meshgrid(*c, indexing="ij"), -1).reshape(-1, 3)
    w = igl.fast_winding_number(v, np.asarray(f, np.int64), q)
    np.save(out, (np.asarray(w) > 0.5).reshape(n, n, n))


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3])
