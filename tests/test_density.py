"""Coverage density and signed distance: analytic truths, backends, writers, pictures."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from PIL import Image

import geovox
import geovox.formats as F
from geovox.cli import main
from geovox.errors import ParameterError

from conftest import SPOT, box_mesh, from_tm

SPHERE = from_tm(trimesh.creation.icosphere(subdivisions=5, radius=1.0), "sphere")


def test_sphere_coverage_volume_within_half_a_percent(backend):
    vol = geovox.voxelize(SPHERE, resolution=128, density="coverage", supersample=4,
                          density_dtype="float32", backend=backend)
    total = float(vol.density.astype(np.float64).sum()) * float(np.prod(vol.spacing))
    assert abs(total - 4 / 3 * math.pi) / (4 / 3 * math.pi) < 0.005
    assert vol.density.dtype == np.float32 and vol.density.max() <= 1.0


def test_coverage_is_full_inside_and_empty_outside(backend):
    vol = geovox.voxelize(SPHERE, resolution=32, density="coverage", backend=backend,
                          bounds=(-1.2, -1.2, -1.2, 1.2, 1.2, 1.2))
    d = vol.density
    assert d.dtype == np.uint8
    c = [vol.grid.centres(a) for a in range(3)]
    r = np.sqrt(c[0][:, None, None] ** 2 + c[1][None, :, None] ** 2 + c[2][None, None, :] ** 2)
    half_diag = 0.5 * np.linalg.norm(vol.spacing)
    assert np.all(d[r < 0.99 - half_diag] == 255)
    assert np.all(d[r > 1.0 + half_diag] == 0)
    partial = (d > 0) & (d < 255)
    assert partial.any() and np.all(np.abs(r[partial] - 1.0) <= half_diag + 0.01)


def test_box_coverage_is_exact_along_the_rays(backend):
    # x and y faces on voxel boundaries, z faces at 30 % and 85 % of a voxel.
    mesh = box_mesh((1.0, 1.0, 1.3), (3.0, 4.0, 2.85))
    vol = geovox.voxelize(mesh, shape=(5, 5, 5), bounds=(0, 0, 0, 5, 5, 5), density="coverage",
                          density_dtype="float32", supersample=2, backend=backend, axis=2)
    expected = np.zeros(5)
    expected[1], expected[2] = 0.7, 0.85
    np.testing.assert_allclose(vol.density[1:3, 1:4, :], np.broadcast_to(expected, (2, 3, 5)), atol=1e-6)
    assert not vol.density[0].any() and not vol.density[3:].any()


def test_backends_agree_within_one_step():
    if len(geovox.available_backends()) < 2:
        pytest.skip("needs both backends")
    a = geovox.voxelize(SPOT, resolution=48, density="coverage", backend="numpy")
    b = geovox.voxelize(SPOT, resolution=48, density="coverage", backend="embree")
    assert np.abs(a.density.astype(int) - b.density.astype(int)).max() <= 1


def test_sdf_of_a_box_is_exact_in_the_band(backend):
    mesh = box_mesh((-1.0, -0.6, -0.4), (1.0, 0.6, 0.4))
    vol = geovox.voxelize(mesh, resolution=24, bounds=(-1.5, -1.5, -1.5, 1.5, 1.5, 1.5),
                          sdf=True, band=3, backend=backend)
    c = [vol.grid.centres(a) for a in range(3)]
    p = np.stack(np.meshgrid(*c, indexing="ij"), -1)
    half = np.array([1.0, 0.6, 0.4])
    q = np.abs(p) - half
    exact = np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)
    limit = 3 * min(vol.spacing)
    band = np.abs(exact) < limit
    np.testing.assert_allclose(vol.sdf[band], exact[band], atol=1e-5)
    assert np.all(np.abs(vol.sdf[~band]) == pytest.approx(limit, rel=1e-6))
    np.testing.assert_array_equal(vol.sdf < 0, vol.occupancy)


def test_sdf_of_a_sphere_matches_the_analytic_distance(backend):
    vol = geovox.voxelize(SPHERE, resolution=40, sdf=True, backend=backend)
    c = [vol.grid.centres(a) for a in range(3)]
    r = np.sqrt(c[0][:, None, None] ** 2 + c[1][None, :, None] ** 2 + c[2][None, None, :] ** 2)
    band = np.abs(vol.sdf) < 3 * min(vol.spacing) * 0.999
    # The icosphere lies within 0.001 of the true sphere.
    np.testing.assert_allclose(vol.sdf[band], (r - 1.0)[band], atol=2e-3)
    assert band.sum() > 1000


@pytest.mark.parametrize("ext", [".raw", ".h5", ".nrrd", ".npz"])
def test_writers_store_density_and_sdf(tmp_path, ext):
    vol = geovox.voxelize(SPOT, shape=(20, 26, 18), density="coverage", sdf=True)
    F.write(vol, tmp_path / f"v{ext}")
    back = F.read(tmp_path / f"v{ext}")
    np.testing.assert_array_equal(back.density, vol.density)
    np.testing.assert_array_equal(back.sdf, vol.sdf)


def test_sdf_raw_header_is_read_by_vtk(tmp_path):
    io = pytest.importorskip("vtkmodules.vtkIOImage")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    vol = geovox.voxelize(SPOT, shape=(20, 26, 18), sdf=True)
    F.write(vol, tmp_path / "v.raw")
    for reader, name in ((io.vtkMetaImageReader, "v_sdf.mhd"), (io.vtkNrrdReader, "v_sdf.nhdr")):
        r = reader()
        r.SetFileName(str(tmp_path / name))
        r.Update()
        a = vtk_to_numpy(r.GetOutput().GetPointData().GetArray(0))
        assert a.dtype == np.float32
        np.testing.assert_array_equal(a.reshape(18, 26, 20).transpose(2, 1, 0), vol.sdf)


def test_density_and_sdf_in_preview_view_and_cli(tmp_path, capsys):
    out = tmp_path / "v.h5"
    assert main(["convert", SPOT, "-o", str(out), "-r", "24", "--density", "coverage",
                 "--supersample", "2", "--sdf", "--band", "2", "--preview", str(tmp_path / "p.png"),
                 "-q"]) == 0
    back = F.read(out)
    assert back.density.dtype == np.uint8 and back.sdf.dtype == np.float32
    assert np.abs(back.sdf).max() == pytest.approx(2 * min(back.spacing), rel=1e-6)
    with Image.open(tmp_path / "p.png") as im:
        img = np.asarray(im.convert("RGB"))
    assert (np.abs(img.astype(int) - (40, 90, 255)).sum(-1) < 30).any()  # blue inside distance
    pytest.importorskip("pyvista")
    assert main(["view", str(out), "--screenshot", str(tmp_path / "s.png")]) == 0


def test_bad_density_options():
    with pytest.raises(ParameterError, match="`density`"):
        geovox.voxelize(SPOT, resolution=8, density="fog")
    with pytest.raises(ParameterError, match="`supersample`"):
        geovox.voxelize(SPOT, resolution=8, density="coverage", supersample=0)
    with pytest.raises(ParameterError, match="`band`"):
        geovox.voxelize(SPOT, resolution=8, sdf=True, band=-1)
