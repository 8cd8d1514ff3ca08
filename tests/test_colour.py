"""Colour: hand-computed models, a brute-force reference, materials, textures."""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest
import trimesh
from PIL import Image

import geovox
from geovox.errors import GeovoxWarning

from conftest import SPOT, corpus

QUADRANTS = {  # texture quadrant (u, v centre) -> colour
    (0.25, 0.75): (255, 0, 0),
    (0.75, 0.75): (0, 255, 0),
    (0.25, 0.25): (0, 0, 255),
    (0.75, 0.25): (255, 255, 0),
}


def write_quadrant_texture(path, size=64, fmt=None):
    """Four flat colour areas; V points up in OBJ, so (u, v) = (0.25, 0.75) is top-left."""
    img = np.zeros((size, size, 3), np.uint8)
    h = size // 2
    img[:h, :h] = QUADRANTS[(0.25, 0.75)]
    img[:h, h:] = QUADRANTS[(0.75, 0.75)]
    img[h:, :h] = QUADRANTS[(0.25, 0.25)]
    img[h:, h:] = QUADRANTS[(0.75, 0.25)]
    Image.fromarray(img).save(path, format=fmt)


def write_tetrahedron(folder, texture_ref="quad.png", mtl="tet.mtl", kd=None):
    """A tetrahedron whose four faces each map into one texture quadrant."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]) * 2.0
    faces = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]
    lines = [f"mtllib {mtl}"] + [f"v {x} {y} {z}" for x, y, z in v]
    for (cu, cv) in QUADRANTS:
        # three UVs close around the quadrant centre, far from its edges
        for du, dv in ((-0.1, -0.1), (0.1, -0.1), (0.0, 0.1)):
            lines.append(f"vt {cu + du} {cv + dv}")
    lines.append("usemtl tex")
    for n, f in enumerate(faces):
        t = [3 * n + 1, 3 * n + 2, 3 * n + 3]
        lines.append("f " + " ".join(f"{a + 1}/{b}" for a, b in zip(f, t)))
    (folder / "tet.obj").write_text("\n".join(lines) + "\n")
    kd_line = f"Kd {kd[0]} {kd[1]} {kd[2]}\n" if kd is not None else ""
    (folder / mtl).write_text(f"newmtl tex\n{kd_line}Ka 0.1 0.2 0.3\nmap_Kd {texture_ref}\n")
    return folder / "tet.obj", v, faces


def nearest_face(points, v, faces):
    """Index of the nearest face per point, and the gap to the second nearest."""
    tris = v[np.array(faces)]
    d = np.stack([np.linalg.norm(trimesh.triangles.closest_point(np.repeat(tris[k:k + 1], len(points), 0),
                                                                points) - points, axis=1)
                  for k in range(len(faces))], axis=1)
    order = np.sort(d, axis=1)
    return d.argmin(axis=1), order[:, 1] - order[:, 0]


def centres_of(vol, idx):
    return np.stack([vol.grid.centres(a)[idx[:, a]] for a in range(3)], axis=1)


def test_textured_tetrahedron_faces_get_their_quadrant(tmp_path, backend):
    obj, v, faces = write_tetrahedron(tmp_path)
    write_quadrant_texture(tmp_path / "quad.png")
    vol = geovox.voxelize(obj, resolution=24, color="fast", backend=backend)
    idx = np.argwhere(vol.occupancy)
    face, gap = nearest_face(centres_of(vol, idx), v, faces)
    quad_colour = np.array(list(QUADRANTS.values()))
    got = vol.colors[tuple(idx.T)]
    assert np.all(got[:, 3] == 255)
    # Every inside voxel clearly nearer one face has exactly that face's colour.
    clear = gap > 0.5 * vol.spacing[0]
    assert clear.sum() > 0.5 * len(idx)
    np.testing.assert_array_equal(got[clear, :3], quad_colour[face[clear]])
    # and every voxel has one of the four colours (flat areas, no blending)
    assert {tuple(c) for c in got[:, :3]} <= {tuple(c) for c in quad_colour}


def test_outside_voxels_have_alpha_zero(backend):
    vol = geovox.voxelize(SPOT, resolution=20, color="fast", backend=backend)
    assert vol.colors.shape == (20, 20, 20, 4) and vol.colors.dtype == np.uint8
    np.testing.assert_array_equal(vol.colors[..., 3], np.where(vol.occupancy, 255, 0))
    assert np.all(vol.colors[~vol.occupancy] == 0)


def test_colors_are_none_without_color():
    assert geovox.voxelize(SPOT, resolution=8).colors is None


def test_kd_multiplies_texture_and_ambient_adds(tmp_path):
    obj, v, faces = write_tetrahedron(tmp_path, kd=(0.5, 1.0, 1.0))
    write_quadrant_texture(tmp_path / "quad.png")
    plain = geovox.voxelize(obj, resolution=16, color=True, diffuse=False)
    kd = geovox.voxelize(obj, resolution=16, color=True)
    amb = geovox.voxelize(obj, resolution=16, color=True, diffuse=False, ambient=True)
    inside = plain.occupancy
    p, k, a = (x.colors[inside, :3].astype(int) for x in (plain, kd, amb))
    np.testing.assert_array_equal(k[:, 0], np.rint(p[:, 0] * 0.5))
    np.testing.assert_array_equal(k[:, 1:], p[:, 1:])
    expected = np.minimum(255, np.rint(p + np.array([0.1, 0.2, 0.3]) * 255))
    assert np.abs(a - expected).max() <= 1


def write_two_material_cube(folder):
    """A cube [0, 2]^3: its top face (z = 2) is red, the rest blue, each face its own material."""
    mesh = trimesh.creation.box(extents=(2, 2, 2))
    mesh.apply_translation((1, 1, 1))
    top = mesh.triangles_center[:, 2] > 1.999
    lines = ["mtllib two.mtl"] + [f"v {x} {y} {z}" for x, y, z in mesh.vertices]
    for name, sel in (("red", top), ("blue", ~top)):
        lines.append(f"usemtl {name}")
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces[sel]]
    (folder / "two.obj").write_text("\n".join(lines) + "\n")
    (folder / "two.mtl").write_text("newmtl red\nKd 1 0 0\nKa 0 0.5 0\n\nnewmtl blue\nKd 0 0 1\n")
    return folder / "two.obj"


def test_two_material_cube(tmp_path, backend):
    obj = write_two_material_cube(tmp_path)
    vol = geovox.voxelize(obj, resolution=10, color="fast", backend=backend)
    assert vol.inside_count == 1000
    c = vol.colors
    # The top layer is nearest the red face; the middle of the bottom layer
    # is nearest the bottom (blue) face.
    assert np.all(c[2:8, 2:8, 9, :3] == (255, 0, 0))
    assert np.all(c[:, :, 0, :3] == (0, 0, 255))
    assert np.all(c[0, 3:7, 3:6, :3] == (0, 0, 255))
    amb = geovox.voxelize(obj, resolution=10, color="fast", ambient=True, backend=backend)
    assert np.all(amb.colors[2:8, 2:8, 9, :3] == (255, 128, 0))


def test_vertex_colours_and_no_material(tmp_path):
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    f = "f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    coloured = "".join(f"v {x} {y} {z} 0.2 0.4 0.6\n" for x, y, z in v)
    (tmp_path / "vc.obj").write_text(coloured + f)
    vol = geovox.voxelize(tmp_path / "vc.obj", resolution=12, color=True)
    assert np.all(vol.colors[vol.occupancy, :3] == (51, 102, 153))
    plain = "".join(f"v {x} {y} {z}\n" for x, y, z in v)
    (tmp_path / "plain.obj").write_text(plain + f)
    vol = geovox.voxelize(tmp_path / "plain.obj", resolution=12, color=True)
    assert np.all(vol.colors[vol.occupancy, :3] == (204, 204, 204))


@pytest.mark.parametrize("fmt,ext", [("BMP", "bmp"), ("JPEG", "jpg"), ("PNG", "png")])
def test_texture_formats_and_windows_paths(tmp_path, fmt, ext):
    (tmp_path / "maps").mkdir()
    write_quadrant_texture(tmp_path / "maps" / f"Quad Tex.{ext}", fmt=fmt)
    obj, v, faces = write_tetrahedron(tmp_path, texture_ref=f"-s 1 1 1 maps\\Quad Tex.{ext}")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        vol = geovox.voxelize(obj, resolution=16, color=True)
    got = vol.colors[vol.occupancy, :3].astype(int)
    # JPEG blurs the quadrant edges a little; the colours stay near the four.
    quad = np.array(list(QUADRANTS.values()))
    nearest = np.abs(got[:, None, :] - quad[None]).sum(axis=2).min(axis=1)
    assert np.median(nearest) <= (6 if fmt == "JPEG" else 0)


def test_missing_texture_warns_and_uses_kd(tmp_path):
    obj, v, faces = write_tetrahedron(tmp_path, texture_ref="gone.png", kd=(0.2, 0.4, 0.6))
    with pytest.warns(GeovoxWarning, match="gone.png"):
        vol = geovox.voxelize(obj, resolution=12, color=True)
    assert np.all(vol.colors[vol.occupancy, :3] == (51, 102, 153))


def test_unreadable_texture_warns(tmp_path):
    obj, v, faces = write_tetrahedron(tmp_path, kd=(1, 1, 1))
    (tmp_path / "quad.png").write_bytes(b"not a png at all")
    with pytest.warns(GeovoxWarning, match="quad.png"):
        vol = geovox.voxelize(obj, resolution=12, color=True)
    assert np.all(vol.colors[vol.occupancy, :3] == 255)


def test_missing_mtl_warns_and_finishes(tmp_path):
    obj, v, faces = write_tetrahedron(tmp_path, mtl="nowhere.mtl")
    os.remove(tmp_path / "nowhere.mtl")
    with pytest.warns(GeovoxWarning, match="nowhere.mtl"):
        vol = geovox.voxelize(obj, resolution=12, color=True)
    assert np.all(vol.colors[vol.occupancy, :3] == 204)


def _reference_colours(mesh, points, image):
    """Brute force: closest point over all triangles (trimesh), then UV, texture, Kd."""
    tris = mesh.triangles
    best_d = np.full(len(points), np.inf)
    best_p = np.zeros((len(points), 3))
    best_t = np.zeros(len(points), int)
    for t in range(len(tris)):
        cp = trimesh.triangles.closest_point(np.repeat(tris[t:t + 1], len(points), 0), points)
        d = np.linalg.norm(cp - points, axis=1)
        better = d < best_d
        best_d[better], best_p[better], best_t[better] = d[better], cp[better], t
    bary = trimesh.triangles.points_to_barycentric(tris[best_t], best_p)
    uv = np.einsum("nk,nkc->nc", bary, mesh.corner_uv[best_t])
    h, w = image.shape[:2]
    x = (uv[:, 0] % 1.0) * w - 0.5
    y = (1 - uv[:, 1] % 1.0) * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    px = lambda yy, xx: image[yy % h, xx % w].astype(float)  # noqa: E731
    rgb = (px(y0, x0) * (1 - fx) * (1 - fy) + px(y0, x0 + 1) * fx * (1 - fy)
           + px(y0 + 1, x0) * (1 - fx) * fy + px(y0 + 1, x0 + 1) * fx * fy)
    return np.rint(rgb), best_d


def test_spot_matches_brute_force_nearest_point():
    vol = geovox.voxelize(SPOT, resolution=24, color="fast", backend="numpy")
    mesh = geovox.load_mesh(SPOT)
    image = np.asarray(Image.open(os.path.join(os.path.dirname(SPOT), "spot_texture.png")).convert("RGB"))
    idx = np.argwhere(vol.occupancy)
    rng = np.random.default_rng(1)
    idx = idx[rng.choice(len(idx), 400, replace=False)]
    ref, dist = _reference_colours(mesh, centres_of(vol, idx), image)
    got = vol.colors[tuple(idx.T)][:, :3].astype(float)
    err = np.abs(got - ref).max(axis=1)
    near = dist < 1.0 * min(vol.spacing)
    # Near the surface the nearest point is found exactly (up to texels).
    assert np.mean(err[near] <= 2) > 0.95, np.mean(err[near] <= 2)
    # Deeper, the six-axis candidate is close to the true nearest point.
    assert np.mean(err <= 16) > 0.85, np.mean(err <= 16)


@pytest.mark.skipif(len(geovox.available_backends()) < 2, reason="needs both backends")
@pytest.mark.parametrize("rel", ["spot/spot.obj", "fuze/fuze.obj", "trimesh_edge_cases/box.obj"])
def test_backends_give_the_same_colours(rel):
    path = corpus(rel)
    a = geovox.voxelize(path, resolution=40, color="fast", backend="numpy")
    b = geovox.voxelize(path, resolution=40, color="fast", backend="embree")
    same = a.occupancy == b.occupancy
    assert same.all()
    diff = np.abs(a.colors.astype(int) - b.colors.astype(int))
    assert diff.max() <= 1


def test_fuze_texture_with_space_in_name_loads():
    path = corpus("fuze", "fuze.obj")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        vol = geovox.voxelize(path, resolution=24, color=True)
    rgb = vol.colors[vol.occupancy, :3]
    assert len(np.unique(rgb.reshape(-1, 3), axis=0)) > 20  # textured, not flat Kd


def test_colour_layout_is_rgba_interleaved_x_fastest():
    vol = geovox.voxelize(SPOT, resolution=12, color=True)
    raw = vol.colors.transpose(2, 1, 0, 3)
    assert raw.flags.c_contiguous
    flat = np.frombuffer(raw.tobytes(), np.uint8).reshape(-1, 4)
    x, y, z = 5, 7, 3
    np.testing.assert_array_equal(flat[x + 12 * (y + 12 * z)], vol.colors[x, y, z])


@pytest.mark.parametrize("jobs", [2, 3])
def test_result_does_not_depend_on_jobs(jobs, backend):
    one = geovox.voxelize(SPOT, resolution=48, color="fast", jobs=1, backend=backend)
    many = geovox.voxelize(SPOT, resolution=48, color="fast", jobs=jobs, backend=backend)
    np.testing.assert_array_equal(one.occupancy, many.occupancy)
    np.testing.assert_array_equal(one.colors, many.colors)


def test_relevant_crossings_keeps_what_a_voxel_can_use():
    from geovox.backends.base import Hits
    from geovox.colour import relevant_crossings

    rng = np.random.default_rng(2)
    h = 2000
    hits = Hits(ray=rng.integers(0, 50, h), depth=rng.integers(-5, 15, h).astype(float),
                triangle=rng.permutation(h), bary=np.zeros((h, 2)))
    n = 10
    k = np.clip(hits.depth, 0, n).astype(int)  # centres at 0.5 .. 9.5 -> k = ceil-ish
    got = relevant_crossings(hits, k, n, 50).sorted()
    # Already in order, the fast path keeps the same crossings.
    s0 = hits.sorted()
    fast = relevant_crossings(s0, np.clip(s0.depth, 0, n).astype(int), n, 50)
    assert fast.ordered
    np.testing.assert_array_equal(fast.triangle, got.triangle)
    # Reference: sort everything, then per ray keep the in-range crossings,
    # the last one before the first centre and the first one past the last.
    s = hits.sorted()
    ks = np.clip(s.depth, 0, n).astype(int)
    want = []
    for r in range(50):
        on = np.flatnonzero(s.ray == r)
        before, inner, after = on[ks[on] == 0], on[(ks[on] > 0) & (ks[on] < n)], on[ks[on] == n]
        want += list(before[-1:]) + list(inner) + list(after[:1])
    np.testing.assert_array_equal(got.triangle, s.triangle[np.array(want)])


def _coloured_boxes(open_bottom=False, gap=False):
    """Subdivided boxes with random vertex colours (every crossing its own colour).

    ``open_bottom``: one box without its bottom face, so that the winding number
    fills it and, along z, every inside voxel lies before the first crossing of its
    column. ``gap``: two boxes stacked along z with empty layers between them.
    """
    parts = [trimesh.creation.box(extents=(2, 2, 2)).subdivide().subdivide()]
    if open_bottom:
        b = parts[0]
        parts = [trimesh.Trimesh(b.vertices, b.faces[b.triangles_center[:, 2] > -0.99],
                                 process=False)]
    if gap:
        top = parts[0].copy()
        top.apply_translation((0.2, -0.1, 3.0))
        parts.append(top)
    mesh = trimesh.util.concatenate(parts)
    rng = np.random.default_rng(7)
    mesh.visual.vertex_colors = rng.integers(0, 256, (len(mesh.vertices), 4)).astype(np.uint8)
    return mesh


@pytest.mark.parametrize("model", ["spot", "open_box", "gap"])
def test_colour_does_not_depend_on_chunks_or_tasks(monkeypatch, model, backend):
    """The six-crossing colour works through chunks of z layers (carrying the
    crossings along z from chunk to chunk), in tasks spread over the threads;
    tiny chunks, tasks and blocks must give the one-chunk result exactly."""
    from geovox.colour import fast as colour

    mesh = {"spot": lambda: SPOT, "open_box": lambda: _coloured_boxes(open_bottom=True),
            "gap": lambda: _coloured_boxes(gap=True)}[model]()
    opts = dict(shape=(23, 19, 31), color="fast", backend=backend)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)  # the open box says it is open
        whole = geovox.voxelize(mesh, jobs=1, **opts)  # one chunk, one task
        monkeypatch.setattr(colour, "CHUNK_VOXELS", 23 * 19 * 2)  # 2 layers, 1 in the last
        monkeypatch.setattr(colour, "TASK_VOXELS", 23 * 19 * 6)  # 3 chunks a task
        monkeypatch.setattr(colour, "BLOCK", 100)
        for jobs in (1, 3):
            small = geovox.voxelize(mesh, jobs=jobs, **opts)
            np.testing.assert_array_equal(small.colors, whole.colors)
    assert len(np.unique(whole.colors[whole.occupancy], axis=0)) > 50


def test_streamed_raw_colours_written_chunk_by_chunk(tmp_path, monkeypatch):
    """Several slabs to .raw: each chunk's colours go straight into the file."""
    import geovox.formats as F
    from geovox.colour import fast as colour

    monkeypatch.setattr(colour, "CHUNK_VOXELS", 16 * 16 * 5)
    opts = dict(shape=(16, 16, 150), color="fast")
    ref = geovox.voxelize(SPOT, axis=1, **opts)  # several slabs cast along y
    info = geovox.convert_to(SPOT, tmp_path / "s.raw", budget=16 * 16 * 64 * 30, jobs=2, **opts)
    assert info["slabs"] == 3
    back = F.read(tmp_path / "s.raw")
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
    np.testing.assert_array_equal(back.colors, ref.colors)


def test_disk_full_while_writing_colours_chunk_by_chunk(tmp_path, monkeypatch):
    """An error in a colour thread's write stops the conversion and leaves no file."""
    import errno

    from geovox.errors import OutputError
    from geovox.formats.raw import RawWriter

    calls = []

    def full(self, z, rgba):
        calls.append(z)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(RawWriter, "write_colours", full)
    with pytest.raises(OutputError, match="disk full"):
        geovox.convert_to(SPOT, tmp_path / "s.raw", shape=(16, 16, 150), color="fast",
                          budget=16 * 16 * 64 * 30, jobs=2)
    assert calls and os.listdir(tmp_path) == []


def test_streamed_raw_colours_without_positional_writes(tmp_path, monkeypatch):
    """Where os.pwrite does not exist (Windows), slabs' colours are written whole."""
    import geovox.formats as F

    monkeypatch.delattr(os, "pwrite")
    opts = dict(shape=(16, 16, 150), color="fast")
    ref = geovox.voxelize(SPOT, axis=1, **opts)
    info = geovox.convert_to(SPOT, tmp_path / "s.raw", budget=16 * 16 * 64 * 30, jobs=2, **opts)
    assert info["slabs"] == 3
    back = F.read(tmp_path / "s.raw")
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
    np.testing.assert_array_equal(back.colors, ref.colors)


def test_textures_read_ahead_are_the_ones_load_textures_reads(tmp_path, monkeypatch):
    # The pipeline starts decoding textures while the rays run
    # (colour.prefetch_textures); what it puts in place is what
    # load_textures would have read, and load_textures then reads nothing.
    from geovox.colour import load_textures, prefetch_textures

    ref = geovox.load_mesh(SPOT)
    load_textures(ref)
    mesh = geovox.load_mesh(SPOT)
    finish = prefetch_textures(mesh)
    assert finish is not None
    finish()
    np.testing.assert_array_equal(mesh.materials[0].image, ref.materials[0].image)

    def refuse(*a, **k):
        raise AssertionError("read again")

    monkeypatch.setattr(Image, "open", refuse)
    load_textures(mesh)
    assert prefetch_textures(mesh) is None  # nothing left to read


@pytest.mark.parametrize("kind", ["not_an_image", "palette", "truncated"])
def test_textures_not_read_ahead_are_reported_as_before(tmp_path, kind):
    # A file that is not a plain PNG or JPEG is left to load_textures, and so
    # is one whose decoding fails on the thread: the same warning, or the
    # same colours, as without reading ahead.
    from geovox.colour import load_textures, prefetch_textures

    obj = tmp_path / "m.obj"
    obj.write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                   "vt 0 0\nvt 1 0\nvt 0 1\nusemtl a\n"
                   "f 1/1 3/3 2/2\nf 1/1 2/2 4/3\nf 1/1 4/3 3/3\nf 2/2 3/3 4/1\n")
    (tmp_path / "m.mtl").write_text("newmtl a\nmap_Kd t.png\n")
    if kind == "not_an_image":
        (tmp_path / "t.png").write_bytes(b"not a png at all")
    elif kind == "palette":
        Image.new("P", (4, 4), 3).save(tmp_path / "t.png")
    else:
        noise = np.random.default_rng(0).integers(0, 256, (64, 64, 3), dtype=np.uint8)
        Image.fromarray(noise).save(tmp_path / "t.png")
        data = (tmp_path / "t.png").read_bytes()
        (tmp_path / "t.png").write_bytes(data[:len(data) // 2])  # the header is whole
    mesh = geovox.load_mesh(obj)
    finish = prefetch_textures(mesh)
    if kind == "truncated":
        finish()  # the thread's failure is not raised, and nothing is put in place
        assert mesh.materials[0].image is None
    else:
        assert finish is None
    if kind == "palette":
        load_textures(mesh)
        assert mesh.materials[0].image.shape == (4, 4, 3)
        return
    with pytest.warns(GeovoxWarning, match="cannot read texture"):
        load_textures(mesh)
    assert mesh.materials[0].image is None
