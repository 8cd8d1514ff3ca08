"""The compiled kernel's single-triangle bounds; a soup of big triangles held to the brute force.

``geovox/_winding.pyx`` sums a (brick, cap triangle) pair as the triangle's
exact solid angle and gradient at the brick's centre, a linear field over
the brick, and bounds its error in two ways: from the distance to the
triangle's face (``single_bound``) and from the distances to its edges
(``edge_bound``, the Biot-Savart form of the solid angle's second
derivatives). These tests hold both bounds to the linear field's error at
points sampled in the brick's ball, show that the edges' bound is the
smaller one over a big triangle's interior, and check that the kernel uses
it: on a soup of big unconnected triangles (trimesh's ``soup.stl`` in small,
each triangle its own cap) the first pass leaves a pinned number of voxels
undecided, far fewer than with the face's bound alone, and every voxel is
the brute-force winding number's.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import geovox
from geovox.errors import GeovoxWarning
from geovox import inside
from geovox.inside import captree, winding
from geovox.kernels import chosen
from test_cap_winding import brute_winding_number


def _kernel():
    with chosen("auto"):
        return inside.winding_kernel()


KERNEL = _kernel()
needs_kernel = pytest.mark.skipif(KERNEL is None, reason="the compiled winding kernel is not built")


def _tri_distance(t, p):
    """Distance from p to the triangle t (3, 3): the nearest of its edges, or its plane where p's
    foot falls inside it (written apart from the kernel's Voronoi regions)."""
    d = min(_segment_distance(t[i], t[(i + 1) % 3], p) for i in range(3))
    n = np.cross(t[1] - t[0], t[2] - t[0])
    n = n / np.linalg.norm(n)
    q = p - np.dot(p - t[0], n) * n  # the foot in the plane: inside the triangle?
    c = [np.dot(np.cross(t[(i + 1) % 3] - t[i], q - t[i]), n) for i in range(3)]
    if min(c) >= 0:
        d = min(d, abs(np.dot(p - t[0], n)))
    return d


def _segment_distance(a, b, p):
    e = b - a
    s = np.clip(np.dot(p - a, e) / np.dot(e, e), 0, 1)
    return np.linalg.norm(a + s * e - p)


def _remainders(t, c, rb, rng, n=400):
    """Largest sampled ``|w(x) - w(c) - grad w(c) . (x - c)|`` over the ball of radius rb about c,
    with the kernel's value and gradient at c and the NumPy solid angle at x."""
    val, grad, face, edges = KERNEL.triangle_bounds(t.reshape(9).copy(), c.copy(), rb)
    h = rng.normal(size=(n, 3))
    h /= np.linalg.norm(h, axis=1)[:, None]
    # Most points near the sphere, where the error peaks.
    h *= rb * rng.uniform(0, 1, n)[:, None] ** (1 / 6)
    h[:3] = rb * np.eye(3)
    x = c + h
    w = captree.triangle_angles(np.repeat(t[None], n, axis=0), x)
    return np.abs(w - val - h @ np.asarray(grad)).max(), face, edges


@needs_kernel
@settings(max_examples=300, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), share=st.floats(0.02, 0.98),
       near=st.sampled_from(["face", "edge", "corner", "anywhere"]))
def test_both_bounds_hold_in_the_ball(seed, share, near):
    # A random triangle, a centre near its face, an edge, a corner or
    # anywhere, and a ball reaching ``share`` of the way to the triangle:
    # the linear field errs by no more than either bound at any sampled point.
    rng = np.random.default_rng(seed)
    t = rng.uniform(-1, 1, (3, 3))
    if np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) < 1e-3:
        return
    if near == "face":
        b = rng.dirichlet(np.ones(3))
        n = np.cross(t[1] - t[0], t[2] - t[0])
        c = b @ t + rng.uniform(-0.3, 0.3) * n / np.linalg.norm(n)
    elif near == "edge":
        i = rng.integers(3)
        c = t[i] + rng.uniform(-0.2, 1.2) * (t[(i + 1) % 3] - t[i]) + rng.normal(scale=0.2, size=3)
    elif near == "corner":
        c = t[rng.integers(3)] + rng.normal(scale=0.1, size=3)
    else:
        c = rng.uniform(-2, 2, 3)
    g0 = _tri_distance(t, c)
    if g0 < 1e-6:
        return
    rb = share * g0
    worst, face, edges = _remainders(t, c, rb, rng)
    assert worst <= edges * (1 + 1e-9) + 1e-13
    assert worst <= face * (1 + 1e-9) + 1e-13


@needs_kernel
def test_the_edges_bound_is_tight_enough_to_matter():
    # Beside the middle of a long edge (a half-plane's solid angle, twice the
    # angle about the edge: its Hessian has norm 2 / D^2 there, against the
    # bound's 3 / D^2), a small ball's error is about two thirds of the bound:
    # a constant 0.6 times as large fails the first inequality, one twice as
    # large the second.
    rng = np.random.default_rng(1)
    t = np.array([[-10.0, 0, 0], [10.0, 0, 0], [0, 10.0, 0]])
    worst, face, edges = _remainders(t, np.array([0.0, -1.0, 0.0]), 0.05, rng, n=4000)
    assert worst <= edges < 2 * worst


@needs_kernel
@pytest.mark.parametrize("height", [0.01, 0.02, 0.05, 0.1, 0.2])
@pytest.mark.parametrize("share", [0.3, 0.6, 0.9])
def test_over_a_big_triangle_the_edges_bound_is_the_lesser(height, share):
    # A brick over the interior of a triangle (its edges 0.3 away): the
    # face's bound depends only on the ratio of the brick to its distance
    # from the face, the edges' falls with the brick's size over the
    # edges' distance, so the lower the brick the larger the gain.
    t = np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    c = np.array([0.3, 0.3, height])
    _, _, face, edges = KERNEL.triangle_bounds(t.reshape(9), c, share * height)
    assert edges < face / 8
    assert edges < 0.25 * (height / 0.2) ** 2  # quadratic in the brick's size


@needs_kernel
def test_a_ball_that_meets_the_triangle_is_refused():
    t = np.array([0.0, 0, 0, 1, 0, 0, 0, 1, 0])
    with pytest.raises(ValueError, match="meets the triangle"):
        KERNEL.triangle_bounds(t, np.array([0.3, 0.3, 0.1]), 0.1)


def soup(n=40, seed=3):
    """``n`` big triangles, unconnected, criss-crossing the unit cube (as trimesh's soup.stl):
    each is its own open part and its own cap."""
    rng = np.random.default_rng(seed)
    tris = []
    while len(tris) < n:
        t = rng.uniform(0, 1, (3, 3))
        e = np.linalg.norm(t - np.roll(t, 1, axis=0), axis=1)
        if e.min() > 0.3 and np.linalg.norm(np.cross(t[1] - t[0], t[2] - t[0])) > 0.1:
            tris.append(t)
    V = np.concatenate(tris)
    return geovox.Mesh(V, np.arange(3 * n).reshape(n, 3), source="soup")


SOUP = soup()
RES = 32
#: Voxels the compiled first pass (``COMPILED_PASSES[0]``) leaves undecided on
#: SOUP at RES. With the face's bound alone (``single_bound``, as before the
#: edges' bound) it left 17,756 of the 32,768.
SOUP_REFINED = 4359


@pytest.fixture(scope="module")
def soup_reference():
    grid = geovox.voxelize(SOUP, resolution=RES, inside="parity").grid
    return grid, brute_winding_number(inside.target(SOUP)[0], grid)


def _winding(monkeypatch, kernel, **kw):
    monkeypatch.setenv("GEOVOX_KERNEL", kernel)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        return geovox.voxelize(SOUP, resolution=RES, inside="winding", **kw)


def test_the_soup_is_its_own_caps():
    assert len(inside.boundary_edges(SOUP)) == 3 * len(SOUP.faces)
    assert len(inside.bridged(inside.target(SOUP)[0])[1]) == len(SOUP.faces)


@needs_kernel
def test_compiled_every_soup_voxel_is_the_brute_force(soup_reference, monkeypatch):
    grid, w = soup_reference
    vol = _winding(monkeypatch, "compiled")
    assert vol.grid.shape == grid.shape
    assert vol.approximate == 0 and captree.STATS["estimated"] == 0
    assert captree.STATS["caps"] == len(SOUP.faces)
    # The brute force is itself a float64 sum: stay clear of ties with 1/2.
    assert np.abs(w - 0.5).min() > 1e-6
    np.testing.assert_array_equal(vol.occupancy, w > 0.5)
    assert captree.STATS["refined"] == SOUP_REFINED


@needs_kernel
def test_compiled_soup_past_its_time_the_proven_voxels_are_the_brute_force(soup_reference,
                                                                          monkeypatch):
    # No time: the first pass's undecided voxels keep their estimates, the
    # others are proven by the bounds (the edges' among them) and must be
    # the brute force's.
    grid, w = soup_reference
    seen = []
    real = winding._estimated
    monkeypatch.setattr(winding, "_estimated", lambda unsure, grid: seen.append(unsure.copy())
                        or real(unsure, grid))
    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    vol = _winding(monkeypatch, "compiled")
    estimated = seen[0]
    assert vol.approximate == np.count_nonzero(estimated) == SOUP_REFINED
    np.testing.assert_array_equal(vol.occupancy[~estimated], (w > 0.5)[~estimated])


def test_numpy_soup_is_the_same_occupancy(soup_reference, monkeypatch):
    grid, w = soup_reference
    vol = _winding(monkeypatch, "numpy")
    assert vol.approximate == 0
    np.testing.assert_array_equal(vol.occupancy, w > 0.5)
