"""The compiled repair and edge checks of open, messy meshes give the NumPy path's arrays.

``geovox._lattice`` computes :func:`geovox.inside.repair.repair`'s steps (the
positions' lexicographic numbers, the weld's close pairs, duplicate groups,
the edge table and the spanning forest with its flips) and
:func:`geovox.inside.edges.boundary_edges` of an open mesh in linear time;
the NumPy code stays as the fallback under ``GEOVOX_KERNEL=numpy``. Both must
give the same repaired mesh, array for array (face order, vertex ids, flips),
so every occupancy is unchanged. The meshes are made to break every step.
"""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh

import geovox
from geovox.inside import edges as E
from geovox.inside import repair as R
from geovox.kernels import chosen
from geovox.mesh import Mesh, build_mesh

pytest.importorskip("geovox._lattice")

DATA = os.path.join(os.path.dirname(__file__), "data")


def _tm(m, shift=(0.0, 0.0, 0.0), scale=1.0):
    return np.asarray(m.vertices, float) * scale + np.asarray(shift), np.asarray(m.faces, np.int64)


def _join(parts):
    """One (vertices, faces) of several, faces renumbered."""
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def _moebius(n=24):
    """A Moebius band of 2 n triangles: its flips cannot all agree."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = []
    for s in (-0.3, 0.3):
        v.append(np.stack([(1 + s * np.cos(t / 2)) * np.cos(t), (1 + s * np.cos(t / 2)) * np.sin(t),
                           s * np.sin(t / 2)], 1))
    v = np.concatenate(v)
    f = []
    for i in range(n):
        j = (i + 1) % n
        a, b, c, d = i, j, n + i, n + j
        if j == 0:  # the half twist: the strip's sides swap
            c, d = n + i, 0
            b = n
        f += [[a, b, c], [b, d, c]]
    return v + np.array([4.0, 0, 0]), np.array(f, np.int64)


def _fan(n=300):
    """An open cone of ``n`` faces around one apex (a bucket far above the insertion sort's)."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    v = np.concatenate([[[0.0, 0.0, 1.0]], np.stack([np.cos(t), np.sin(t), np.zeros(n)], 1)])
    f = np.stack([np.zeros(n, np.int64), 1 + np.arange(n), 1 + (np.arange(n) + 1) % n], 1)
    return v + np.array([0, 4.0, 0]), f


def _messy(seed, moebius=True):
    """Many kinds of damage in one mesh of several components.

    With ``moebius``, a band whose flips contradict: the compiled repair then
    runs the rounds of :func:`geovox.inside.edges.components` (the forest
    decides); without, its union-find must give the same flips.
    """
    rng = np.random.default_rng(seed)
    parts = []
    # Open spheres with holes, faces flipped at random, one turned inside out.
    for k in range(3):
        v, f = _tm(trimesh.creation.icosphere(subdivisions=2), shift=rng.uniform(-2, 2, 3),
                   scale=rng.uniform(0.3, 1.0))
        f = f[rng.random(len(f)) > 0.05]
        flip = rng.random(len(f)) < (1.0 if k == 0 else 0.3)
        f[flip] = f[flip][:, ::-1]
        parts.append((v, f))
    # A closed box stored twice, once each way round (double-sided), and one
    # with exact duplicates.
    v, f = _tm(trimesh.creation.box((1, 1, 1)), shift=(0, 0, 3))
    parts.append((v, np.concatenate([f, f[:, ::-1]])))
    v, f = _tm(trimesh.creation.box((0.5, 1, 1)), shift=(3, 3, 0))
    parts.append((v, np.concatenate([f, f[:4], f[2:6, [1, 2, 0]]])))
    # Two closed boxes sharing a face stored both ways: an inner wall.
    # (The second is the first mirrored at x = 0.5: the same split of the face.)
    v, f = _tm(trimesh.creation.box((1, 1, 1)), shift=(-4, -4, 0))
    parts.append(_join([(v, f), (v * [-1, 1, 1] + [-7, 0, 0], f[:, ::-1])]))
    # Non-manifold fins: three and four faces on one edge.
    v = np.array([[0, 0, 0], [0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0.5]], float)
    parts.append((v + 6, np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [1, 0, 5]], np.int64)))
    # Degenerate faces: a repeated vertex, and three collinear points.
    v = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [0, 1, 0]], float)
    parts.append((v - 6, np.array([[0, 1, 2], [0, 0, 3], [3, 1, 1], [0, 1, 3]], np.int64)))
    parts += [_moebius(), _fan()] if moebius else [_fan()]
    v, f = _join(parts)
    # Vertices split at equal positions (UV seams), some closer than the weld
    # distance, and signed zeros.
    dup = rng.choice(len(v), len(v) // 4, replace=False)
    v2 = v[dup].copy()
    near = rng.random(len(dup)) < 0.3
    v2[near] += rng.normal(0, 1e-9, (int(near.sum()), 3))
    v = np.concatenate([v, v2])
    redirect = np.arange(len(v) - len(dup))
    redirect[dup] = len(v) - len(dup) + np.arange(len(dup))
    use = rng.random(f.shape) < 0.5
    f = np.where(use, redirect[f], f)
    zero = v == 0
    v[zero & (rng.random(v.shape) < 0.5)] = -0.0
    # Shuffled faces, and unused vertices.
    f = f[rng.permutation(len(f))]
    v = np.concatenate([v, rng.normal(0, 1, (7, 3))])
    return v, f


def _loaded(name):
    from geovox.io.load import load_mesh

    m = load_mesh(os.path.join(DATA, name))
    return m.vertices, m.faces


CASES = {f"messy{s}": (lambda s=s: _messy(s)) for s in range(4)}
CASES.update({f"orientable{s}": (lambda s=s: _messy(s, moebius=False)) for s in range(4)})
CASES.update({"moebius": _moebius, "fan": _fan,
              "truck": lambda: _loaded("wild/truck.obj"),
              "pyramids": lambda: _loaded("wild/pyramids.3mf"),
              "wallhole": lambda: _loaded("trimesh_edge_cases/wallhole.obj"),
              "rabbit": lambda: _loaded("trimesh_edge_cases/rabbit.obj")})

FIELDS = ("face", "swapped", "piece", "merged_vertices", "welded", "degenerate", "duplicates",
          "opposite", "inner", "flipped", "pieces", "closed_pieces", "outward")


def _everything(v, f, kernel):
    """Every array the repair and the checks give, on a fresh mesh, under ``kernel``."""
    mesh = build_mesh(v, f, "case")
    with chosen(kernel):
        out = {"boundary": E.boundary_edges(mesh), "counts": np.array(E.edge_counts(mesh)),
               "consistent": np.array(E.consistent(mesh))}
        rep = R.repair(mesh)
        out.update({k: np.asarray(getattr(rep, k)) for k in FIELDS})
        out["vertices"], out["faces"] = rep.mesh.vertices, rep.mesh.faces
        out["boundary_after"] = E.boundary_edges(rep.mesh)
        out["seeded"] = rep.mesh.geometric_faces
    return out


@pytest.mark.parametrize("case", sorted(CASES))
def test_compiled_repair_gives_the_numpy_arrays(case):
    v, f = CASES[case]()
    a, b = _everything(v, f, "numpy"), _everything(v, f, "compiled")
    for k in a:
        assert a[k].dtype == b[k].dtype and a[k].shape == b[k].shape, k
        assert np.array_equal(a[k], b[k]), k  # bit for bit, signed zeros included
        if a[k].dtype.kind == "f":
            assert np.array_equal(a[k].view(np.uint64), b[k].view(np.uint64)), k


@pytest.mark.parametrize("kernel", ["numpy", "compiled"])
@pytest.mark.parametrize("case", ["messy0", "messy1", "moebius", "truck", "pyramids", "wallhole"])
def test_what_the_repair_caches_on_its_copy_is_what_the_checks_would_find(case, kernel):
    # repair() seeds the copy's geometric faces with its faces (its vertices
    # are distinct and in lexicographic order, so merging changes nothing),
    # and its open edges and edge counts from its own edge table.
    v, f = CASES[case]()
    with chosen(kernel):
        rep = R.repair(build_mesh(v, f, "case"))
        fresh = Mesh(rep.mesh.vertices, rep.mesh.faces)
        assert np.array_equal(fresh.geometric_faces, rep.mesh.faces)
        for check in (E.boundary_edges, E.edge_counts, E.non_manifold, E.consistent):
            seeded, again = check(rep.mesh), check(fresh)
            assert np.asarray(seeded).dtype == np.asarray(again).dtype
            assert np.array_equal(seeded, again), check.__name__


def test_the_cases_break_what_they_are_meant_to():
    v, f = _messy(0)
    with chosen("compiled"):
        mesh = build_mesh(v, f, "messy")
        rep = R.repair(mesh)
        n_open, n_nonmanifold = E.edge_counts(mesh)
    assert n_open and n_nonmanifold
    assert rep.welded and rep.degenerate and rep.duplicates and rep.opposite and rep.inner
    assert rep.flipped and rep.outward and rep.pieces > 5
    # The Moebius band: some manifold edge is run the same way by both its
    # faces after the flips (no choice of flips can avoid one).
    mv, mf = _moebius()
    rep = R.repair(build_mesh(mv, mf, "moebius"))
    edge, count, forward = E.edge_table(rep.mesh.faces, len(rep.mesh.vertices))
    pairs = E.manifold_pairs(edge, count)
    assert np.any(forward[pairs[:, 0]] == forward[pairs[:, 1]])


@pytest.mark.parametrize("seed", range(5))
def test_compiled_components_follow_the_same_forest(seed):
    # Random graphs with contradicting parities: the forest decides them,
    # so the compiled rounds must hook through the same edges.
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 3000))
    e = int(rng.integers(0, 3 * n))
    a, b = rng.integers(0, n, e), rng.integers(0, n, e)
    odd = rng.random(e) < 0.5
    with chosen("numpy"):
        want = E.components(n, a, b, odd)
    with chosen("compiled"):
        got = E.components(n, a, b, odd)
    assert want[0] == got[0]
    assert np.array_equal(want[1], got[1]) and np.array_equal(want[2], got[2])


@pytest.mark.parametrize("seed", range(3))
def test_compiled_edge_table_and_close_pairs_match_numpy(seed):
    rng = np.random.default_rng(seed)
    faces = rng.integers(0, 40, (500, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2])
                  & (faces[:, 2] != faces[:, 0])]
    faces[:60, 0] = 0  # one vertex on many edges: the merging sort
    faces = faces[(faces[:, 1] != 0) & (faces[:, 2] != 0) | (np.arange(len(faces)) >= 60)]
    with chosen("numpy"):
        want = E.sorted_edges(faces, 40)
    with chosen("compiled"):
        got = E.sorted_edges(faces, 40)
    for x, y in zip(want, got):
        assert np.array_equal(x, y)
    # Points on a lattice of exactly the tolerance, and jittered copies.
    p = np.concatenate([np.indices((6, 6, 6)).reshape(3, -1).T * 0.5,
                        rng.uniform(0, 3, (400, 3))])
    p = np.concatenate([p, p[::3] + rng.normal(0, 0.2, (len(p[::3]), 3))])
    for tol in (0.5, 0.21, 1e-3):
        with chosen("numpy"):
            want = R.close_pairs(p, tol)
        with chosen("compiled"):
            got = R.close_pairs(p, tol)
        key = lambda q: set(map(tuple, q.tolist()))  # noqa: E731 (the order differs)
        assert key(want) == key(got) and len(got) == len(key(got))


@pytest.mark.filterwarnings("ignore:.*(not closed|approximate):geovox.errors.GeovoxWarning")
@pytest.mark.parametrize("case", ["messy1", "truck"])
def test_the_occupancy_of_a_messy_model_is_the_same_under_both_kernels(case):
    v, f = CASES[case]()
    vols = [geovox.voxelize(build_mesh(v, f, "case"), resolution=24, kernel=k).occupancy
            for k in ("numpy", "compiled")]
    assert vols[0].any() and np.array_equal(vols[0], vols[1])


# --- the kernels of issue 37's scans, each against the NumPy it stands for ---------


def _rows(rng, n, kind):
    if kind == "normal":
        return rng.normal(size=(n, 3))
    v = rng.integers(-2, 3, (n, 3)).astype(float)  # ties on x, y and z
    v[rng.random(v.shape) < 0.3] *= -0.0  # signed zeros: one position
    return v


@pytest.mark.parametrize("kind", ["normal", "ties"])
def test_lex_order_is_lexsort(kind):
    from geovox import _lattice

    rng = np.random.default_rng(3)
    for n in (0, 1, 2, 17, 5000):
        v = _rows(rng, n, kind)
        assert np.array_equal(_lattice.lex_order(np.ascontiguousarray(v)),
                              np.lexsort((v[:, 2], v[:, 1], v[:, 0])))


def test_merge_positions_numbers_by_first_appearance():
    from geovox import _lattice

    rng = np.random.default_rng(4)
    for n in (1, 5, 3000, 70000):  # 70000: the table grows several times
        v = _rows(rng, n, "ties") + rng.integers(0, 30, (n, 1))
        got = _lattice.merge_positions(v)
        _, first, inverse = np.unique(v + 0.0, axis=0, return_index=True, return_inverse=True)
        rank = np.empty(len(first), np.int64)
        rank[np.argsort(first)] = np.arange(len(first))
        assert np.array_equal(got, rank[inverse.reshape(-1)])


def test_face_groups_and_duplicate_faces_match_numpy():
    from geovox import _lattice

    rng = np.random.default_rng(5)
    for trial in range(60):
        n = int(rng.integers(3, 40))
        f = rng.integers(0, n, (int(rng.integers(1, 300)), 3))
        f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        if trial % 3 == 0 and len(f):
            f[: len(f) // 2, 0] = 0  # a fan's apex: one big bucket
            f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
        if trial % 2:
            f = np.concatenate([f, f[::7][:, [1, 2, 0]], f[::11][:, ::-1]])[rng.permutation(len(f) + len(f[::7]) + len(f[::11]))]
        if len(f) == 0:
            continue
        with chosen("numpy"):
            want = R._face_groups(f, n)
        got = _lattice.face_groups(f)
        for x, y in zip(want, got):
            assert np.array_equal(x, y)
        assert _lattice.duplicate_faces(f) == (len(want[0]) < len(f))


def test_edge_checks_count_what_edge_counts_counts():
    from geovox import _lattice

    for case in ("messy0", "orientable1", "fan", "truck", "wallhole"):
        v, f = CASES[case]()
        mesh = build_mesh(v, f, case)
        with chosen("numpy"):
            counts = E.edge_counts(mesh)
            closed = len(E.boundary_edges(build_mesh(v, f, case))) == 0
        got = _lattice.edge_checks(mesh.geometric_faces)
        assert got[0] == closed and got[2:] == counts and got[1] == (counts[1] > 0)


def test_boundary_loops_are_loops_and_loop_order():
    from geovox import _lattice
    from geovox.inside import bridge, caps

    for case in ("messy0", "orientable2", "truck", "wallhole", "fan"):
        v, f = CASES[case]()
        with chosen("compiled"):
            tm = R.repair(build_mesh(v, f, case)).mesh
        edges = E.boundary_edges(tm)
        if len(edges) == 0:
            continue
        vid = np.unique(edges, return_inverse=True)[1].reshape(-1, 2)
        nv = int(vid.max()) + 1
        found = _lattice.boundary_loops(vid, nv)
        _, label, _ = E.components(nv, vid[:, 0], vid[:, 1])
        piece = caps.loops(vid, label[vid[:, 0]])
        if found is None:  # a position that does not balance: NumPy decides
            assert (bridge.loop_order(vid, piece) < 0).any()
            continue
        assert np.array_equal(found[0], piece)
        assert np.array_equal(found[1], bridge.loop_order(vid, piece))


def test_sweep_pairs_finds_every_close_pair_of_sorted_points():
    from geovox import _lattice

    rng = np.random.default_rng(6)
    p = np.concatenate([np.indices((6, 6, 6)).reshape(3, -1).T * 0.5, rng.uniform(0, 3, (400, 3))])
    p = np.concatenate([p, p[::3] + rng.normal(0, 0.2, (len(p[::3]), 3))])
    p = p[np.lexsort((p[:, 2], p[:, 1], p[:, 0]))]
    for tol in (0.5, 0.21, 1e-3):
        with chosen("numpy"):
            want = R.close_pairs(p, tol)
        got = _lattice.sweep_pairs(np.ascontiguousarray(p), tol, 10 ** 9)
        assert set(map(tuple, want.tolist())) <= set(map(tuple, got.tolist()))
        with chosen("compiled"):
            again = R.close_pairs(p, tol, lex_sorted=True)
        assert set(map(tuple, want.tolist())) == set(map(tuple, again.tolist()))
    assert _lattice.sweep_pairs(np.zeros((100, 3)), 1.0, 50) is None  # past its budget: give up


def test_repair_edges_leaves_duplicates_and_contradictions_to_its_caller():
    from geovox import _lattice

    v, f = _moebius()
    with chosen("compiled"):
        rep = R.repair(build_mesh(v, f, "moebius"))
    pos, g = rep.mesh.vertices, rep.mesh.faces.copy()
    c = pos.mean(axis=0)
    order = R._einsum_order()
    assert order in (0, 1, 2)  # NumPy's dot product, as the kernel follows it here
    assert _lattice.repair_edges(g.copy(), len(pos), pos, c, order) == _lattice.CONTRADICTION
    twice = np.concatenate([g, g[:3, ::-1]])
    before = twice.copy()
    assert _lattice.repair_edges(twice, len(pos), pos, c, order) == _lattice.DUPLICATES
    assert np.array_equal(twice, before)  # no face turned


def test_compiled_cap_tree_is_the_numpy_tree():
    from geovox import _winding
    from geovox.inside import captree

    rng = np.random.default_rng(8)
    for k in (1, 2, 3, 7, 100, 1001):
        tris = captree._morton_sorted(rng.normal(size=(k, 3, 3)))
        st, nodes, offset, size = captree._cap_tree(tris)
        assert np.array_equal(st, tris)
        S, A, C, H, Rr, Q, M, off, sz = _winding.cap_tree(np.ascontiguousarray(tris.reshape(-1, 9)))
        assert np.array_equal(off, offset) and np.array_equal(sz, size)
        for got, want in ((S, nodes["S"]), (A, nodes["A"]), (C, nodes["c"]), (H, nodes["h"]),
                          (Rr, nodes["r"])):
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-14)
        # The moments, as NumPy sums them: S_t (x) centroid_t about c; sqrt of sum A_t (|g - c|^2 + own).
        Sl = 0.5 * np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        g = tris.mean(axis=1)
        own = ((tris - g[:, None]) ** 2).sum(axis=(1, 2)) / 12
        for lv, (first, n) in enumerate(zip(offset, size)):
            node = np.arange(k) >> lv
            c = nodes["c"][first + node]
            q = np.zeros((n, 3, 3))
            np.add.at(q, node, Sl[:, :, None] * (g - c)[:, None, :])
            np.testing.assert_allclose(Q[first:first + n].reshape(-1, 3, 3), q, rtol=1e-9,
                                       atol=1e-12)
            m2 = np.bincount(node, weights=np.linalg.norm(Sl, axis=1)
                             * (((g - c) ** 2).sum(axis=1) + own), minlength=n)
            np.testing.assert_allclose(M[first:first + n], np.sqrt(m2), rtol=1e-12, atol=1e-14)
