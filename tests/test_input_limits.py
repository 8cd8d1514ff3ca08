"""Limits for files from anywhere (issue 36): compressed inputs are refused in one line
before they inflate past the limit, and MTL colour lines are checked."""

from __future__ import annotations

import gzip
import io
import os
import tarfile
import time
import warnings
import zipfile

import numpy as np
import pytest
import trimesh

import geovox
from geovox.cli import main
from geovox.errors import GeovoxWarning, MeshError
from geovox.io import limits

ZEROS = 80 << 20  # past limits.FLOOR, and a ratio of about 1000:1


def _zeros_zip(path, name="bomb.stl", size=ZEROS):
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        with z.open(name, "w") as f:
            block = bytes(1 << 20)
            for _ in range(size >> 20):
                f.write(block)
    return str(path)


def test_zip_bomb_is_refused_in_one_line_without_inflating(tmp_path, capsys):
    path = _zeros_zip(tmp_path / "bomb.zip")
    assert os.path.getsize(path) < 200_000
    start = time.perf_counter()
    with pytest.raises(MeshError, match=r"bomb\.zip: its 1 member \('bomb\.stl' the largest, "
                                        r"83\.9 MB\) inflated would take 83\.9 MB, more than"):
        geovox.load_mesh(path)
    assert time.perf_counter() - start < 1.0  # read from the zip's directory, not inflated
    assert main(["convert", path, "-o", str(tmp_path / "v.raw")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--max-input-size" in err
    assert not os.path.exists(tmp_path / "v.raw")


def test_a_ply_header_claiming_two_billion_vertices_is_one_line(tmp_path, capsys):
    # a count the bytes do not hold is refused before anything is allocated (issue 41
    # moved instanced copies off the file-size rule; claimed counts stay on it)
    path = tmp_path / "claims.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\n"
                     b"property float x\nproperty float y\nproperty float z\nelement face 1\n"
                     b"property list uchar int vertex_indices\nend_header\n" + bytes(64))
    start = time.perf_counter()
    with pytest.raises(MeshError, match=r"claims\.ply: the PLY header announces 2,000,000,000 "
                                        r"vertex, 1 face, but .* cut short"):
        geovox.load_mesh(str(path))
    assert time.perf_counter() - start < 1.0
    assert main(["convert", str(path), "-o", str(tmp_path / "v.raw")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err


def test_zipped_formats_are_checked_too(tmp_path):
    # a 3MF is a zip: the same limit, before its reader opens it
    path = _zeros_zip(tmp_path / "bomb.3mf", name="3D/3dmodel.model")
    with pytest.raises(MeshError, match=r"bomb\.3mf: .*inflated would take"):
        geovox.load_mesh(path)


def test_gzip_bomb_is_refused_while_inflating(tmp_path):
    path = tmp_path / "bomb.tar.gz"
    with tarfile.open(path, "w:gz") as t:
        info = tarfile.TarInfo("bomb.stl")
        info.size = ZEROS
        t.addfile(info, io.BytesIO(bytes(ZEROS)))
    with pytest.raises(MeshError, match=r"bomb\.tar\.gz: inflates past .* not read"):
        geovox.load_mesh(str(path))


def test_real_archives_still_load_and_max_input_size_sets_the_limit(tmp_path):
    box = trimesh.creation.box(extents=(2.0, 1.0, 1.0))
    path = tmp_path / "box.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("box.stl", box.export(file_type="stl"))
    assert len(geovox.load_mesh(str(path)).faces) == 12
    with pytest.raises(MeshError, match=r"more than 100 bytes \(max_input_size"):
        geovox.load_mesh(str(path), max_input_size=100)
    gz = tmp_path / "box.stl.gz"
    gz.write_bytes(gzip.compress(box.export(file_type="stl")))
    geovox.io.archive.check_archive(str(gz))  # within the limit: nothing said
    with pytest.raises(MeshError, match="inflates past 100 bytes"):
        geovox.io.archive.check_archive(str(gz), limits.Limit(100))


def test_max_input_size_refuses_a_plain_file_too(tmp_path):
    path = tmp_path / "box.stl"
    trimesh.creation.box().export(path)
    with pytest.raises(MeshError, match=r"box\.stl: the file would take 684 bytes, more than "
                                        r"100 bytes"):
        geovox.load_mesh(str(path), max_input_size=100)
    with pytest.raises(geovox.errors.ParameterError, match="max_input_size"):
        geovox.load_mesh(str(path), max_input_size=-1)


def test_parse_size():
    assert limits.parse_size("500M") == 500_000_000
    assert limits.parse_size("2GiB") == 2 << 30
    assert limits.parse_size("1234") == 1234
    for bad in ("", "-1", "0", "ten", "5X"):
        with pytest.raises(ValueError):
            limits.parse_size(bad)


def test_default_limit():
    assert limits.input_limit(1000) >= limits.FLOOR or limits.available_memory() < 2 ** 28
    assert limits.input_limit(10**6, most=5) == 5 == limits.Limit(5).of(10**6)
    memory = limits.available_memory()
    if memory:
        assert limits.input_limit(10**12) == int(limits.MEMORY_SHARE * memory)


def test_the_command_line_option_reaches_the_reader(tmp_path, capsys):
    path = tmp_path / "box.stl"
    trimesh.creation.box().export(path)
    assert main(["convert", str(path), "-o", str(tmp_path / "v.raw"), "-r", "4",
                 "--max-input-size", "100"]) == 2
    assert "max_input_size" in capsys.readouterr().err


def test_the_command_line_option_is_parsed(capsys):
    assert main(["convert", "x.stl", "--max-input-size", "lots"]) == 2
    assert "--max-input-size" in capsys.readouterr().err


# ----------------------------------------------------------------------------- MTL colours


@pytest.mark.parametrize("line,said", [
    ("Kd 0 1", "a colour is one number (grey) or three"),
    ("Kd nan 0 0", "three finite numbers"),
    ("Kd spectral red.rfl", "a colour is one number (grey) or three"),
])
def test_mtl_colour_lines_other_than_one_or_three_numbers(tmp_path, line, said):
    (tmp_path / "m.mtl").write_text(f"newmtl red\n{line}\nKa 0.1\n")
    box = trimesh.creation.box()
    obj = "mtllib m.mtl\nusemtl red\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in box.vertices)
    obj += "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in box.faces)
    (tmp_path / "box.obj").write_text(obj)
    mesh = geovox.load_mesh(str(tmp_path / "box.obj"))
    (material,) = mesh.materials
    assert material.kd is None and np.allclose(material.ka, 0.1)
    assert any(f"m.mtl, line 2: Kd of material 'red' ({line!r})" in p and said in p
               for p in mesh.problems), mesh.problems
    with pytest.warns(GeovoxWarning, match="line 2"):
        vol = geovox.voxelize(str(tmp_path / "box.obj"), resolution=4, color=True)
    assert np.all(vol.colors[..., :3][vol.occupancy] == 204)  # the default grey


def test_mtl_colour_with_extra_numbers_uses_three(tmp_path):
    from geovox.io.mtl import read_mtl

    (tmp_path / "m.mtl").write_text("newmtl a\nKd 1 0 0 1\nnewmtl b\nKd 0.5\n")
    problems = []
    got = read_mtl(str(tmp_path / "m.mtl"), problems)
    assert got["a"].kd.tolist() == [1, 0, 0] and got["b"].kd.tolist() == [0.5] * 3
    assert len(problems) == 1 and "numbers after the third are not used" in problems[0]
