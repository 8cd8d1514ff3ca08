"""3MF extensions trimesh does not read whole (geovox.threemf).

Real files: assimp's test models (tests/data/assimp; BSD-3-Clause, and the
3MF Consortium's BSD-2-Clause sample cube_gears_prod_req.3mf) and the 3MF
Consortium's samples (tests/data/3mf-samples, BSD-2-Clause); licences in
tests/data/LICENSES.
"""

from __future__ import annotations

import io
import zipfile

import numpy as np
import pytest

import geovox
from geovox.cli import main
from geovox.errors import MeshError

from conftest import corpus


def _one_line_error(argv, capsys, *needles):
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1 and err.startswith("geovox: error:"), err
    for needle in needles:
        assert needle in err, err
    return err


def test_production_build_items_across_parts():
    # 17 build items, each naming object 1 of its own part through p:path.
    # lib3mf 2.5.0 (the 3MF Consortium's reader), on this file: 17 items,
    # 25,692 triangles, bounds (37.61457, 35.61846, 16.92) .. (205.61038,
    # 160.72038, 50.5213) after the items' transforms.
    mesh = geovox.load_mesh(corpus("assimp", "cube_gears_prod_req.3mf"))
    assert len(mesh.faces) == 25_692
    assert np.allclose(mesh.bounds, [[37.61457, 35.61846, 16.92], [205.61038, 160.72038, 50.5213]],
                       atol=1e-4)
    assert not mesh.problems


def test_production_components_keep_each_parts_own_object_1():
    # Two components name object 1 of two different parts (a tetrahedron
    # each, the second moved 20 along x). trimesh alone merged both parts'
    # meshes into one object and placed it twice (16 triangles).
    mesh = geovox.load_mesh(corpus("assimp", "production_components.3mf"))
    assert len(mesh.faces) == 8
    lo, hi = mesh.bounds
    assert lo.tolist() == [0, 0, 0] and hi[0] == 25


def test_production_file_voxelises_like_its_single_part_self(tmp_path):
    # The same gears with every object in the root part: the same volume,
    # voxel for voxel, over the same region.
    src = zipfile.ZipFile(corpus("assimp", "production_components.3mf"))
    root = src.read("3D/3dmodel.model").decode()
    parts = [src.read(f"3D/Objects/part{x}.model").decode() for x in "AB"]
    meshes = [p[p.index("<mesh>"):p.index("</mesh>") + len("</mesh>")] for p in parts]
    single = root.replace(' p:path="/3D/Objects/partA.model" objectid="1"', ' objectid="3"') \
        .replace(' p:path="/3D/Objects/partB.model" objectid="1"', ' objectid="4"') \
        .replace("<resources>", f'<resources><object id="3" type="model">{meshes[0]}</object>'
                                f'<object id="4" type="model">{meshes[1]}</object>')
    path = tmp_path / "single.3mf"
    with zipfile.ZipFile(path, "w") as z:
        for info in src.infolist():
            if info.filename == "3D/3dmodel.model":
                z.writestr(info.filename, single)
            elif not info.filename.startswith("3D/Objects/"):
                z.writestr(info, src.read(info))
    bounds = [-1, -1, -1, 26, 11, 11]
    a = geovox.voxelize(corpus("assimp", "production_components.3mf"), resolution=24,
                        bounds=bounds, backend="numpy")
    b = geovox.voxelize(str(path), resolution=24, bounds=bounds, backend="numpy")
    assert a.inside_count > 0 and np.array_equal(a.occupancy, b.occupancy)


def test_production_reference_to_a_missing_part(tmp_path, capsys):
    src = zipfile.ZipFile(corpus("assimp", "production_components.3mf"))
    path = tmp_path / "broken.3mf"
    with zipfile.ZipFile(path, "w") as z:
        for info in src.infolist():
            if info.filename != "3D/Objects/partB.model":
                z.writestr(info, src.read(info))
    _one_line_error(["info", str(path)], capsys, "broken.3mf",
                    "refers to the model part '/3D/Objects/partB.model', which the 3MF archive "
                    "does not contain")


def test_beam_lattice_says_it_is_not_triangles(capsys):
    _one_line_error(["info", corpus("3mf-samples", "pyramid.3mf")], capsys,
                    "pyramid.3mf: object 'Pyramid Lattice' holds 391 beams (3MF Beam Lattice "
                    "extension)", "geovox voxelises triangle surfaces only")


def test_sliced_object_with_a_full_mesh_reads_its_mesh():
    mesh = geovox.load_mesh(corpus("3mf-samples", "box_sliced.3mf"))
    assert len(mesh.faces) == 12
    vol = geovox.voxelize(mesh, resolution=8, backend="numpy")
    assert vol.inside == "parity" and vol.inside_count == 8 ** 3


def _edited(tmp_path, name, edit):
    src = zipfile.ZipFile(corpus("3mf-samples", "box_sliced.3mf"))
    path = tmp_path / name
    with zipfile.ZipFile(path, "w") as z:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "3D/3dmodel.model":
                data = edit(data.decode()).encode()
            z.writestr(info, data)
    return str(path)


def test_slices_only_object_is_refused_in_one_line(tmp_path, capsys):
    def no_triangles(text):
        return text[:text.index("<triangles>")] + text[text.index("</triangles>") + 12:]

    path = _edited(tmp_path, "slices_only.3mf", no_triangles)
    _one_line_error(["info", path], capsys, "slices_only.3mf: object 'box' is given only as "
                    "slices (3MF Slice extension)", "does not read slices")


def test_low_resolution_mesh_beside_slices_is_refused(tmp_path):
    path = _edited(tmp_path, "lowres.3mf", lambda t: t.replace(
        's:slicestackid="1"', 's:slicestackid="1" s:meshresolution="lowres"'))
    with pytest.raises(MeshError, match=r"lowres\.3mf: object 'box' has slices .* low-resolution"):
        geovox.load_mesh(path)


def test_plain_3mf_is_left_to_trimesh(monkeypatch):
    # A file without any of the extensions is not rewritten.
    from geovox.io import threemf

    assert threemf.flatten(corpus("wild", "pyramids.3mf")) is None
    data = threemf.flatten(corpus("assimp", "production_components.3mf"))
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        assert "3D/Objects/partA.model" not in z.namelist()
        root = z.read("3D/3dmodel.model")
    assert b"path=" not in root
