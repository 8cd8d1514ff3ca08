"""Inside/outside tests: the automatic choice, parity, vote and winding, repair.

The modules, top to bottom; each imports only modules below it (counting
imports inside functions; ``tests/test_inside_layout.py`` keeps it so):

| module | holds |
|---|---|
| :mod:`geovox.inside.winding` | the winding number: signed crossings, the caps' correction, ties |
| :mod:`geovox.inside.choice` | ``choose`` (the inside test to run), ``target`` (the mesh it runs on) and the memory check |
| :mod:`geovox.inside.caps` | the caps over an open mesh's holes, and the mesh they close |
| :mod:`geovox.inside.bridge` | minimum-area triangulations of the holes' loops |
| :mod:`geovox.inside.captree` | the caps' winding number, summed over a tree of them |
| :mod:`geovox.inside.repair` | the repaired copy a winding test of a broken mesh works on |
| :mod:`geovox.inside.edges` | merged positions, the edge table, the holes, components |
"""

from . import bridge, captree, caps, choice, edges, repair, winding
from .caps import bridged, capped
from .captree import cap_winding, solid_angles, winding_kernel
from .choice import METHODS, choose, repair_warning, target
from .edges import (boundary_edges, components, consistent, edge_counts, non_manifold,
                    overlapping_pieces)
from .winding import (approximate_warning, crossing_signs, signed_counts, winding_occupancy,
                      working_bytes)

__all__ = ["METHODS", "approximate_warning", "boundary_edges", "bridge", "bridged", "cap_winding",
           "capped", "captree", "caps", "choice", "choose", "components", "consistent",
           "crossing_signs", "edge_counts", "edges", "non_manifold", "overlapping_pieces", "repair",
           "repair_warning", "signed_counts", "solid_angles", "target", "winding",
           "winding_kernel", "winding_occupancy", "working_bytes"]
