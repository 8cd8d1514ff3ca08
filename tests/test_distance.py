"""Distance fields from the nearest-point stage: exact against an independent reference.

The reference is a float64 point-to-triangle distance written here from
Ericson's region tests (Real-Time Collision Detection, 5.1.5), not geovox's
formula, taken as the minimum over every triangle of the mesh. A value
passes when ``|value - reference| <= 1e-5 voxel + 1e-6 |value|`` (float32
rounding is about 6e-8 of the value).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

import geovox
from geovox.errors import GeovoxWarning
from geovox.kernels import chosen
from geovox.nearest import band_distances, kernel_module, nearest_distances

from conftest import DATA, SPOT

TRUCK = os.path.join(DATA, "wild", "truck.obj")


def reference_distance(points: np.ndarray, triangles: np.ndarray, block: int = 1 << 21):
    """(n,) float64: the smallest distance from each point to the triangles (brute force)."""
    a, b, c = (np.asarray(triangles[:, k], float) for k in range(3))
    out = np.full(len(points), np.inf)
    per = max(1, block // len(a))
    for s in range(0, len(points), per):
        p = np.asarray(points[s:s + per], float)[:, None, :]
        q = _closest_point(p, a[None], b[None], c[None])
        d = np.sqrt(((p - q) ** 2).sum(axis=2)).min(axis=1)
        out[s:s + per] = d
    return out


def _closest_point(p, a, b, c):
    """Ericson's closest point on triangle abc to p, broadcast over (points, triangles)."""
    dot = lambda u, v: (u * v).sum(axis=-1, keepdims=True)  # noqa: E731
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = dot(ab, ap), dot(ac, ap)
    bp = p - b
    d3, d4 = dot(ab, bp), dot(ac, bp)
    cp = p - c
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        v = vb / denom
        w = vc / denom
        face = a + ab * v + ac * w
        t_ab = d1 / (d1 - d3)
        t_ac = d2 / (d2 - d6)
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
    out = face
    # Regions, the later ones winning where Ericson's early returns would.
    out = np.where((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + (c - b) * t_bc, out)
    out = np.where((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + ac * t_ac, out)
    out = np.where((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + ab * t_ab, out)
    out = np.where((d6 >= 0) & (d5 <= d6), c, out)
    out = np.where((d3 >= 0) & (d4 <= d3), b, out)
    out = np.where((d1 <= 0) & (d2 <= 0), a, out)
    # Zero-area triangles: the nearest of the three edges.
    flat = ~np.isfinite(out).all(axis=-1, keepdims=True) | (np.abs(denom) < 1e-300)
    if flat.any():
        best = None
        for s, e in ((a, b), (a, c), (b, c)):
            d = e - s
            t = np.clip(np.nan_to_num(dot(p - s, d) / np.maximum(dot(d, d), 1e-300)), 0, 1)
            q = s + d * t
            best = q if best is None else np.where(dot(p - q, p - q) < dot(p - best, p - best),
                                                   q, best)
        out = np.where(flat, best, out)
    return out


def centres(vol, index):
    """World centres of the voxels ``index`` (n, 3)."""
    return np.asarray(vol.grid.lo) + (index + 0.5) * np.asarray(vol.grid.spacing)


def check_exact(vol, mesh_triangles, index, band):
    """Every voxel of ``index``: exact within the band, the band's limit beyond it."""
    h = float(np.min(vol.grid.spacing))
    value = vol.sdf[tuple(index.T)].astype(np.float64)
    ref = reference_distance(centres(vol, index), mesh_triangles)
    tol = 1e-5 * h + 1e-6 * np.abs(value)
    limit = band * h
    near = ref < limit - 2 * tol
    err = np.abs(np.abs(value) - ref)
    assert np.all(err[near] <= tol[near]), f"worst {err[near].max() / h:.3g} voxels"
    if math.isfinite(band):
        beyond = ref > limit + 2 * tol
        np.testing.assert_array_equal(np.abs(value[beyond]), np.float32(limit))
    return near.sum()


def sample(shape, n, seed=0, among=None):
    rng = np.random.default_rng(seed)
    pool = np.argwhere(np.ones(shape, bool) if among is None else among)
    return pool[rng.choice(len(pool), size=min(n, len(pool)), replace=False)]


def test_band_is_exact_and_clamped_on_spot():
    vol = geovox.voxelize(SPOT, resolution=48, sdf=True)
    tris = geovox.load_mesh(SPOT).triangles
    h = float(np.min(vol.grid.spacing))
    idx = np.concatenate([sample(vol.shape, 1200, 1, np.abs(vol.sdf) < 3 * h),
                          sample(vol.shape, 300, 2)])
    assert check_exact(vol, tris, idx, 3.0) > 1000
    # Negative exactly where the solid is.
    np.testing.assert_array_equal(np.signbit(vol.sdf), vol.occupancy)


def test_band_inf_is_exact_everywhere():
    vol = geovox.voxelize(SPOT, resolution=40, sdf=True, band=math.inf)
    tris = geovox.load_mesh(SPOT).triangles
    idx = sample(vol.shape, 1500, 3)
    assert check_exact(vol, tris, idx, math.inf) == len(idx)
    np.testing.assert_array_equal(np.signbit(vol.sdf), vol.occupancy)
    # Far voxels are far: no clamp anywhere.
    assert np.abs(vol.sdf).max() > 10 * np.min(vol.grid.spacing)


def test_band_values_do_not_depend_on_band_inf():
    """Inside the band, band 3 and band inf are the same numbers (two engines, one answer)."""
    a = geovox.voxelize(SPOT, resolution=40, sdf=True)
    b = geovox.voxelize(SPOT, resolution=40, sdf=True, band=math.inf)
    h = np.float32(3 * np.min(a.grid.spacing))
    inner = np.abs(b.sdf) < h
    np.testing.assert_array_equal(a.sdf[inner], b.sdf[inner])
    np.testing.assert_array_equal(np.abs(a.sdf[~inner]), h)


def test_leaky_model_takes_the_winding_numbers_sign():
    with pytest.warns(GeovoxWarning):
        vol = geovox.voxelize(TRUCK, resolution=24, sdf=True, band=math.inf)
    assert vol.inside == "winding"
    tris = geovox.load_mesh(TRUCK).triangles
    idx = sample(vol.shape, 800, 4)
    check_exact(vol, tris, idx, math.inf)
    np.testing.assert_array_equal(np.signbit(vol.sdf), vol.occupancy)
    assert vol.occupancy.any() and not vol.occupancy.all()


def open_sheet(n=8):
    """A wavy open sheet over the unit square: (2 n², 3, 3) triangles."""
    u, v = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    z = 0.15 * np.sin(3 * u) * np.cos(2 * v)
    verts = np.stack([u, v, z], axis=-1).reshape(-1, 3)
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None]
    i = i.reshape(-1)
    faces = np.concatenate([np.stack([i, i + n + 1, i + 1], 1),
                            np.stack([i + 1, i + n + 1, i + n + 2], 1)])
    return trimesh.Trimesh(verts, faces, process=False)


def test_unsigned_distance_of_an_open_sheet():
    sheet = open_sheet()
    vol = geovox.voxelize(sheet, resolution=24, occupancy="surface", sdf="unsigned",
                          band=math.inf, bounds=(-0.2, -0.2, -0.4, 1.2, 1.2, 0.4))
    assert (vol.sdf >= 0).all() and not np.signbit(vol.sdf).any()
    idx = np.argwhere(np.ones(vol.shape, bool))
    check_exact(vol, sheet.triangles, idx, math.inf)
    # And in a band, the same numbers within it.
    banded = geovox.voxelize(sheet, resolution=24, occupancy="surface", sdf="unsigned",
                             band=2.0, bounds=(-0.2, -0.2, -0.4, 1.2, 1.2, 0.4))
    check_exact(banded, sheet.triangles, idx, 2.0)


@pytest.mark.parametrize("kernel", ["numpy", "compiled"])
def test_compiled_and_numpy_give_the_same_bits(kernel):
    if kernel == "compiled" and kernel_module() is None:
        pytest.skip("the compiled kernel is not built")
    mesh = geovox.load_mesh(SPOT)
    vol = geovox.voxelize(SPOT, resolution=32)
    g = vol.grid
    h = float(np.min(g.spacing))
    with chosen(kernel):
        band = band_distances(mesh.triangles, g.shape, g.spacing, origin=g.lo, limit=2.5 * h)
        near = nearest_distances(mesh.triangles, np.ones(g.shape, bool, order="F"), g.spacing,
                                 origin=g.lo, z0=0)
    with chosen("numpy"):
        band_np = band_distances(mesh.triangles, g.shape, g.spacing, origin=g.lo, limit=2.5 * h)
        near_np = nearest_distances(mesh.triangles, np.ones(g.shape, bool, order="F"),
                                    g.spacing, origin=g.lo, z0=0)
    lim = np.float32(2.5 * h)
    np.testing.assert_array_equal(np.minimum(band, lim), np.minimum(band_np, lim))
    np.testing.assert_array_equal(near, near_np)
    # The two engines agree within the band.
    inner = near < lim
    np.testing.assert_array_equal(band[inner], near[inner])


def test_slabs_are_the_whole_grids_slices():
    """A block of layers measures its voxels as the whole grid does (z0 and the frame)."""
    mesh = geovox.load_mesh(SPOT)
    g = geovox.voxelize(SPOT, resolution=32).grid
    h = float(np.min(g.spacing))
    nx, ny, nz = g.shape
    whole = band_distances(mesh.triangles, g.shape, g.spacing, origin=g.lo, limit=3 * h)
    part = band_distances(mesh.triangles, (nx, ny, 8), g.spacing, origin=g.lo, limit=3 * h,
                          z0=12)
    lim = np.float32(3 * h)
    w = np.minimum(whole.reshape(g.shape, order="F")[:, :, 12:20], lim)
    np.testing.assert_array_equal(np.minimum(part.reshape((nx, ny, 8), order="F"), lim), w)


def test_vdb_slab_by_slab_holds_the_whole_volume(tmp_path):
    kw = dict(resolution=96, sdf=True)
    vol = geovox.voxelize(SPOT, **kw)
    geovox.formats.write(vol, tmp_path / "whole.vdb")
    geovox.convert_to(SPOT, tmp_path / "slabs.vdb", budget=2e6, **kw)  # 64-layer slabs
    whole = geovox.formats.read(tmp_path / "whole.vdb")
    back = geovox.formats.read(tmp_path / "slabs.vdb")
    np.testing.assert_array_equal(whole.sdf, vol.sdf)
    np.testing.assert_array_equal(whole.occupancy, vol.occupancy)
    # The slabs' rays run along y, the whole grid's along z: voxel centres on the surface
    # (within 1e-8 of it) may take either side, as in every slab-by-slab format.
    on_surface = np.abs(vol.sdf) < 1e-6 * np.min(vol.grid.spacing)
    differ = np.signbit(back.sdf) != np.signbit(vol.sdf)
    assert not (differ & ~on_surface).any()
    np.testing.assert_array_equal(np.abs(back.sdf), np.abs(vol.sdf))
    np.testing.assert_array_equal(back.occupancy, np.signbit(back.sdf))


def test_vdb_writer_in_slabs_makes_the_whole_writes_trees(tmp_path):
    """The slab writer's trees from a volume cut into 64-layer slabs are a whole write's."""
    from geovox.formats import vdb
    from geovox.formats.base import as_meta
    from geovox.volume import Volume

    vol = geovox.voxelize(SPOT, resolution=150, sdf=True, color=True)
    writer = vdb.VDBWriter(tmp_path / "t.vdb", as_meta(vol))
    nz = vol.shape[2]
    for z0 in range(0, nz, 64):
        z1 = min(z0 + 64, nz)
        part = Volume(occupancy=np.asfortranarray(vol.occupancy[:, :, z0:z1]), grid=vol.grid,
                      backend="numpy", colors=vol.colors[:, :, z0:z1],
                      sdf=np.asfortranarray(vol.sdf[:, :, z0:z1]))
        writer.write(z0, part)
    for (g, _), parts, whole in zip(writer.specs, writer.parts, vdb._grids(vol)):
        slabs = writer._tree(g, parts)()
        mine = vdb._tree(whole)
        assert slabs[0] == mine[0] and slabs[1] == mine[1], g.name
    try:
        raise RuntimeError("stop here")  # abort is called from an except block
    except RuntimeError:
        writer.abort()
    assert not list(tmp_path.iterdir())  # nothing left behind


def test_sparse_formats_carry_the_band(tmp_path):
    vol = geovox.voxelize(SPOT, resolution=40, sdf=True)
    h = np.float32(3 * np.min(vol.grid.spacing))
    for name, opts in (("s.npz", {"sparse": True}), ("s.ply", {})):
        geovox.formats.write(vol, tmp_path / name, **opts)
        back = geovox.formats.read(tmp_path / name)
        np.testing.assert_array_equal(back.occupancy, vol.occupancy)
        np.testing.assert_array_equal(back.sdf, vol.sdf)
    with np.load(tmp_path / "s.npz") as z:
        assert len(z["coords"]) == np.count_nonzero(vol.occupancy | (np.abs(vol.sdf) < h))
        assert z["occupied"].sum() == vol.occupancy.sum()
    head = (tmp_path / "s.ply").read_bytes()[:1000]
    assert b"property uchar occupied" in head and b"property float sdf" in head


@pytest.mark.parametrize("args, says", [
    (["--band", "0"], "--band: must be a positive number of voxels or inf, got '0'"),
    (["--band", "-1"], "--band: must be a positive number of voxels or inf, got '-1'"),
    (["--band", "nan"], "--band: must be a positive number of voxels or inf, got 'nan'"),
    (["--sdf", "sideways"], "--sdf: must be 'signed' or 'unsigned', got 'sideways'"),
])
def test_bad_distance_options_are_one_line(tmp_path, args, says):
    out = tmp_path / "o.npz"
    argv = ["convert", SPOT, "-o", str(out), "-r", "16"] + (["--sdf"] if args[0] != "--sdf"
                                                             else []) + args
    p = subprocess.run([sys.executable, "-m", "geovox", *argv], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 2
    lines = [line for line in p.stderr.splitlines() if line.strip()]
    assert says in lines[-1] and "Traceback" not in p.stderr
    assert not out.exists()


def test_dense_band_inf_that_cannot_fit_is_refused_before_allocating(tmp_path):
    out = tmp_path / "huge.npz"
    p = subprocess.run([sys.executable, "-m", "geovox", "convert", SPOT, "-o", str(out),
                        "-r", "4000", "--sdf", "--band", "inf"], capture_output=True, text=True,
                       timeout=120)
    assert p.returncode == 2, p.stderr
    assert "Traceback" not in p.stderr and len(p.stderr.strip().splitlines()) == 1
    assert not out.exists()


def test_vdb_level_set_as_openvdb_reads_it(tmp_path):
    from test_vdb import _has_openvdb, openvdb_read

    if not _has_openvdb():
        pytest.skip("OpenVDB's reader (python3-openvdb) is not installed")
    kw = dict(resolution=64, sdf=True)
    # Slab by slab (several slabs) as the command line writes a big grid, and the .npz.
    geovox.convert_to(SPOT, tmp_path / "s.vdb", budget=3e6, **kw)
    vol = geovox.voxelize(SPOT, **kw)
    geovox.formats.write(vol, tmp_path / "s.npz")
    with np.load(tmp_path / "s.npz") as z:
        sdf = z["sdf"]
    g = openvdb_read(tmp_path / "s.vdb", vol.shape)["sdf"]
    h = np.float32(3 * np.min(vol.grid.spacing))
    assert str(g["class"]) == "level set"
    assert g["background"] == h  # 3 voxels
    active = g["active"]
    np.testing.assert_array_equal(active, np.abs(sdf) < h)
    np.testing.assert_array_equal(g["values"][active], sdf[active])
    # Inactive: the background outside, minus it inside (tiles included).
    np.testing.assert_array_equal(g["values"][~active], np.where(sdf[~active] < 0, -h, h))


def test_unsigned_vdb_is_no_level_set(tmp_path):
    from test_vdb import _has_openvdb, openvdb_read

    if not _has_openvdb():
        pytest.skip("OpenVDB's reader (python3-openvdb) is not installed")
    vol = geovox.voxelize(open_sheet(), resolution=24, occupancy="surface", sdf="unsigned")
    assert vol.unsigned
    geovox.formats.write(vol, tmp_path / "u.vdb")
    g = openvdb_read(tmp_path / "u.vdb", vol.shape)["sdf"]
    assert str(g["class"]) == "unknown"
    active = g["active"]
    np.testing.assert_array_equal(g["values"][active], vol.sdf[active])
