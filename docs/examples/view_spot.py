"""The gallery's 3D view: spot voxelised at 128³ with colour, beside its mesh.

    python docs/examples/view_spot.py [OUT.png]         (default: docs/spot_view.png)

The same as ``geovox view data/spot/spot.obj -r 128 --color --mesh data/spot/spot.obj
--screenshot docs/spot_view.png``: PyVista renders off screen (the ``view`` extra, ``pip install
-e '.[view]'``), no display needed.
"""

import os
import sys
from pathlib import Path

import geovox
from geovox.view import show

ROOT = Path(__file__).resolve().parents[2]
#: Relative to the repository root, so that the pictures show this path, not the machine's.
SPOT = "data/spot/spot.obj"


def main(out=ROOT / "docs" / "spot_view.png"):
    out = Path(out).resolve()  # before the chdir: a relative OUT is the caller's
    os.chdir(ROOT)
    spot = SPOT
    vol = geovox.voxelize(spot, resolution=128, color=True)
    show(vol, mesh=geovox.load_mesh(spot), screenshot=str(out))
    print("wrote", out)


if __name__ == "__main__":
    main(*sys.argv[1:])
