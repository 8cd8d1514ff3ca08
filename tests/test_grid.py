"""Grid construction: resolution, shape, voxel_size, bounds and their errors."""

from __future__ import annotations

import numpy as np
import pytest

import geovox
from geovox.errors import ParameterError
from geovox.grid import DEFAULT_RESOLUTION, make_grid

from conftest import SPOT

MB = np.array([[0.0, 0.0, 0.0], [2.0, 1.0, 4.0]])


def test_resolution_is_n_on_every_axis():
    g = make_grid(MB, resolution=10)
    assert g.shape == (10, 10, 10)
    np.testing.assert_allclose(g.spacing, [0.2, 0.1, 0.4])
    np.testing.assert_allclose(g.centres(0)[[0, -1]], [0.1, 1.9])


def test_default_resolution():
    assert make_grid(MB).shape == (DEFAULT_RESOLUTION,) * 3


def test_shape():
    g = make_grid(MB, shape=(4, 5, 6))
    assert g.shape == (4, 5, 6)
    np.testing.assert_allclose(g.lo, MB[0])
    np.testing.assert_allclose(g.hi, MB[1])


def test_voxel_size_grows_region_symmetrically():
    g = make_grid(MB, voxel_size=0.3)
    assert g.shape == (7, 4, 14)
    np.testing.assert_allclose(g.spacing, 0.3)
    np.testing.assert_allclose((g.lo + g.hi) / 2, MB.mean(axis=0))


def test_voxel_size_exact_fit_adds_nothing():
    g = make_grid(MB, voxel_size=0.5)
    assert g.shape == (4, 2, 8)
    np.testing.assert_allclose(g.lo, MB[0])


def test_bounds_override_mesh_box():
    g = make_grid(MB, bounds=(-1, -1, -1, 1, 1, 1), resolution=4)
    np.testing.assert_allclose(g.lo, -1)
    np.testing.assert_allclose(g.spacing, 0.5)


def test_flat_mesh_gets_a_thin_slab():
    g = make_grid(np.array([[0, 0, 0], [1, 1, 0.0]]), resolution=4)
    assert np.all(g.spacing > 0)


@pytest.mark.parametrize("kwargs,match", [
    ({"resolution": 0}, r"`resolution` must be a positive integer, got 0"),
    ({"resolution": -3}, r"`resolution` must be a positive integer, got -3"),
    ({"resolution": 2.5}, r"`resolution` must be a positive integer, got 2.5"),
    ({"resolution": "abc"}, r"`resolution` must be a positive integer, got 'abc'"),
    ({"resolution": True}, r"`resolution` must be a positive integer"),
    ({"shape": (1, 2)}, r"`shape` must be three positive integers"),
    ({"shape": (1, 0, 2)}, r"`shape` must be a positive integer, got 0"),
    ({"voxel_size": 0}, r"`voxel_size` must be a positive number"),
    ({"voxel_size": float("nan")}, r"`voxel_size` must be a positive number"),
    ({"resolution": 4, "shape": (1, 2, 3)}, r"only one of"),
    ({"bounds": (0, 0, 0, 0, 1, 1)}, r"min < max.*x"),
    ({"bounds": (0, 0, 0, 1, 1)}, r"6 numbers"),
    ({"bounds": (0, 0, 0, 1, 1, float("inf"))}, r"finite"),
    ({"bounds": "nope"}, r"6 numbers"),
])
def test_bad_parameters_name_parameter_and_value(kwargs, match):
    with pytest.raises(ParameterError, match=match) as info:
        make_grid(MB, **kwargs)
    assert isinstance(info.value, ValueError)


def test_volume_reports_grid_facts():
    vol = geovox.voxelize(SPOT, shape=(10, 20, 30), backend="numpy")
    assert vol.shape == (10, 20, 30)
    assert vol.occupancy.shape == (10, 20, 30)
    assert vol.occupancy.flags.f_contiguous
    assert vol.occupancy.dtype == bool
    lo, hi = vol.bounds
    np.testing.assert_allclose(np.subtract(hi, lo) / (10, 20, 30), vol.spacing)
    assert vol.backend == "numpy"


@pytest.mark.parametrize("axis", [1, 2])
def test_word_wise_parity_fill_equals_voxel_by_voxel(axis):
    # With x a multiple of 8 the fill XORs eight voxels at a time; the
    # running XOR voxel by voxel must give the same volume.
    from geovox.backends.base import Hits
    from geovox.parallel import scan_along
    from geovox.parity import fill, toggle_indices

    rng = np.random.default_rng(axis)
    grid = make_grid(np.array([[0, 0, 0], [1, 1, 1.0]]), shape=(24, 9, 13))
    columns = grid.columns(axis)
    n = 3000
    hits = Hits(ray=rng.integers(0, columns.count, n), depth=rng.random(n) * 1.2 - 0.1,
                triangle=np.zeros(n, np.int64), bary=np.zeros((n, 2)))
    got = fill(hits, columns, grid, jobs=2)
    want = np.zeros(grid.shape, dtype=bool, order="F")
    want.reshape(-1, order="F")[toggle_indices(hits, columns, grid)] = True
    scan_along(np.logical_xor, want, axis, 1)
    assert want.any() and not want.all()
    np.testing.assert_array_equal(got, want)
