"""The backend interface: column rays in, every crossing out."""

from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from ..grid import Columns


@dataclass
class Hits:
    """Every crossing of a lattice of column rays with a mesh.

    Attributes
    ----------
    ray : (m,) int64
        Ray index ``i + nu * j`` (see :class:`geovox.grid.Columns`).
    depth : (m,) float64
        Distance of the crossing along the ray from the plane
        ``axis = columns.w0`` (the grid's low face; the coordinate is
        ``columns.w0 + depth``).
    triangle : (m,) int64
        Index of the crossed triangle in the mesh's face array.
    bary : (m, 2) float64
        Barycentric weights ``(u, v)`` of the triangle's vertices 1 and 2 at
        the crossing (vertex 0 has ``1 - u - v``).
    ordered : bool
        Known to be in ray-then-depth order already (see :meth:`sorted`).

    Hits come in no particular order (sorting a million hits costs more
    than the parity fill, which does not need it); call :meth:`sorted` for
    ray-then-depth order.
    """

    ray: np.ndarray
    depth: np.ndarray
    triangle: np.ndarray
    bary: np.ndarray
    ordered: bool = False

    def __len__(self) -> int:
        return len(self.ray)

    @classmethod
    def concatenate(cls, parts) -> "Hits":
        """One Hits holding every crossing of ``parts`` (an iterable of Hits), in their order."""
        parts = list(parts)
        if not parts:
            return cls.empty()
        return cls(
            ray=np.concatenate([p.ray for p in parts]),
            depth=np.concatenate([p.depth for p in parts]),
            triangle=np.concatenate([p.triangle for p in parts]),
            bary=np.concatenate([p.bary for p in parts]),
        )

    def take(self, index) -> "Hits":
        """The hits selected by a boolean mask or index array."""
        return Hits(self.ray[index], self.depth[index], self.triangle[index], self.bary[index])

    @classmethod
    def empty(cls) -> "Hits":
        """No crossings: arrays of length 0 with the dtypes and shapes above."""
        return cls(
            ray=np.zeros(0, np.int64),
            depth=np.zeros(0, np.float64),
            triangle=np.zeros(0, np.int64),
            bary=np.zeros((0, 2), np.float64),
        )

    def sorted(self) -> "Hits":
        """The hits ordered by ray, then depth, then triangle (deterministic on ties)."""
        if self.ordered:
            return self
        out = self.take(np.lexsort((self.triangle, self.depth, self.ray)))
        out.ordered = True
        return out


class Backend(abc.ABC):
    """A ray-casting engine.

    A backend has one job: for a lattice of axis-parallel column rays, report
    every crossing with the mesh. It finds candidate (ray, triangle) pairs its
    own way and must settle each one with :class:`geovox.exact.Projection`,
    the shared numeric contract, so that all backends agree exactly.
    """

    #: Registry name.
    name: str = ""

    @abc.abstractmethod
    def cast(self, mesh, columns: Columns, jobs: int = 1) -> Hits:
        """Return every crossing of the column rays with ``mesh``.

        Parameters
        ----------
        mesh : geovox.mesh.Mesh
            The triangles: ``mesh.triangles`` is (m, 3, 3) float64.
        columns : Columns
            The lattice of rays, all along ``+columns.axis``.
        jobs : int
            Threads the backend may use; the hits must not depend on it.

        Returns
        -------
        Hits
            Each crossing once, in any order, each (ray, triangle) pair
            decided by :class:`geovox.exact.Projection`.

        Raises
        ------
        BackendUnavailableError
            The engine cannot run (a device lost, out of device memory); the
            message names ``--backend numpy`` as the way on.
        """
