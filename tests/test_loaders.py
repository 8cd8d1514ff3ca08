"""Every format (geovox's own readers for GLB/glTF, STL and PLY; trimesh for 3MF, OFF,
COLLADA, archives): each either converts or fails with one line naming the file and the
problem, and nothing loses geometry silently. Regressions from benchmarks/bench_wild.py
(trimesh's own models/ folder); most files are made here, a few small ones are
copied in tests/data/wild (trimesh's, MIT)."""

from __future__ import annotations

import logging
import os
import sys
import zipfile

import numpy as np
import pytest
import trimesh

import geovox
from geovox.cli import main
from geovox.errors import GeovoxWarning, InputNotFoundError, MeshError

from conftest import corpus

SOLID = 16  # grid for the solids below; small, every count checked exactly


def _box():
    # A grid fitted to a box has every voxel centre inside it.
    return trimesh.creation.box(extents=(2.0, 1.0, 1.0))


def _sphere():
    return trimesh.creation.icosphere(subdivisions=2)


def _one_line_error(argv, capsys, *needles):
    """Run the CLI; it must exit 2 with exactly one `geovox: error:` line holding the needles."""
    status = main(argv)
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1 and err.startswith("geovox: error:"), err
    for needle in needles:
        assert needle in err, err
    return err


@pytest.mark.parametrize("ext", ["glb", "stl", "ply", "off", "3mf", "dae"])
def test_formats_through_trimesh_give_the_same_volume(ext, tmp_path):
    # The same sphere written in each format voxelises to the same volume as
    # the mesh itself (float32 formats round the vertices: compared within a
    # few surface voxels).
    if ext == "dae":
        pytest.importorskip("collada")
    sphere = _sphere()
    path = tmp_path / f"sphere.{ext}"
    sphere.export(path)
    want = geovox.voxelize(sphere, resolution=SOLID, backend="numpy")
    got = geovox.voxelize(str(path), resolution=SOLID, backend="numpy")
    assert got.inside == "parity"  # read back closed
    assert abs(got.inside_count - want.inside_count) <= 8
    assert np.count_nonzero(got.occupancy != want.occupancy) <= 8


def test_real_3mf_with_several_objects_loads():
    # pyramids.3mf (trimesh's): 12 closed objects placed by the build, 3,276 triangles.
    mesh = geovox.load_mesh(corpus("wild", "pyramids.3mf"))
    assert len(mesh.faces) == 3276
    vol = geovox.voxelize(mesh, resolution=SOLID, backend="numpy")
    assert vol.inside == "parity" and vol.inside_count > 0


def test_3mf_without_its_modules_says_what_to_install(tmp_path, capsys, monkeypatch):
    # What trimesh does when networkx or lxml is missing: its 3MF loader is a
    # wrapper that raises the stored ImportError.
    from trimesh.exceptions import ExceptionWrapper
    from trimesh.exchange import load

    path = tmp_path / "box.3mf"
    _box().export(path)
    monkeypatch.setitem(load.mesh_loaders, "3mf",
                        ExceptionWrapper(ModuleNotFoundError("No module named 'networkx'")))
    _one_line_error(["convert", str(path), "-o", str(tmp_path / "v.raw")], capsys,
                    "box.3mf", "3MF", "pip install networkx")
    assert sorted(os.listdir(tmp_path)) == ["box.3mf"]


def _draco_glb(path):
    pytest.importorskip("DracoPy")
    data = trimesh.exchange.gltf.export_glb(trimesh.Scene(_sphere()), extension_draco=True)
    assert b"KHR_draco_mesh_compression" in data
    path.write_bytes(data)
    return path


def test_draco_compressed_gltf_decodes(tmp_path):
    path = _draco_glb(tmp_path / "draco.glb")
    mesh = geovox.load_mesh(str(path))
    assert len(mesh.faces) == len(_sphere().faces)
    # Draco quantises positions to 14 bits: the same shape within 1e-3.
    assert np.abs(mesh.bounds - _sphere().bounds).max() < 1e-3
    vol = geovox.voxelize(mesh, resolution=SOLID, backend="numpy")
    want = geovox.voxelize(_sphere(), resolution=SOLID, backend="numpy")
    assert np.count_nonzero(vol.occupancy != want.occupancy) <= 8


def test_draco_that_does_not_decode_is_an_error_not_an_empty_volume(tmp_path, capsys,
                                                                      monkeypatch):
    # Without DracoPy, trimesh logged a warning and returned placeholder zeros;
    # voxelising those once gave exit 0 and an empty volume. geovox's reader says
    # what to install.
    path = _draco_glb(tmp_path / "draco.glb")
    monkeypatch.setitem(sys.modules, "DracoPy", None)  # import DracoPy now fails
    with pytest.raises(MeshError, match="Draco-compressed.*not installed"):
        geovox.load_mesh(str(path))
    _one_line_error(["convert", str(path), "-o", str(tmp_path / "v.raw")], capsys,
                    "draco.glb", "KHR_draco_mesh_compression", "pip install DracoPy")
    assert sorted(os.listdir(tmp_path)) == ["draco.glb"]


def test_any_lost_geometry_message_from_trimesh_is_an_error(tmp_path, monkeypatch):
    # The rule, not just Draco: a reader that logs that it dropped geometry
    # and carries on gives an error naming the file and trimesh's words.
    path = tmp_path / "box.off"  # OFF: read through trimesh (PLY is geovox's own)
    path.write_bytes(_box().export(file_type="off").encode())
    from trimesh.exchange import load

    real = load.mesh_loaders["off"]

    def dropping(*args, **kwargs):
        logging.getLogger("trimesh.exchange.ply").warning("PLY failed to populate: face")
        return real(*args, **kwargs)

    monkeypatch.setitem(load.mesh_loaders, "off", dropping)
    with pytest.raises(MeshError, match=r"box\.off: part of the geometry could not be read.*"
                                        r"PLY failed to populate: face"):
        geovox.load_mesh(str(path))


def test_other_trimesh_log_messages_do_not_reach_stderr(tmp_path, capsys):
    # cube_invalid_shininess.dae (trimesh's): its reader logs "Invalid shininess
    # value", which Python printed on stderr beside geovox's own lines.
    pytest.importorskip("collada")
    src = corpus("wild", "cube_invalid_shininess.dae")
    assert main(["convert", src, "-o", str(tmp_path / "v.raw"), "-r", "8", "-q"]) == 0
    assert capsys.readouterr().err == ""
    mesh = geovox.load_mesh(src)
    assert any("shininess" in p for p in mesh.problems)  # said as a warning with --color


def test_missing_gltf_buffer_names_the_file(tmp_path, capsys):
    files = trimesh.Scene(_box()).export(file_type="gltf")
    for name, data in files.items():
        if name.endswith(".gltf"):
            (tmp_path / name).write_bytes(data)
    missing = sorted(n for n in files if n.endswith(".bin"))[0]
    path = tmp_path / "model.gltf"
    _one_line_error(["convert", str(path), "-o", str(tmp_path / "v.raw")], capsys,
                    "model.gltf", "refers to a file that is missing", missing)


@pytest.mark.parametrize("name,data,needle", [
    ("bad.glb", b"glTF" + bytes(range(40)), "cannot be read as glTF binary (.glb)"),
    ("bad.3mf", b"PK\x03\x04 not really a zip", "cannot be read as 3MF (.3mf)"),
    ("buffer.bin", b"\x00" * 48, "glTF buffer"),
    ("model.mtl", b"newmtl a\nKd 1 0 0\n", "material library"),
    ("notes.txt", b"hello\n", "does not read .txt files"),
])
def test_unreadable_files_give_one_line_in_words(name, data, needle, tmp_path, capsys):
    path = tmp_path / name
    path.write_bytes(data)
    err = _one_line_error(["convert", str(path), "-o", str(tmp_path / "v.raw")], capsys,
                          name, needle)
    # Words first: the exception's own text never stands alone in brackets.
    assert not err.rstrip().endswith(("(AssertionError)", "(KeyError)", ".bin)"))


def test_point_clouds_and_lines_say_there_are_no_faces(tmp_path, capsys):
    points = trimesh.PointCloud(np.random.default_rng(0).random((10, 3)))
    (tmp_path / "points.ply").write_bytes(points.export(file_type="ply"))
    (tmp_path / "points.xyz").write_text(points.export(file_type="xyz"))
    lines = trimesh.load_path(np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 1]]))
    (tmp_path / "lines.glb").write_bytes(trimesh.Scene(lines).export(file_type="glb"))
    for name, held in [("points.ply", "a point cloud (10 points)"),
                       ("points.xyz", "a point cloud (10 points)"),
                       ("lines.glb", "lines (")]:
        _one_line_error(["info", str(tmp_path / name)], capsys, name, "has no faces", held)


def test_empty_scene_says_so(capsys):
    # empty_nodes.glb (trimesh's): nodes and no meshes.
    _one_line_error(["info", corpus("wild", "empty_nodes.glb")], capsys,
                    "empty_nodes.glb", "contains no geometry")


def test_scene_with_points_beside_a_mesh_converts_the_mesh(tmp_path):
    scene = trimesh.Scene([_box(), trimesh.PointCloud(np.full((5, 3), 9.0))])
    path = tmp_path / "mixed.glb"
    path.write_bytes(scene.export(file_type="glb"))
    mesh = geovox.load_mesh(str(path))
    assert len(mesh.faces) == 12
    assert mesh.bounds[1, 0] == pytest.approx(1.0)  # the stray points are not in the box


def test_archives_load(tmp_path):
    path = tmp_path / "box.zip"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("box.stl", _box().export(file_type="stl"))
    vol = geovox.voxelize(str(path), resolution=SOLID, backend="numpy")
    assert vol.inside_count == SOLID**3


# ----------------------------------------------------------------------------- empty volumes


def test_flat_gltf_warns_that_the_volume_is_empty(tmp_path, capsys):
    # Mesh_PrimitiveMode_04.gltf (trimesh's): two triangles in a plane. It
    # converted to an empty volume with exit 0 and no word about it.
    out = tmp_path / "v.raw"
    assert main(["convert", corpus("wild", "Mesh_PrimitiveMode_04.gltf"), "-o", str(out),
                 "-r", "8"]) == 0
    captured = capsys.readouterr()
    assert "inside 0 of" in captured.out
    assert "the volume is empty: the mesh is flat (no thickness along z)" in captured.err


@pytest.mark.parametrize("name,faces,needle", [
    ("single triangle", [[0, 1, 2]], "flat"),
    # A tilted triangle: not flat along any axis, and one planar piece never
    # reaches a winding number above 1/2 (a bent sheet can, once the repair
    # turns it outward: its concave side then counts as enclosed).
    ("tilted triangle", [[0, 1, 3]], "open surface (3 open edges)"),
])
def test_empty_results_always_say_why(name, faces, needle):
    v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 1]])
    mesh = geovox.Mesh(v, np.array(faces), source=name)
    with pytest.warns(GeovoxWarning) as record:
        vol = geovox.voxelize(mesh, resolution=8, backend="numpy")
    assert vol.inside_count == 0
    said = [str(w.message) for w in record if "volume is empty" in str(w.message)]
    assert len(said) == 1 and name in said[0] and needle in said[0], said


def test_empty_result_of_a_closed_mesh_says_why():
    # Every face doubled and reversed: closed, and parity sees each crossing twice.
    box = _box()
    doubled = geovox.Mesh(box.vertices, np.vstack([box.faces, box.faces[:, ::-1]]),
                          source="doubled")
    with pytest.warns(GeovoxWarning) as record:
        vol = geovox.voxelize(doubled, resolution=8, backend="numpy", inside="parity")
    assert vol.inside_count == 0
    assert any("volume is empty" in str(w.message) and "12 of its 24 faces repeat another face"
               in str(w.message) for w in record)


def test_streamed_empty_volume_warns_too(tmp_path):
    v = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0]])
    mesh = geovox.Mesh(v, np.array([[0, 1, 2]]), source="tri")
    with pytest.warns(GeovoxWarning) as record:
        info = geovox.convert_to(mesh, str(tmp_path / "t.raw"), shape=(4, 4, 130),
                                 budget=4 * 4 * 64)
    assert info["slabs"] > 1 and info["inside"] == 0
    assert sum("volume is empty: the mesh is flat" in str(w.message) for w in record) == 1


# ----------------------------------------------------------------------------- folders


def test_folder_without_meshes_says_so(tmp_path, capsys):
    (tmp_path / "readme.txt").write_text("no models here\n")
    (tmp_path / "sub").mkdir()
    err = _one_line_error(["convert", str(tmp_path), "-o", str(tmp_path / "out.raw")], capsys,
                          f"no meshes found in {tmp_path}", ".obj", ".stl", ".3mf")
    assert "-o must be a folder" not in err
    from geovox.batch import find_inputs

    with pytest.raises(InputNotFoundError, match="no meshes found"):
        find_inputs([str(tmp_path)])


def test_folders_are_searched_for_3mf_and_collada(tmp_path):
    from geovox.batch import find_inputs

    for name in ("a.3MF", "b.dae", "c.zae", "d.glb", "notes.txt", "e.zip"):
        (tmp_path / name).write_bytes(b"x")
    found = [os.path.basename(p) for p in find_inputs([str(tmp_path)])]
    assert found == ["a.3MF", "b.dae", "c.zae", "d.glb"]


def test_empty_reason_names_faces_wound_against_each_other():
    # multibody.stl (trimesh's) is closed with faces wound against their
    # neighbours; the winding number then cancels. The reason, asked directly
    # (whether a repair later fills such a mesh is the inside test's business).
    from geovox.grid import make_grid
    from geovox.block import empty_reason

    box = _box()
    faces = box.faces.copy()
    faces[::2] = faces[::2, ::-1]
    mesh = geovox.Mesh(box.vertices, faces, source="flipped")
    grid = make_grid(mesh.bounds, resolution=8)
    why = empty_reason(mesh, grid, "winding")
    assert why.startswith("flipped: the volume is empty") and "wound against each other" in why
    assert "edges run the same way" in why


def test_gltf_triangle_fan_trimesh_skips_is_read_by_geovox(tmp_path):
    # trimesh skips glTF primitives in TRIANGLE_FAN mode (6) with a debug
    # message only; geovox triangulates them itself (tests/test_gltf_modes.py).
    from geovox.io.gltf import fan_faces

    box = _box()
    data = trimesh.Scene(box).export(file_type="glb")
    assert data.count(b'"mode":4') == 1
    path = tmp_path / "fan.glb"
    path.write_bytes(data.replace(b'"mode":4', b'"mode":6'))
    mesh = geovox.load_mesh(str(path))
    assert np.array_equal(mesh.faces, fan_faces(box.faces.reshape(-1)))


def test_broken_file_inside_a_zip_is_an_error_not_a_partial_volume(tmp_path):
    path = tmp_path / "two.zip"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("good.stl", _box().export(file_type="stl"))
        z.writestr("bad.glb", b"glTF" + bytes(range(40)))
    with pytest.raises(MeshError, match=r"two\.zip: part of the geometry could not be read.*"
                                        r"failed to load file in zip"):
        geovox.load_mesh(str(path))
    # The logger is left as it was.
    assert logging.getLogger("trimesh").propagate and \
        logging.getLogger("trimesh").level == logging.NOTSET


def test_trimesh_point_cloud_object_says_it_has_no_faces():
    cloud = trimesh.PointCloud(np.zeros((3, 3)))
    with pytest.raises(MeshError, match=r"has no faces, only a point cloud \(3 points\)"):
        geovox.voxelize(cloud, resolution=4)


def test_bare_exception_from_a_reader_is_put_in_words(tmp_path, capsys, monkeypatch):
    # A reader that fails with a bare `assert` once gave "(AssertionError)".
    from trimesh.exchange import load

    path = tmp_path / "box.3mf"  # a format read through trimesh
    path.write_bytes(_box().export(file_type="3mf"))

    def broken(*args, **kwargs):
        raise AssertionError()

    monkeypatch.setitem(load.mesh_loaders, "3mf", broken)
    err = _one_line_error(["info", str(path)], capsys, "box.3mf",
                          "cannot be read as 3MF (.3mf); the file is damaged or not what "
                          "its extension says", "AssertionError")
    assert not err.rstrip().endswith("(AssertionError)")
