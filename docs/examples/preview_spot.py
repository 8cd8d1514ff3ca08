"""The gallery's preview of spot: composites along x, y, z and the middle slices.

    python docs/examples/preview_spot.py [OUT.png]      (default: docs/spot_preview.png)

The same picture as ``geovox preview data/spot/spot.obj -r 128 --color -o docs/spot_preview.png``:
spot voxelised at 128³ with exact colour, drawn with NumPy and Pillow alone (no display needed).
"""

import os
import sys
from pathlib import Path

import geovox
from geovox.preview import write_preview

ROOT = Path(__file__).resolve().parents[2]
#: Relative to the repository root, so that the pictures show this path, not the machine's.
SPOT = "data/spot/spot.obj"


def main(out=ROOT / "docs" / "spot_preview.png"):
    out = Path(out).resolve()  # before the chdir: a relative OUT is the caller's
    os.chdir(ROOT)
    vol = geovox.voxelize(SPOT, resolution=128, color=True)
    print("wrote", write_preview(vol, out))


if __name__ == "__main__":
    main(*sys.argv[1:])
