"""The caps' winding number on a cap-heavy model, held to a brute-force winding number.

Models like the libigl truck (50 parts, 1,388 open edges) put most of the
winding path's work in the caps' winding number ``w_K`` (see
``geovox.inside.captree.correct_caps``). These tests hold every voxel that the
path decides by a proven bound to the brute-force generalised winding
number of the repaired mesh (every triangle summed exactly at every voxel
centre), and pin how many voxels are left to the estimate: a loosened
far-field pass, or a bound that stops being proven, changes one or the other.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

import geovox
from geovox.errors import GeovoxWarning
from geovox import inside
from geovox.inside import captree, caps, winding
from geovox.kernels import chosen


def cap_heavy(n=24, seed=5):
    """``n`` open parts placed and turned at random in the unit cube, overlapping.

    Open tubes, spheres with a cap cut off and boxes without their top, each
    stretched along its axes: 598 faces and 278 open edges for the defaults,
    so that the caps (one triangle per open edge) are many and large.
    """
    rng = np.random.default_rng(seed)
    V, F, off = [], [], 0
    for i in range(n):
        if i % 3 == 0:
            m = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=int(rng.integers(6, 12)))
            keep = np.abs(m.face_normals[:, 2]) < 0.5
        elif i % 3 == 1:
            m = trimesh.creation.icosphere(subdivisions=1)
            keep = m.triangles_center[:, 2] < rng.uniform(-0.3, 0.7)
        else:
            m = trimesh.creation.box((2, 2, 2))
            keep = m.triangles_center[:, 2] < 0.99
        R = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
        scale = rng.uniform(0.06, 0.2) * rng.uniform(0.5, 1.5, 3)
        V.append(np.asarray(m.vertices) * scale @ R.T + rng.uniform(0, 1, 3))
        F.append(np.asarray(m.faces)[keep] + off)
        off += len(m.vertices)
    return geovox.Mesh(np.concatenate(V), np.concatenate(F), source="cap-heavy")


MESH = cap_heavy()


def _compiled_winding():
    """The compiled winding module where it was built, else None."""
    with chosen("auto"):
        return inside.winding_kernel()
RES = 20
#: Voxels the compiled first pass leaves undecided on MESH at RES (see the tests below):
#: (0.4, 1e-4) with the moment- and segment-aware bounds of geovox/_winding.pyx and
#: a single triangle's bound from its edges (78 with the face's bound alone; a
#: first pass of (0.2, 1e-4) with the bound ``3 A (r + rb)^2 / (4 pi d^4)`` left 22)
#: left 70; MESH's caps are small next to its voxels, so ``captree.SCAN_PASS``
#: (0.7, 1e-3) runs first and leaves 281 (the later passes decide the rest).
ESTIMATED_AT_ZERO = 281


def brute_winding_number(mesh, grid):
    """(nx, ny, nz) float64: every triangle's solid angle over 4 pi, summed exactly at each centre."""
    tris = mesh.triangles
    c = [grid.centres(a) for a in range(3)]
    p = np.stack(np.meshgrid(*c, indexing="ij"), -1).reshape(-1, 3)
    out = np.zeros(len(p))
    block = 64
    for s in range(0, len(p), block):
        q = p[s:s + block]
        k = len(q)
        a = captree.triangle_angles(np.tile(tris, (k, 1, 1)), np.repeat(q, len(tris), axis=0))
        out[s:s + block] = a.reshape(k, -1).sum(axis=1)
    return out.reshape(grid.shape)


@pytest.fixture(scope="module")
def reference():
    grid = geovox.voxelize(MESH, resolution=RES, inside="parity").grid
    return grid, brute_winding_number(inside.target(MESH)[0], grid)


def run_winding(monkeypatch):
    """The volume and the mask of the voxels left to the estimate (all False where none)."""
    seen = []
    real = winding._estimated
    monkeypatch.setattr(winding, "_estimated", lambda unsure, grid: seen.append(unsure.copy())
                        or real(unsure, grid))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        vol = geovox.voxelize(MESH, resolution=RES, inside="winding")
    assert len(seen) <= 1
    estimated = seen[0] if seen else np.zeros(vol.grid.shape, bool)
    assert vol.approximate == np.count_nonzero(estimated)
    return vol, estimated


def test_the_model_is_cap_heavy():
    assert len(MESH.faces) == 598
    assert len(inside.boundary_edges(MESH)) == 278
    assert len(inside.capped(inside.target(MESH)[0])[1]) >= 250


KERNELS = ["numpy", pytest.param("compiled", marks=pytest.mark.skipif(
    _compiled_winding() is None, reason="the compiled winding kernel is not built"))]


@pytest.mark.parametrize("kernel", KERNELS)
def test_within_the_budget_every_voxel_is_the_brute_force(reference, monkeypatch, kernel):
    grid, w = reference
    monkeypatch.setenv("GEOVOX_KERNEL", kernel)
    vol, estimated = run_winding(monkeypatch)
    assert vol.grid.shape == grid.shape
    assert np.count_nonzero(estimated) == 0
    # The brute force is itself a float64 sum: stay clear of ties with 1/2.
    assert np.abs(w - 0.5).min() > 1e-6
    np.testing.assert_array_equal(vol.occupancy, w > 0.5)


@pytest.mark.parametrize("direct", [True, False], ids=["direct", "passes"])
def test_past_a_small_budget_proven_voxels_are_the_brute_force(reference, monkeypatch, direct):
    # No time for the refining passes: they give up and leave voxels to the
    # first pass's estimate. Every voxel the bounds decided must still be
    # the brute force's, and how many were left is pinned (loosening PASSES
    # to ((3.0, 1e-1),) * 3 leaves 7,993 instead of 4,502; with the fans of
    # inside.capped instead of the small caps of inside.bridged, 5,340). The
    # NumPy traversal's budget, of processor time: at 0 its first pass alone
    # decides, whatever the machine's speed.
    grid, w = reference
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    if not direct:
        monkeypatch.setattr(captree, "DIRECT", 0)
    vol, estimated = run_winding(monkeypatch)
    proven = ~estimated
    np.testing.assert_array_equal(vol.occupancy[proven], (w > 0.5)[proven])
    assert np.count_nonzero(estimated) == 4502


@pytest.mark.skipif(_compiled_winding() is None, reason="the compiled winding kernel is not built")
def test_compiled_past_its_time_the_proven_voxels_are_the_brute_force(reference, monkeypatch):
    # No time at all: every voxel the first pass (bricks, second-order far
    # field) leaves undecided keeps its estimate. The rest are proven and
    # must be the brute force's; how many are left is pinned (a looser
    # first pass, or a bound that grew, changes it: a first pass of
    # (0.8, 1e-3) leaves 406).
    grid, w = reference
    monkeypatch.setenv("GEOVOX_KERNEL", "compiled")
    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    vol, estimated = run_winding(monkeypatch)
    proven = ~estimated
    np.testing.assert_array_equal(vol.occupancy[proven], (w > 0.5)[proven])
    assert np.count_nonzero(estimated) == captree.STATS["estimated"] == ESTIMATED_AT_ZERO


@pytest.mark.skipif(_compiled_winding() is None, reason="the compiled winding kernel is not built")
@pytest.mark.parametrize("passes, bricks", [
    (((0.4, 1e-4), (0.25, 1e-6), (0.1, 1e-7)), 1),  # no pass over the undecided bricks
    (((1.5, 1e-2), (0.6, 1e-3), (0.3, 1e-4), (0.1, 1e-5)), 4),  # reach past the centres' distance
    (((0.4, 1e-4),), 1),  # straight to the exact sum
])
def test_compiled_passes_change_the_work_not_the_answer(reference, monkeypatch, passes, bricks):
    # However the passes are split between bricks and single voxels, and
    # however loose the first, every voxel is the brute force's.
    grid, w = reference
    monkeypatch.setenv("GEOVOX_KERNEL", "compiled")
    monkeypatch.setattr(captree, "COMPILED_PASSES", passes)
    monkeypatch.setattr(captree, "COMPILED_BRICKS", bricks)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        vol = geovox.voxelize(MESH, resolution=RES, inside="winding")
    assert captree.STATS["estimated"] == 0 and captree.STATS["refined"] > 0
    np.testing.assert_array_equal(vol.occupancy, w > 0.5)


@pytest.mark.skipif(_compiled_winding() is None, reason="the compiled winding kernel is not built")
@pytest.mark.parametrize("jobs", [1, 3])
def test_compiled_refines_every_voxel_alone_and_agrees(reference, monkeypatch, jobs):
    # With time, the voxels the first pass leaves are refined alone (tighter
    # passes, then the exact sum), on any number of threads.
    grid, w = reference
    monkeypatch.setenv("GEOVOX_KERNEL", "compiled")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        vol = geovox.voxelize(MESH, resolution=RES, inside="winding", jobs=jobs)
    assert captree.STATS["refined"] == ESTIMATED_AT_ZERO and captree.STATS["estimated"] == 0
    np.testing.assert_array_equal(vol.occupancy, w > 0.5)


def test_kernel_choice():
    with chosen("numpy"):
        assert inside.winding_kernel() is None
    with pytest.raises(geovox.ParameterError, match="auto, compiled or numpy"), chosen("fast"):
        inside.winding_kernel()


def test_boundary_pieces_split_into_closed_loops():
    # Two squares' boundaries meeting at one corner, and a path that does
    # not close (its piece keeps one fan).
    vid = np.array([[0, 1], [1, 2], [2, 3], [3, 0],      # square A
                    [0, 4], [4, 5], [5, 6], [6, 0],      # square B, through corner 0
                    [7, 8], [8, 9]])                     # an open path
    piece = np.array([0] * 8 + [1] * 2)
    lab = caps.loops(vid, piece)
    assert len(np.unique(lab)) == 3
    assert len(np.unique(lab[8:])) == 1 and not set(lab[8:]) & set(lab[:8])
    for k in np.unique(lab[:8]):  # each loop closed: every position arrives as often as it leaves
        e = vid[:8][lab[:8] == k]
        assert sorted(e[:, 0]) == sorted(e[:, 1])


def test_caps_over_loops_close_the_same_boundary():
    # The caps' own boundary must be the mesh's boundary reversed, whatever
    # the loops: the capped mesh has no open edge left.
    tm = inside.target(MESH)[0]
    closed, cap_tris, piece = inside.capped(tm)
    assert len(inside.boundary_edges(closed)) == 0
    assert len(cap_tris) == len(inside.boundary_edges(tm))


class _Clock:
    """A processor clock for geovox.inside.winding that moves on one second each time it is read."""

    def __init__(self):
        self.now = 0.0

    def process_time(self):
        self.now += 1.0
        return self.now


@pytest.mark.parametrize("seconds", [0.0, 2.0, 5.0, 9.0, 1e9])
def test_the_numpy_budget_is_time_and_only_its_end_depends_on_it(reference, monkeypatch, seconds):
    # The NumPy traversal's budget is processor time (WORK_SECONDS), read
    # between chunks of pairs, before a pass and between the exact sums: a
    # clock that jumps a second at every reading runs it out at every such
    # point in turn. Wherever it runs out, the voxels it leaves are counted
    # (the Report's approximate, the warning's mask) and every other voxel
    # is the brute force's; with time to spare nothing depends on the clock.
    grid, w = reference
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    monkeypatch.setattr(captree, "time", _Clock())
    monkeypatch.setattr(captree, "WORK_SECONDS", seconds)
    vol, estimated = run_winding(monkeypatch)
    proven = ~estimated
    np.testing.assert_array_equal(vol.occupancy[proven], (w > 0.5)[proven])
    if seconds == 1e9:
        assert vol.approximate == 0
        np.testing.assert_array_equal(vol.occupancy, w > 0.5)
    else:
        assert vol.approximate > 0
    if seconds == 0.0:
        assert vol.approximate == 4502  # the first pass alone (as the test above)


@pytest.mark.parametrize("kernel", KERNELS)
def test_the_report_counts_the_approximate_voxels(reference, monkeypatch, kernel):
    # Report.approximate is the warning's count and the count of the voxels
    # the traversal left to their estimates, and every voxel that is not
    # the brute force's is one of them; the summary says it.
    import re

    from geovox.planner import as_options, plan

    from geovox.runners import run

    grid, w = reference
    monkeypatch.setenv("GEOVOX_KERNEL", kernel)
    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    seen = []
    real = winding._estimated
    monkeypatch.setattr(winding, "_estimated", lambda unsure, grid: seen.append(unsure.copy())
                        or real(unsure, grid))
    with pytest.warns(GeovoxWarning) as record:
        report = run(MESH, plan(MESH, as_options(resolution=RES, inside="winding")))
    (mask,) = seen
    said = [re.match(r"([0-9,]+) of 8,000 voxels .* are approximate", str(r.message))
            for r in record]
    (n,) = [int(m.group(1).replace(",", "")) for m in said if m]
    assert report.approximate == report.volume.approximate == n == np.count_nonzero(mask) > 0
    assert report["approximate"] == n
    wrong = report.volume.occupancy != (w > 0.5)
    assert np.all(mask[wrong])
    if kernel == "compiled":
        assert n == captree.STATS["estimated"] == ESTIMATED_AT_ZERO
    (line,) = [x for x in report.summary(1.0) if x.startswith("approximate ")]
    share = 100 * n / 8000
    assert line == (f"approximate {n:,} voxels ({share:.1f}%): " if share >= 1 else
                    f"approximate {n:,} voxels ({share:.2g}%): ") + (
        "decided by an estimate of the winding number (its work budget ran out)")
    # With time: none, and the summary has no such line.
    monkeypatch.setattr(captree, "WORK_SECONDS", 10.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        report = run(MESH, plan(MESH, as_options(resolution=RES, inside="winding")))
    assert report.approximate == 0
    assert not [x for x in report.summary(1.0) if x.startswith("approximate")]


def test_slabs_sum_their_approximate_voxels_and_say_it_once(tmp_path, monkeypatch):
    # Streamed slab by slab (their warnings silenced), the Report sums the
    # slabs' approximate voxels and one warning says the sum.
    import re

    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    seen = []
    real = winding._estimated
    monkeypatch.setattr(winding, "_estimated", lambda unsure, grid: seen.append(
        int(np.count_nonzero(unsure))) or real(unsure, grid))
    with pytest.warns(GeovoxWarning) as record:
        report = geovox.convert_to(MESH, tmp_path / "m.h5", shape=(16, 16, 150), inside="winding",
                                   budget=16 * 16 * 64 * 17)
    assert report.slabs > 1 and len(seen) == report.slabs
    said = [re.match(r"([0-9,]+) of 38,400 voxels .* are approximate", str(r.message))
            for r in record]
    (n,) = [int(m.group(1).replace(",", "")) for m in said if m]
    assert report.approximate == n == sum(seen) > 0


def test_a_batch_records_the_approximate_voxels(tmp_path, monkeypatch):
    import json

    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    path = tmp_path / "cap_heavy.off"
    v, f = MESH.vertices, MESH.faces
    path.write_text("OFF\n%d %d 0\n" % (len(v), len(f))
                    + "".join("%r %r %r\n" % tuple(map(float, x)) for x in v)
                    + "".join("3 %d %d %d\n" % tuple(x) for x in f))
    manifest = tmp_path / "done.jsonl"
    (r,) = geovox.convert_many([path], tmp_path / "out", resolution=RES, inside="winding",
                               manifest=manifest)
    assert r.status == "ok" and r.approximate > 0
    assert "are approximate" in r.note
    (rec,) = [json.loads(x) for x in manifest.read_text().splitlines()]
    assert rec["approximate"] == r.approximate
