"""Shared fixtures: one `backend` fixture over the CPU backends, and
small meshes built to hit the edge cases of column ray casting."""

from __future__ import annotations

import contextlib
import gc
import os
import time

import numpy as np
import pytest
import trimesh

import geovox
from geovox.mesh import Mesh

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
#: Real public models the tests use, copied from the shared corpus with their
#: licences (see data/README.md); spot is the bundled model in ../data.
DATA = os.path.join(HERE, "data")
SPOT = os.path.join(ROOT, "data", "spot", "spot.obj")


@pytest.fixture(params=geovox.available_backends())
def backend(request):
    """Every test using this runs once per installed CPU backend (those `auto` may try).

    The backend contract itself, on every backend that can run here, webgpu
    included (through lavapipe where there is no GPU), is the class in
    test_conformance.py: sized for a software GPU, so it can run on all of them.
    """
    return request.param


@contextlib.contextmanager
def dask_client(*, set_as_default=False, **cluster_options):
    """A Client of a LocalCluster started here, and everything closed before it returns.

    Closing a LocalCluster removes its workers and then stops its event loop
    within a few milliseconds. The scheduler tells the cluster of each worker
    removed through a stream that batches for 5 ms; when that batch's timer
    fires just before the loop stops, the timer's future holds a
    ``TimeoutError('Timeout')`` nobody reads, and asyncio prints "Future
    exception was never retrieved" when it is collected: at interpreter
    exit, after pytest's summary (issue 41). So the workers go first and the
    loop runs on until that stream is quiet; the cluster then closes with
    nothing in flight, and what it leaves is collected here, while pytest
    still captures the test's output.
    """
    import distributed

    with distributed.LocalCluster(**cluster_options) as cluster:
        with distributed.Client(cluster, set_as_default=set_as_default) as client:
            yield client
        cluster.scale(0)
        deadline = time.monotonic() + 30
        while cluster.scheduler_info.get("workers") and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.1)  # twenty of the status stream's 5 ms batches: its last timer has fired
    gc.collect()


def corpus(*parts):
    """Path of a real model in tests/data (spot: the bundled data/spot)."""
    rel = os.path.join(*parts)
    base = os.path.join(ROOT, "data") if rel.split("/")[0] == "spot" else DATA
    path = os.path.join(base, rel)
    if not os.path.exists(path):
        raise FileNotFoundError(f"test model missing from the repository: {path}")
    return path


def box_mesh(lo, hi, diagonals="alternate") -> Mesh:
    """Axis-aligned box; each face split along a chosen diagonal.

    ``diagonals="alternate"`` flips the diagonal between opposite faces so
    that the diagonals of the top and bottom faces cross in projection.
    """
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    corners = np.array([[(hi if (k >> a) & 1 else lo)[a] for a in range(3)] for k in range(8)])
    # quads as (v0, v1, v2, v3) counter-clockwise seen from outside
    quads = [
        (0, 2, 3, 1),  # z = lo
        (4, 5, 7, 6),  # z = hi
        (0, 1, 5, 4),  # y = lo
        (2, 6, 7, 3),  # y = hi
        (0, 4, 6, 2),  # x = lo
        (1, 3, 7, 5),  # x = hi
    ]
    faces = []
    for n, (a, b, c, d) in enumerate(quads):
        if diagonals == "alternate" and n % 2:
            faces += [(a, b, d), (b, c, d)]
        else:
            faces += [(a, b, c), (a, c, d)]
    return Mesh(corners, np.array(faces), source="box")


def from_tm(m: trimesh.Trimesh, name: str) -> Mesh:
    return Mesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), source=name)


def reference_occupancy(mesh: Mesh, grid, axis: int = 2) -> np.ndarray:
    """Slow, independent float64 classification of every voxel centre.

    Each centre is nudged across the rays by (1e-8, 1e-10) voxels along the
    two other axes (in increasing axis order) and by 1e-6 voxels along the
    ray, which puts it in general position; it is inside when an odd number
    of triangles lie before it along ``axis`` (strict tests only, no tie
    rules). This realises the symbolic-perturbation convention of
    geovox.exact, whose nudge along the ray dominates the one across it.
    """
    eps = np.zeros(3)
    eps[axis] = 1e-6
    eps[[a for a in range(3) if a != axis]] = [1e-8, 1e-10]
    eps = eps * grid.spacing
    cs = [grid.centres(a) + eps[a] for a in range(3)]
    P = np.stack(np.meshgrid(*cs, indexing="ij"), axis=-1).reshape(-1, 3)
    u, v = (a for a in range(3) if a != axis)
    T = mesh.triangles
    count = np.zeros(len(P), dtype=np.int64)
    for start in range(0, len(T), 64):
        t = T[start:start + 64]
        a, b, c = t[:, 0], t[:, 1], t[:, 2]

        def orient(p, q, r):
            return ((q[..., u] - p[..., u]) * (r[..., v] - p[..., v])
                    - (q[..., v] - p[..., v]) * (r[..., u] - p[..., u]))

        area = orient(a, b, c)
        ok = area != 0
        a, b, c, area = a[ok], b[ok], c[ok], area[ok]
        Pe = P[:, None, :]
        w0 = orient(b[None], c[None], Pe) / area
        w1 = orient(c[None], a[None], Pe) / area
        w2 = orient(a[None], b[None], Pe) / area
        inside2d = (w0 > 0) & (w1 > 0) & (w2 > 0)
        depth = w0 * a[None, :, axis] + w1 * b[None, :, axis] + w2 * c[None, :, axis]
        count += (inside2d & (depth < Pe[..., axis])).sum(axis=1)
    return (count % 2 == 1).reshape(grid.shape)
