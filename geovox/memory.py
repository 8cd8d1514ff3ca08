"""Memory budgeting: what a conversion needs, what the machine has, and refusing early.

Its own module so that the pipeline, the slab streamer, the inside tests and
the command line share one rule without importing each other.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .errors import GridTooLargeError, MeshTooLargeError

if TYPE_CHECKING:  # the type alone: the command line's --help imports this, without NumPy
    from .grid import Grid

#: Refuse grids whose occupancy array alone would exceed this fraction of RAM.
MEMORY_FRACTION = 0.8


def available_memory() -> int | None:
    """Bytes of memory available now (``MemAvailable``), or None where unknown."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def bytes_per_voxel(options) -> float:
    """Working memory per voxel of one conversion (occupancy and what ``options`` ask for).

    Occupancy is 1 byte a voxel, and the surface voxels (``occupancy``
    ``"surface"`` or ``"both"``) 1 more; colour adds 4 for RGBA and about 16
    of working arrays while nearest crossings are found; density and distance
    4 each plus a float32 working copy.
    """
    from .options import colour_of

    return (1.0 + (1.0 if getattr(options, "occupancy", "solid") != "solid" else 0.0)
            + (20.0 if colour_of(options.color) else 0.0)
            + (8.0 if options.density else 0.0) + (8.0 if options.sdf else 0.0))


def check_memory(grid: Grid, bytes_per_voxel: float = 1.0) -> None:
    """Refuse, before allocating, a grid that cannot fit in memory.

    Raises
    ------
    GridTooLargeError
        ``grid.size * bytes_per_voxel`` exceeds ``MEMORY_FRACTION`` of the
        available memory.
    """
    need = grid.size * bytes_per_voxel
    avail = available_memory()
    if avail is not None and need > MEMORY_FRACTION * avail:
        nx, ny, nz = grid.shape
        raise GridTooLargeError(
            f"a {nx} x {ny} x {nz} grid needs {need / 2**30:.1f} GiB but only "
            f"{avail / 2**30:.1f} GiB of memory is available; use a smaller resolution, or "
            f"write it slab by slab to .h5 or .raw (geovox convert does; in Python, "
            f"geovox.convert_to)"
        )


def check_mesh_memory(need: float, what: str, instead: str) -> None:
    """Refuse, before the work, a step on the mesh whose working memory would not fit.

    Parameters
    ----------
    need : float
        Bytes the step needs beside what is allocated already (the mesh).
    what : str
        The step and its mesh, e.g. ``"bunny.stl: the winding number of a
        repaired copy (25,600,000 triangles, 3,900,000 open edges)"``.
    instead : str
        What the user can do instead.

    Raises
    ------
    MeshTooLargeError
        ``need`` exceeds ``MEMORY_FRACTION`` of the available memory.
    """
    avail = available_memory()
    if avail is not None and need > MEMORY_FRACTION * avail:
        raise MeshTooLargeError(
            f"{what} needs about {need / 2**30:.1f} GiB of working memory but only "
            f"{avail / 2**30:.1f} GiB is available; {instead}")
