"""Scans: closed models with many small holes (issue 37), small enough to check by brute force.

A scan is decided by the winding number of its repaired copy, exactly: every
voxel here is checked against the brute-force winding number of that copy
(every triangle's solid angle summed at the voxel centre), under both
kernels; the holes move voxels only next to them; a scan that would not fit
in memory is refused before its repair, in one line. No timings here (see
benchmarks/bench_triangles.py).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

import geovox
from geovox.errors import GeovoxWarning, GridTooLargeError, MeshTooLargeError
from geovox.inside import captree, choice, repair
from geovox.inside.edges import edge_counts, is_closed
from geovox.kernels import chosen


def scan(subdivisions=3, share=0.05, seed=37, soup=False):
    """An icosphere with ``share`` of its faces removed at random: many small holes.

    ``soup``: as an STL file gives it, three vertices a triangle (merged by
    position when read).
    """
    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    v, f = np.asarray(m.vertices), np.asarray(m.faces)
    removed = np.random.default_rng(seed).random(len(f)) < share
    f = f[~removed]
    if soup:
        v, f = v[f].reshape(-1, 3), np.arange(3 * len(f)).reshape(-1, 3)
    return geovox.Mesh(v, f, source="scan"), geovox.Mesh(np.asarray(m.vertices),
                                                         np.asarray(m.faces), source="closed")


def brute(mesh, grid):
    """The winding number of ``mesh`` at every voxel centre of ``grid``, summed exactly."""
    c = np.stack(np.meshgrid(*[grid.centres(a) for a in range(3)], indexing="ij"), -1)
    p = c.reshape(-1, 3)
    tris = mesh.triangles
    w = np.zeros(len(p))
    for t in tris:  # one triangle at every point at once
        w += captree.triangle_angles(np.broadcast_to(t, (len(p), 3, 3)).copy(), p)
    return w.reshape(grid.shape)


def _voxelize(mesh, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        return geovox.voxelize(mesh, **kw)


@pytest.mark.parametrize("kernel", ["numpy", "compiled"])
@pytest.mark.parametrize("soup", [False, True])
def test_a_scan_is_the_brute_force_winding_number_of_its_repaired_copy(kernel, soup):
    mesh, _ = scan(soup=soup)
    if kernel == "compiled":
        pytest.importorskip("geovox._lattice")
    vol = _voxelize(mesh, resolution=20, kernel=kernel)
    assert vol.inside == "winding" and vol.approximate == 0
    with chosen(kernel):
        w = brute(choice.target(mesh)[0], vol.grid)
    assert np.abs(w - 0.5).min() > 1e-6  # no tie for the brute force itself
    np.testing.assert_array_equal(vol.occupancy, w > 0.5)


def test_a_scans_holes_move_voxels_only_next_to_them():
    # The holes are small next to the voxels: the scan's voxels are the
    # closed model's but for a few beside a removed face.
    mesh, closed = scan(subdivisions=4)
    kw = dict(resolution=24, bounds=np.r_[closed.bounds[0] - 0.05, closed.bounds[1] + 0.05])
    a, b = _voxelize(mesh, **kw), _voxelize(closed, **kw)
    assert b.inside == "parity" and a.inside == "winding"
    moved = np.argwhere(a.occupancy != b.occupancy)
    assert len(moved) <= 0.005 * b.inside_count
    m = trimesh.creation.icosphere(subdivisions=4)
    removed = np.random.default_rng(37).random(len(m.faces)) < 0.05
    gone = np.asarray(m.triangles_center)[removed]
    for i in moved:
        p = np.array([a.grid.centres(k)[i[k]] for k in range(3)])
        assert np.linalg.norm(gone - p, axis=1).min() < np.linalg.norm(a.grid.spacing)


def test_kernels_give_one_repaired_scan():
    pytest.importorskip("geovox._lattice")
    for soup in (False, True):
        mesh, _ = scan(soup=soup)
        reps = []
        for kernel in ("numpy", "compiled"):
            with chosen(kernel):
                reps.append(repair.repair(geovox.Mesh(mesh.vertices, mesh.faces)))
        a, b = reps
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
        assert np.array_equal(a.mesh.faces, b.mesh.faces)
        for field in ("face", "swapped", "piece"):
            assert np.array_equal(getattr(a, field), getattr(b, field)), field
        assert (a.pieces, a.flipped, a.outward) == (b.pieces, b.flipped, b.outward)


def test_the_closedness_check_counts_open_edges_without_listing_them():
    pytest.importorskip("geovox._lattice")
    mesh, closed = scan()
    with chosen("compiled"):
        assert is_closed(closed) and not is_closed(mesh)
        assert "boundary" not in mesh._cache  # no list of edges was made for the counts
        counts = edge_counts(mesh)
    with chosen("numpy"):
        again = geovox.Mesh(mesh.vertices, mesh.faces)
        assert edge_counts(again) == counts and len(geovox.inside.boundary_edges(again)) == counts[0]


def test_a_scan_that_would_not_fit_is_refused_before_its_repair(monkeypatch):
    from geovox import memory

    mesh, _ = scan()
    faces, n_open = len(mesh.faces), None

    def no_repair(m):
        raise AssertionError("repaired although it would not fit")

    monkeypatch.setattr(choice, "repair", no_repair)
    monkeypatch.setattr(memory, "available_memory", lambda: 1 << 16)  # 64 KiB
    with pytest.raises(MeshTooLargeError) as caught:
        _voxelize(mesh, resolution=8)
    assert isinstance(caught.value, GridTooLargeError) and isinstance(caught.value, MemoryError)
    n_open = edge_counts(mesh)[0]
    said = str(caught.value)
    assert "\n" not in said and f"{faces:,} triangles" in said and f"{n_open:,} open edges" in said
    assert "GiB" in said and "--inside parity or vote" in said
    # Parity needs no repair: the same mesh converts.
    assert _voxelize(mesh, resolution=8, inside="parity").inside == "parity"


def test_the_working_memory_grows_with_faces_positions_and_open_edges():
    base = choice.working_memory(1000, 500, 100)
    assert base > 0
    assert choice.working_memory(2000, 500, 100) > base
    assert choice.working_memory(1000, 600, 100) > base
    assert choice.working_memory(1000, 500, 200) > base


def test_a_file_of_one_degenerate_triangle_repeated_is_empty_and_cheap():
    # Every face is the same point: nothing encloses anything, and the rays
    # are cast through one face, not all.
    pytest.importorskip("geovox._lattice")
    mesh = geovox.Mesh(np.zeros((3 * 5000, 3)), np.arange(3 * 5000).reshape(-1, 3), source="zeros")
    cast = []
    from geovox.backends.numpy import NumpyBackend

    real = NumpyBackend.cast
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(NumpyBackend, "cast", lambda self, m, *a, **k: cast.append(len(m.faces))
                   or real(self, m, *a, **k))
        vol = _voxelize(mesh, shape=(4, 4, 4), bounds=(-1, -1, -1, 1, 1, 1), backend="numpy")
    assert not vol.occupancy.any() and cast == [1]
