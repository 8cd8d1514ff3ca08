"""Names the readers give parts, as trimesh gives them (so ``--labels part`` keeps its names)."""

from __future__ import annotations

__all__ = ["unique_name"]


def unique_name(start, taken, counts=None) -> str:
    """trimesh's ``util.unique_name`` (5.2): ``start``, else ``start_1``, ``start_2``, ...

    ``counts`` remembers the last number given per start, as trimesh's
    glTF reader keeps it; the parts' names are trimesh's.
    """
    if start and start not in taken:
        return start
    increment = 0 if counts is None else counts.get(start, 0)
    formatter = "geometry_{}"
    if start:
        formatter = start + "_{}"
        split = start.rsplit("_", 1)
        if len(split) == 2 and increment == 0:
            try:
                increment, formatter = int(split[1]), split[0] + "_{}"
            except ValueError:
                pass
    for i in range(increment + 1, 2 + increment + len(taken)):
        if formatter.format(i) not in taken:
            if counts is not None:
                counts[start] = i
            return formatter.format(i)
    raise AssertionError("unreachable: more candidates than names taken")
