"""The gallery's spot cut in half by ``--bounds``: exact colour against fast colour.

    python docs/examples/cut_spot.py [OUT_FOLDER]       (default: docs/)

Writes ``spot_cut_exact.png`` and ``spot_cut_fast.png``, as
``geovox preview data/spot/spot.obj -r 128 --bounds -0.471552 -0.736784 -0.668909 0 0.953646
1.049 --color -o docs/spot_cut_exact.png`` (and ``--fast-color``) do. The region runs from spot's
left edge to x = 0, so the composite along x shows the cut face: with exact colour each inside
voxel has its nearest surface point's colour; with fast colour, axis-aligned stripes appear
deeper in, where the six crossings miss the nearest triangle.
"""

import os
import sys
from pathlib import Path

import geovox
from geovox.preview import write_preview

ROOT = Path(__file__).resolve().parents[2]
#: Relative to the repository root, so that the pictures show this path, not the machine's.
SPOT = "data/spot/spot.obj"
BOUNDS = (-0.471552, -0.736784, -0.668909, 0.0, 0.953646, 1.049)


def main(folder=ROOT / "docs"):
    folder = Path(folder).resolve()
    os.chdir(ROOT)
    for name, color in (("exact", True), ("fast", "fast")):
        vol = geovox.voxelize(SPOT, resolution=128, bounds=BOUNDS,
                              color=color)
        print("wrote", write_preview(vol, folder / f"spot_cut_{name}.png"))


if __name__ == "__main__":
    main(*sys.argv[1:])
