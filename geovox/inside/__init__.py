"""Inside/outside tests: the automatic choice, parity, vote and winding, repair.

| module | holds |
|---|---|
| :mod:`geovox.inside.winding` | ``choose``, the winding number, the caps and their tree |
| :mod:`geovox.inside.repair` | the repaired copy a winding test of a broken mesh works on |
| :mod:`geovox.inside.bridge` | caps that bridge the holes of open loops |
"""

from . import bridge, repair, winding
from .winding import (
    PASSES,
    STATS,
    approximate_warning,
    boundary_edges,
    bridged,
    cap_winding,
    capped,
    choose,
    consistent,
    crossing_signs,
    edge_counts,
    overlapping_pieces,
    settle_ties,
    solid_angles,
    target,
    winding_kernel,
    winding_occupancy,
    working_bytes,
)

__all__ = [
    "PASSES", "STATS", "approximate_warning", "boundary_edges", "bridge", "bridged", "cap_winding",
    "capped", "choose", "consistent", "crossing_signs", "edge_counts", "overlapping_pieces",
    "repair", "settle_ties", "solid_angles", "target", "winding", "winding_kernel",
    "winding_occupancy", "working_bytes",
]
