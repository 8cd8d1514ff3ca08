"""Reference grids (``like=``, ``--like``): oblique, anisotropic scans as NIfTI, NRRD and MetaImage.

The truth for occupancy is the mesh moved into the grid's index space by
hand and voxelised on the plain axis-aligned grid whose voxel centres are the
integer points; for colour and distance, brute-force searches in world
coordinates; for the written files, nibabel, pynrrd, SimpleITK and VTK.
"""

from __future__ import annotations

import json
import os
import struct

import numpy as np
import pytest
import trimesh

import geovox
from geovox import formats
from geovox.cli import main
from geovox.errors import GeovoxWarning, ParameterError
from geovox.reference import (RAS_FROM_LPS, load_reference, mesh_space_mark, parse_mhd,
                              reference_grid)

from conftest import SPOT

nibabel = pytest.importorskip("nibabel")
nrrd = pytest.importorskip("nrrd")

SHAPE = (40, 36, 24)
SPACING = np.array([0.8, 1.1, 1.7])


def rotation(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    r = np.eye(3)
    i, j = (a for a in range(3) if a != axis)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


#: Rotated about two axes (x by 0.4 rad, z by 0.7 rad), anisotropic, LPS.
DIRECTION = rotation(0, 0.4) @ rotation(2, 0.7)
AFFINE = np.eye(4)
AFFINE[:3, :3] = DIRECTION * SPACING
AFFINE[:3, 3] = -AFFINE[:3, :3] @ ((np.asarray(SHAPE) - 1) / 2) + [3.0, -2.0, 1.0]


def sphere(radius=12.0, subdivisions=3):
    return trimesh.creation.icosphere(subdivisions, radius=radius)


def write_references(folder) -> dict:
    """The oblique reference as NIfTI (RAS), NRRD (LPS) and MetaImage (LPS), with voxels."""
    data = (np.arange(np.prod(SHAPE)) % 251).reshape(SHAPE).astype(np.int16)
    paths = {k: os.path.join(folder, f"ref.{k}") for k in ("nii.gz", "nrrd", "mhd")}
    nibabel.save(nibabel.Nifti1Image(data, RAS_FROM_LPS @ AFFINE), paths["nii.gz"])
    nrrd.write(paths["nrrd"], data, {"space": "left-posterior-superior",
                                     "space directions": AFFINE[:3, :3].T,
                                     "space origin": AFFINE[:3, 3]})
    # MetaImage written by hand (geovox parses it; SimpleITK's own writer is checked below).
    tm = " ".join(repr(float(v)) for v in DIRECTION.T.reshape(-1))
    with open(paths["mhd"], "w") as f:
        f.write(f"ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\n"
                f"TransformMatrix = {tm}\nOffset = {' '.join(repr(float(v)) for v in AFFINE[:3, 3])}\n"
                f"AnatomicalOrientation = RAI\n"
                f"ElementSpacing = {' '.join(repr(float(v)) for v in SPACING)}\n"
                f"DimSize = {' '.join(map(str, SHAPE))}\nElementType = MET_SHORT\n"
                f"ElementDataFile = ref.raw\n")
    data.T.astype("<i2").tofile(os.path.join(folder, "ref.raw"))
    return paths


@pytest.fixture(scope="module")
def refs(tmp_path_factory):
    return write_references(str(tmp_path_factory.mktemp("refs")))


def index_space_truth(mesh, affine, shape, space_flip=False):
    """The mesh moved into index space by hand, voxelised on the unit grid centred on the integers."""
    a = np.linalg.inv(affine)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if space_flip:
        v = v * [-1.0, -1.0, 1.0]
    moved = trimesh.Trimesh(v @ a[:3, :3].T + a[:3, 3], mesh.faces, process=False)
    n = np.asarray(shape, dtype=np.float64)
    return geovox.voxelize(moved, shape=tuple(shape), bounds=(-0.5, -0.5, -0.5, *(n - 0.5)))


@pytest.mark.parametrize("kind", ["nii.gz", "nrrd", "mhd"])
def test_reference_is_read_with_its_oblique_affine(refs, kind):
    ref = load_reference(refs[kind])
    assert ref.shape == SHAPE
    # NIfTI stores the affine in float32: rounding there only.
    np.testing.assert_allclose(ref.affine_in("LPS"), AFFINE, rtol=0, atol=1e-5 if kind == "nii.gz" else 1e-12)
    np.testing.assert_allclose(ref.spacing, SPACING, rtol=1e-6)
    assert ref.orthogonal
    assert ref.space == ("RAS" if kind == "nii.gz" else "LPS")


@pytest.mark.parametrize("kind", ["nii.gz", "nrrd", "mhd"])
def test_mask_equals_the_mesh_voxelised_in_index_space(refs, kind, backend):
    mesh = sphere()
    vol = geovox.voxelize(mesh, like=refs[kind], backend=backend)
    truth = index_space_truth(mesh, load_reference(refs[kind]).affine_in("LPS"), SHAPE)
    differ = int(np.count_nonzero(vol.occupancy ^ truth.occupancy))
    # The local frame is index space scaled per axis: only float rounding can differ,
    # and on this fixture nothing does (counted, not assumed).
    assert differ == 0, differ
    assert 3000 < vol.inside_count < SHAPE[0] * SHAPE[1] * SHAPE[2]
    assert vol.mesh_space == ("LPS", "assumed: no file to read a SPACE= mark from")


def test_spot_on_an_oblique_grid_matches_index_space():
    vol = geovox.voxelize(SPOT, like=(AFFINE / [[20], [20], [20], [1]] * [1, 1, 1, 1] + _shift(), SHAPE))
    ref = vol.grid.reference
    truth = index_space_truth(trimesh.load(SPOT, process=False), ref.affine, SHAPE)
    assert vol.inside_count > 1000
    assert int(np.count_nonzero(vol.occupancy ^ truth.occupancy)) == 0


def _shift():
    s = np.zeros((4, 4))
    s[:3, 3] = [0.0, 0.1, 0.2]
    return s


def test_nifti_output_affine_is_the_references(refs, tmp_path):
    out = str(tmp_path / "mask.nii.gz")
    assert main(["convert", os.fspath(_stl(tmp_path)), "--like", refs["nii.gz"], "-o", out, "-q"]) == 0
    img, ref_img = nibabel.load(out), nibabel.load(refs["nii.gz"])
    np.testing.assert_array_equal(img.affine, ref_img.affine)
    np.testing.assert_allclose(img.header.get_qform(), ref_img.affine, atol=1e-5)
    assert img.header.get_sform(coded=True)[1] == 1 and img.header.get_qform(coded=True)[1] == 1
    assert img.get_data_dtype() == np.uint8 and img.shape == SHAPE
    assert set(np.unique(np.asarray(img.dataobj))) == {0, 1}


def test_nrrd_output_keeps_the_references_space(refs, tmp_path):
    out = str(tmp_path / "mask.nrrd")
    assert main(["convert", os.fspath(_stl(tmp_path)), "--like", refs["nrrd"], "-o", out, "-q"]) == 0
    _, h = nrrd.read(out)
    _, r = nrrd.read(refs["nrrd"])
    assert h["space"] == r["space"] == "left-posterior-superior"
    np.testing.assert_allclose(h["space directions"], r["space directions"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(h["space origin"], r["space origin"], rtol=0, atol=1e-12)
    # From a NIfTI reference: RAS, as the reference has it.
    out2 = str(tmp_path / "mask2.nrrd")
    assert main(["convert", os.fspath(_stl(tmp_path)), "--like", refs["nii.gz"], "-o", out2, "-q"]) == 0
    assert nrrd.read_header(out2)["space"] == "right-anterior-superior"


def _stl(tmp_path, header=b"", name="sphere.stl", mesh=None):
    """A binary STL of ``mesh`` (default the sphere) with an 80-byte header."""
    mesh = sphere() if mesh is None else mesh
    path = tmp_path / name
    tri = mesh.triangles.astype("<f4")
    with open(path, "wb") as f:
        f.write(header.ljust(80, b" ")[:80])
        f.write(struct.pack("<I", len(tri)))
        rec = np.zeros(len(tri), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
        rec["v"] = tri
        f.write(rec.tobytes())
    return path


def test_slicer_marks_are_read_where_slicer_writes_them(tmp_path):
    assert mesh_space_mark(_stl(tmp_path, b"3D Slicer output. SPACE=RAS", "a.stl")) == "RAS"
    assert mesh_space_mark(_stl(tmp_path, b"3D Slicer output. SPACE=LPS", "b.stl")) == "LPS"
    assert mesh_space_mark(_stl(tmp_path, b"", "c.stl")) is None
    (tmp_path / "d.obj").write_text("# 3D Slicer output. SPACE=RAS\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert mesh_space_mark(tmp_path / "d.obj") == "RAS"
    # Only the leading comment counts.
    (tmp_path / "e.obj").write_text("v 0 0 0\n# SPACE=RAS\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert mesh_space_mark(tmp_path / "e.obj") is None
    (tmp_path / "f.ply").write_text("ply\nformat ascii 1.0\ncomment SPACE=LPS\nelement vertex 0\n"
                                    "end_header\n")
    assert mesh_space_mark(tmp_path / "f.ply") == "LPS"
    (tmp_path / "g.vtk").write_text("# vtk DataFile Version 4.2\n3D Slicer output. SPACE=RAS\nASCII\n")
    assert mesh_space_mark(tmp_path / "g.vtk") == "RAS"
    (tmp_path / "h.stl").write_text("solid 3D Slicer output. SPACE=RAS\nendsolid\n")
    assert mesh_space_mark(tmp_path / "h.stl") == "RAS"


def test_a_mesh_marked_ras_lands_mirrored_in_x_and_y(tmp_path):
    # An axis-aligned LPS grid centred on the origin, and a box off-centre in x and y.
    n = np.array([30, 26, 20])
    a = np.eye(4)
    a[:3, :3] = np.diag([1.0, 1.2, 1.5])
    a[:3, 3] = -a[:3, :3] @ ((n - 1) / 2)
    box = trimesh.creation.box(extents=(6, 4, 8))
    box.apply_translation([5.3, -3.1, 0.7])
    plain = _stl(tmp_path, b"", "plain.stl", box)
    marked = _stl(tmp_path, b"3D Slicer output. SPACE=RAS", "ras.stl", box)
    lps = geovox.voxelize(os.fspath(plain), like=(a, tuple(n)))
    ras = geovox.voxelize(os.fspath(marked), like=(a, tuple(n)))
    assert lps.mesh_space[0] == "LPS" and ras.mesh_space == ("RAS", "the file's SPACE=RAS mark")
    assert lps.inside_count > 50
    np.testing.assert_array_equal(ras.occupancy, lps.occupancy[::-1, ::-1, :])
    assert not np.array_equal(ras.occupancy, lps.occupancy)
    # --mesh-space overrides the mark.
    forced = geovox.voxelize(os.fspath(marked), like=(a, tuple(n)), mesh_space="lps")
    np.testing.assert_array_equal(forced.occupancy, lps.occupancy)
    assert forced.mesh_space == ("LPS", "given")


def test_without_like_the_mark_changes_nothing(tmp_path):
    box = trimesh.creation.box(extents=(6, 4, 8))
    box.apply_translation([5.3, -3.1, 0.7])
    a = geovox.voxelize(os.fspath(_stl(tmp_path, b"", "p.stl", box)), resolution=16)
    b = geovox.voxelize(os.fspath(_stl(tmp_path, b"SPACE=RAS", "r.stl", box)), resolution=16)
    np.testing.assert_array_equal(a.occupancy, b.occupancy)
    assert a.bounds == b.bounds and a.mesh_space is None
    with pytest.raises(ParameterError, match="mesh_space"):
        geovox.voxelize(box, resolution=8, mesh_space="ras")


def brute_distance(mesh, points) -> np.ndarray:
    """(n,) float64: each point's distance to its nearest triangle, by trying every triangle."""
    best = np.full(len(points), np.inf)
    for tri in mesh.triangles:
        near = trimesh.triangles.closest_point(np.repeat(tri[None], len(points), axis=0), points)
        best = np.minimum(best, np.linalg.norm(near - points, axis=1))
    return best


def _world_centres(ref):
    ijk = np.stack(np.meshgrid(*[np.arange(k) for k in ref.shape], indexing="ij"), -1).reshape(-1, 3)
    a = ref.affine_in("LPS")
    return ijk, ijk @ a[:3, :3].T + a[:3, 3]


def test_sdf_is_the_world_distance_on_an_anisotropic_oblique_grid():
    mesh = sphere(subdivisions=2)
    vol = geovox.voxelize(mesh, like=(AFFINE, SHAPE), sdf=True, band=2.0)
    _, world = _world_centres(vol.grid.reference)
    sdf = vol.sdf.reshape(-1, order="C")
    near = np.abs(sdf) < 2.0 * SPACING.min() * 0.999
    dist = brute_distance(mesh, world[near])
    sign = np.where(vol.occupancy.reshape(-1)[near], -1.0, 1.0)
    err = np.abs(sdf[near] - sign * dist)
    assert near.sum() > 500
    assert err.max() < 1e-5, err.max()  # float32 storage; world units, not index units
    # Beyond the band: clamped to band x the smallest spacing, in world units.
    assert np.isclose(np.abs(vol.sdf).max(), 2.0 * SPACING.min(), rtol=1e-6)


def test_colour_is_the_world_nearest_surface_points_on_an_oblique_grid():
    # One colour per face: each inside voxel's colour names the face geovox found nearest.
    mesh = sphere(radius=12.0, subdivisions=1)
    colours = np.zeros((len(mesh.faces), 4), dtype=np.uint8)
    colours[:, 0] = np.arange(len(mesh.faces)) * 3
    colours[:, 1] = 255 - np.arange(len(mesh.faces)) * 3
    colours[:, 2], colours[:, 3] = 77, 255
    mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=colours)
    vol = geovox.voxelize(mesh, like=(AFFINE, SHAPE), color=True)
    ijk, world = _world_centres(vol.grid.reference)
    inside = vol.occupancy.reshape(-1)
    rgba = vol.colors.reshape(-1, 4)[inside]
    face = {(int(c[0]), int(c[1])): f for f, c in enumerate(colours)}
    chosen = np.array([face[(int(c[0]), int(c[1]))] for c in rgba])
    pts = world[inside]
    best = brute_distance(mesh, pts)
    got = np.linalg.norm(trimesh.triangles.closest_point(mesh.triangles[chosen], pts) - pts, axis=1)
    # The chosen face is at the smallest world distance (ties within 1e-9 allowed).
    assert inside.sum() > 3000
    assert np.abs(got - best).max() < 1e-9


def test_coverage_on_an_oblique_grid_sums_to_the_volume():
    mesh = sphere(subdivisions=3)
    vol = geovox.voxelize(mesh, like=(AFFINE, SHAPE), density="coverage",
                          density_dtype="float32")
    total = float(vol.density.astype(np.float64).sum()) * float(np.prod(SPACING))
    assert abs(total / mesh.volume - 1) < 0.005


def test_streaming_onto_a_reference_equals_the_whole_volume(refs, tmp_path):
    mesh = sphere()
    whole = geovox.voxelize(mesh, like=refs["nrrd"], color=True)
    out = str(tmp_path / "s.h5")
    info = geovox.convert_to(mesh, out, like=refs["nrrd"], color=True, budget=40 * 36 * 64 * 4)
    assert info["slabs"] == 1 or info["slabs"] >= 1
    back = formats.read(out)
    np.testing.assert_array_equal(back.occupancy, whole.occupancy)
    np.testing.assert_array_equal(back.colors, whole.colors)
    import h5py

    with h5py.File(out) as f:
        np.testing.assert_allclose(f.attrs["affine"], AFFINE, atol=1e-12)
        assert f.attrs["space"] == "LPS"
        np.testing.assert_allclose(f["VTKHDF"].attrs["Direction"], DIRECTION.reshape(-1), atol=1e-12)
    # Occupancy alone, streamed 64 slices at a time, into RAW with its headers.
    big = tmp_path / "big.nrrd"
    n = (70, 60, 130)
    nrrd.write(str(big), np.zeros(n, np.uint8), {"space": "left-posterior-superior",
                                                 "space directions": (AFFINE[:3, :3] / 3).T,
                                                 "space origin": AFFINE[:3, 3]})
    raw = str(tmp_path / "big.raw")
    info = geovox.convert_to(mesh, raw, like=str(big))
    assert info["filled_in_slabs"] or info["slabs"] >= 1
    mem = geovox.voxelize(mesh, like=str(big))
    np.testing.assert_array_equal(formats.read(raw).occupancy, mem.occupancy)


def test_every_output_is_placed_as_simpleitk_reads_it(refs, tmp_path):
    sitk = pytest.importorskip("SimpleITK")
    stl = os.fspath(_stl(tmp_path))
    for kind in ("nii.gz", "nrrd", "mhd"):
        ref = sitk.ReadImage(refs[kind])
        for ext in (".nii", ".nii.gz", ".nrrd", ".raw"):
            out = str(tmp_path / f"{kind.replace('.', '_')}{ext}")
            assert main(["convert", stl, "--like", refs[kind], "-o", out, "-q", "--color",
                         "--sdf"]) == 0
            stem = out[:-len(ext)]
            readable = {".nii": [out, stem + "_rgba.nii", stem + "_sdf.nii"],
                        ".nii.gz": [out, stem + "_sdf.nii.gz"],
                        ".nrrd": [out, stem + "_rgba.nrrd", stem + "_sdf.nrrd"],
                        ".raw": [stem + ".mhd", stem + ".nhdr", stem + "_rgba.mhd",
                                 stem + "_sdf.nhdr"]}[ext]
            for path in readable:
                img = sitk.ReadImage(path)
                assert img.GetSize() == SHAPE, path
                np.testing.assert_allclose(img.GetOrigin(), ref.GetOrigin(), atol=1e-5, err_msg=path)
                np.testing.assert_allclose(img.GetSpacing(), ref.GetSpacing(), rtol=1e-6, err_msg=path)
                np.testing.assert_allclose(img.GetDirection(), ref.GetDirection(), atol=1e-6,
                                           err_msg=path)
    # SimpleITK's own MetaImage writer: geovox reads its TransformMatrix the same way.
    img = sitk.ReadImage(refs["nrrd"])
    sitk.WriteImage(img, str(tmp_path / "itk.mhd"))
    np.testing.assert_allclose(load_reference(str(tmp_path / "itk.mhd")).affine, AFFINE, atol=1e-9)


def test_vtkhdf_direction_is_read_by_vtk(refs, tmp_path):
    vtk = pytest.importorskip("vtk")
    out = str(tmp_path / "m.vtkhdf")
    geovox.formats.write(geovox.voxelize(sphere(), like=refs["mhd"]), out)
    r = vtk.vtkHDFReader()
    r.SetFileName(out)
    r.Update()
    img = r.GetOutput()
    m = img.GetDirectionMatrix()
    np.testing.assert_allclose([[m.GetElement(i, j) for j in range(3)] for i in range(3)],
                               DIRECTION, atol=1e-12)
    np.testing.assert_allclose(img.GetOrigin(), AFFINE[:3, 3], atol=1e-12)
    np.testing.assert_allclose(img.GetSpacing(), SPACING, atol=1e-12)


@pytest.mark.parametrize("kind", ["nrrd", "nii.gz"])
@pytest.mark.parametrize("ext", [".h5", ".json", ".npz", ".nrrd", ".nii.gz", ".vtkhdf", ".zarr"])
def test_a_volume_geovox_wrote_is_a_reference(refs, tmp_path, ext, kind):
    if ext == ".zarr":
        pytest.importorskip("zarr")
    vol = geovox.voxelize(sphere(), like=refs[kind])
    target = str(tmp_path / ("v.raw" if ext == ".json" else "v" + ext))
    geovox.formats.write(vol, target)
    again = load_reference(str(tmp_path / ("v" + ext)))
    assert again.shape == SHAPE
    np.testing.assert_allclose(again.affine_in("LPS"), vol.grid.reference.affine_in("LPS"),
                               atol=1e-5 if ext == ".nii.gz" else 1e-12)
    np.testing.assert_allclose(again.affine_in("LPS"), AFFINE, atol=1e-5)
    np.testing.assert_array_equal(geovox.voxelize(sphere(), like=again).occupancy, vol.occupancy)


def test_plain_outputs_are_unchanged_by_the_new_fields(tmp_path):
    vol = geovox.voxelize(sphere(), resolution=12)
    written = geovox.formats.write(vol, str(tmp_path / "p.raw"))
    meta = json.loads((tmp_path / "p.json").read_text())
    assert "affine" not in meta and "space" not in meta
    assert "TransformMatrix = 1 0 0 0 1 0 0 0 1" in (tmp_path / "p.mhd").read_text()
    assert "space:" not in (tmp_path / "p.nhdr").read_text()
    assert len(written) == 4


def test_nifti_of_a_plain_grid_takes_the_mesh_as_lps(tmp_path):
    vol = geovox.voxelize(sphere(), resolution=10)
    out = str(tmp_path / "p.nii.gz")
    geovox.formats.write(vol, out)
    a = nibabel.load(out).affine
    lo = np.asarray(vol.bounds[0]) + 0.5 * np.asarray(vol.spacing)
    np.testing.assert_allclose(a[:3, 3], lo * [-1, -1, 1], atol=1e-5)
    np.testing.assert_allclose(np.diag(a)[:3], np.asarray(vol.spacing) * [-1, -1, 1], rtol=1e-6)
    back = geovox.formats.read(out)
    np.testing.assert_array_equal(back.occupancy, vol.occupancy)


def test_sheared_reference_keeps_occupancy_and_refuses_sdf():
    a = AFFINE.copy()
    a[:3, 2] += 0.4 * a[:3, 0]  # a tilted gantry: k's direction leans towards i
    ref = reference_grid(a, SHAPE)
    assert not ref.orthogonal
    vol = geovox.voxelize(sphere(), like=ref)
    truth = index_space_truth(sphere(), a, SHAPE)
    assert int(np.count_nonzero(vol.occupancy ^ truth.occupancy)) == 0
    with pytest.raises(ParameterError, match="sheared"):
        geovox.voxelize(sphere(), like=ref, sdf=True)
    with pytest.warns(GeovoxWarning, match="sheared"):
        geovox.voxelize(sphere(), like=ref, color=True)


def test_seg_nrrd_layers_are_one_grid_and_time_series_are_refused(tmp_path):
    seg = str(tmp_path / "s.seg.nrrd")
    dirs = np.vstack([np.full(3, np.nan), AFFINE[:3, :3].T])
    nrrd.write(seg, np.zeros((2,) + SHAPE, np.uint8),
               {"space": "left-posterior-superior", "space directions": dirs,
                "space origin": AFFINE[:3, 3], "kinds": ["list", "domain", "domain", "domain"]})
    ref = load_reference(seg)
    assert ref.shape == SHAPE
    np.testing.assert_allclose(ref.affine, AFFINE, atol=1e-12)
    four = str(tmp_path / "t.nii.gz")
    nibabel.save(nibabel.Nifti1Image(np.zeros(SHAPE + (3,), np.int16), RAS_FROM_LPS @ AFFINE), four)
    with pytest.raises(ParameterError, match="4-D image"):
        load_reference(four)


def _one_line_error(argv, capsys, match):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("geovox: error:"), err
    assert match in err, err


def test_bad_references_are_one_line_and_exit_2(refs, tmp_path, capsys):
    stl = os.fspath(_stl(tmp_path))
    out = str(tmp_path / "o.nii.gz")
    (tmp_path / "junk.nii").write_bytes(b"not an image at all" * 30)
    _one_line_error(["convert", stl, "--like", str(tmp_path / "junk.nii"), "-o", out], capsys,
                    "cannot be read as an image")
    _one_line_error(["convert", stl, "--like", stl, "-o", out], capsys, "not a reference image")
    _one_line_error(["convert", stl, "--like", str(tmp_path / "missing.nii"), "-o", out], capsys,
                    "not found")
    singular = str(tmp_path / "sing.nrrd")
    nrrd.write(singular, np.zeros(SHAPE, np.uint8), {"space": "left-posterior-superior",
               "space directions": [[1, 0, 0], [2, 0, 0], [0, 0, 1]], "space origin": [0, 0, 0]})
    _one_line_error(["convert", stl, "--like", singular, "-o", out], capsys, "singular")
    four = str(tmp_path / "four.nii.gz")
    nibabel.save(nibabel.Nifti1Image(np.zeros(SHAPE + (2,), np.int16), np.eye(4)), four)
    _one_line_error(["convert", stl, "--like", four, "-o", out], capsys, "4-D image")
    _one_line_error(["convert", stl, "--like", refs["nrrd"], "-r", "32", "-o", out], capsys,
                    "cannot be combined with --resolution")
    _one_line_error(["convert", stl, "--like", refs["nrrd"], "--bounds", "0", "0", "0", "1", "1",
                     "1", "-o", out], capsys, "--bounds")
    _one_line_error(["convert", stl, "--like", refs["nrrd"], "-o", str(tmp_path / "o.binvox")],
                    capsys, "binvox cannot record")
    _one_line_error(["convert", stl, "--mesh-space", "ras", "-o", out], capsys, "--mesh-space")
    assert not os.path.exists(out)


def test_a_mesh_outside_the_field_of_view_warns_and_is_empty(refs, tmp_path, capsys):
    far = sphere()
    far.apply_translation([500.0, 0, 0])
    path = os.fspath(_stl(tmp_path, b"", "far.stl", far))
    out = str(tmp_path / "far.nii.gz")
    assert main(["convert", path, "--like", refs["nrrd"], "-o", out]) == 0
    err = capsys.readouterr().err
    assert "entirely outside the field of view" in err
    assert not np.asarray(nibabel.load(out).dataobj).any()
    assert main(["info", path, "--like", refs["nrrd"]]) == 0
    assert "entirely outside the image" in capsys.readouterr().out


def test_info_like_says_how_much_lies_in_the_field_of_view(refs, tmp_path, capsys):
    assert main(["info", os.fspath(_stl(tmp_path)), "--like", refs["nii.gz"]]) == 0
    text = capsys.readouterr().out
    assert "the whole mesh lies inside the image" in text
    assert "mesh space LPS (assumed: the file has no SPACE= mark)" in text
    huge = sphere(radius=400.0)  # around the image: its surface nowhere inside
    assert main(["info", os.fspath(_stl(tmp_path, b"", "huge.stl", huge)), "--like",
                 refs["nii.gz"]]) == 0
    assert "the image may lie inside the mesh" in capsys.readouterr().out
    half = sphere(radius=20.0)  # wider than the image in places: partly inside
    assert main(["info", os.fspath(_stl(tmp_path, b"SPACE=RAS", "big.stl", half)), "--like",
                 refs["nii.gz"]]) == 0
    text = capsys.readouterr().out
    assert "part of the mesh lies inside the image" in text and "mesh space RAS" in text


def test_convert_report_names_the_mesh_space(refs, tmp_path, capsys):
    out = str(tmp_path / "r.nrrd")
    assert main(["convert", os.fspath(_stl(tmp_path, b"SPACE=LPS", "l.stl")), "--like",
                 refs["mhd"], "-o", out]) == 0
    text = capsys.readouterr().out
    assert "onto ref.mhd (LPS); mesh space LPS (the file's SPACE=LPS mark)" in text


def test_preview_like_draws_the_mask_over_the_reference(refs, tmp_path):
    from PIL import Image

    png = str(tmp_path / "p.png")
    assert main(["preview", os.fspath(_stl(tmp_path)), "--like", refs["mhd"], "-o", png]) == 0
    img = np.asarray(Image.open(png).convert("RGB")).astype(int)
    # Red mask pixels and grey image pixels are both there.
    red = (img[..., 0] > 200) & (img[..., 1] < 120)
    grey = (np.abs(img[..., 0] - img[..., 1]) < 3) & (img[..., 0] > 60)
    assert red.sum() > 500 and grey.sum() > 500
    # A volume already written onto the reference previews the same way.
    out = str(tmp_path / "v.nii.gz")
    assert main(["convert", os.fspath(_stl(tmp_path)), "--like", refs["mhd"], "-o", out, "-q"]) == 0
    assert main(["preview", out, "--like", refs["mhd"], "-o", str(tmp_path / "q.png")]) == 0


def test_mhd_parser_reads_fields_until_the_data_file():
    fields = parse_mhd("ObjectType = Image\nNDims = 3\nElementDataFile = LOCAL\nbinary = junk\n")
    assert fields == {"ObjectType": "Image", "NDims": "3", "ElementDataFile": "LOCAL"}


def test_a_mirrored_grid_gives_the_mirrored_volume_for_an_open_mesh():
    # det < 0: the move into the local frame reflects the mesh; the winding number's
    # repair re-orients the copy, so inside, coverage, distance and colour just mirror.
    m = sphere(radius=10.0)
    m = trimesh.Trimesh(m.vertices, m.faces[5:], process=False)  # five faces missing
    n = np.array([30, 28, 26])
    a = np.eye(4)
    a[:3, :3] = np.diag([0.9, 1.0, 1.1])
    a[:3, 3] = -a[:3, :3] @ ((n - 1) / 2) + [0.3, 0.2, 0.1]
    b = a.copy()
    b[0, 0] = -a[0, 0]
    b[0, 3] = a[0, 0] * (n[0] - 1) + a[0, 3]  # b's voxel i is a's voxel n - 1 - i
    opts = dict(density="coverage", sdf=True, color=True)
    with pytest.warns(GeovoxWarning):
        va = geovox.voxelize(m, like=(a, tuple(n)), **opts)
    with pytest.warns(GeovoxWarning):
        vb = geovox.voxelize(m, like=(b, tuple(n)), **opts)
    assert va.inside == vb.inside == "winding" and va.inside_count > 3000
    np.testing.assert_array_equal(va.occupancy, vb.occupancy[::-1])
    np.testing.assert_array_equal(va.density, vb.density[::-1])
    np.testing.assert_allclose(va.sdf, vb.sdf[::-1], rtol=0, atol=1e-6)
    np.testing.assert_array_equal(va.colors, vb.colors[::-1])


def test_many_meshes_onto_one_reference(refs, tmp_path):
    small = sphere(radius=5.0)
    small.apply_translation([4.0, 0, 0])
    a = _stl(tmp_path, b"", "a.stl")
    b = _stl(tmp_path, b"SPACE=RAS", "b.stl", small)
    results = geovox.convert_many([str(a), str(b)], str(tmp_path / "out"), fmt="nifti",
                                  like=refs["nrrd"])
    assert [r.status for r in results] == ["ok", "ok"], [r.error for r in results]
    for r, mesh in zip(results, (str(a), str(b))):
        img = nibabel.load(r.outputs[0])
        np.testing.assert_allclose(img.affine, RAS_FROM_LPS @ AFFINE, atol=1e-5)
        np.testing.assert_array_equal(np.asarray(img.dataobj) > 0,
                                      geovox.voxelize(mesh, like=refs["nrrd"]).occupancy)


def test_seg_nrrd_output_is_a_slicer_segmentation_on_the_reference(refs, tmp_path):
    out = str(tmp_path / "liver.seg.nrrd")
    assert main(["convert", os.fspath(_stl(tmp_path)), "--like", refs["nii.gz"], "-o", out, "-q"]) == 0
    data, h = nrrd.read(out)
    assert set(np.unique(data)) == {0, 1}  # label value 1, not 0/255
    assert h["Segment0_LabelValue"] == "1" and h["Segment0_Name"] == "sphere"
    assert h["Segmentation_MasterRepresentation"] == "Binary labelmap"
    nz = np.nonzero(data)
    assert h["Segment0_Extent"] == " ".join(str(int(f(nz[a]))) for a in range(3) for f in (np.min, np.max))
    assert h["space"] == "right-anterior-superior"
    np.testing.assert_allclose(h["space directions"], load_reference(refs["nii.gz"]).affine[:3, :3].T)
    # Read back as a reference (a segmentation of the scan is one too).
    np.testing.assert_allclose(load_reference(out).affine_in("LPS"), AFFINE, atol=1e-5)


def test_zarr_slab_by_slab_onto_a_reference(refs, tmp_path):
    pytest.importorskip("zarr")
    out = str(tmp_path / "z.zarr")
    geovox.convert_to(sphere(), out, like=refs["mhd"], sdf=True)
    back = formats.read(out)
    whole = geovox.voxelize(sphere(), like=refs["mhd"], sdf=True)
    np.testing.assert_array_equal(back.occupancy, whole.occupancy)
    np.testing.assert_array_equal(back.sdf, whole.sdf)
    attrs = json.loads((tmp_path / "z.zarr" / "zarr.json").read_text())["attributes"]["geovox"]
    np.testing.assert_allclose(attrs["affine"], AFFINE, atol=1e-12)
    assert attrs["space"] == "LPS"


def test_paraview_reads_the_vtkhdf_direction(refs, tmp_path):
    # What the README says of ParaView and `Direction`, checked where pvpython exists.
    import shutil
    import subprocess

    pvpython = shutil.which("pvpython")
    if pvpython is None:
        pytest.skip("ParaView's pvpython is not installed (Debian: apt install paraview python3-paraview)")
    vol = geovox.voxelize(sphere(), like=refs["mhd"])
    path = str(tmp_path / "oblique.hdf")  # the name ParaView 5.10+ opens as VTK-HDF
    geovox.formats.write(vol, path, fmt="vtkhdf")
    run = subprocess.run([pvpython, os.path.join(os.path.dirname(__file__), "paraview_direction.py"),
                          path], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.strip().splitlines()[-1])
    np.testing.assert_allclose(np.reshape(got["direction"], (3, 3)), DIRECTION, atol=1e-12)
    np.testing.assert_allclose(got["first"], AFFINE[:3, 3], atol=1e-9)
    np.testing.assert_allclose(got["last"], AFFINE[:3, :3] @ (np.asarray(SHAPE) - 1) + AFFINE[:3, 3],
                               atol=1e-9)
    # The sphere is centred on the world origin; where ParaView draws its contour says
    # whether it applies the direction (5.11 does not: it lands along the world axes).
    centre = np.asarray(got["contour_centre"])
    index_of_centre = np.linalg.solve(AFFINE[:3, :3], -AFFINE[:3, 3])
    unrotated = AFFINE[:3, 3] + SPACING * index_of_centre  # origin + spacing x index, no rotation
    if tuple(got["version"]) <= (5, 11):
        np.testing.assert_allclose(centre, unrotated, atol=0.5)
    else:
        print("ParaView", got["version"], "contour centre", centre.tolist())
