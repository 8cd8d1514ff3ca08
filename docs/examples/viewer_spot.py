"""The HTML viewer page embedded in the documentation: spot at 128³ with colour.

    python docs/examples/viewer_spot.py [OUT.html]      (default: docs/viewer/spot.html)

Runs the two commands a user runs, with this checkout's geovox::

    python -m geovox convert data/spot/spot.obj -o /tmp/spot_128x128x128_uint8.raw -r 128 --color
    python -m geovox view /tmp/spot_128x128x128_uint8.json --html docs/viewer/spot.html

so the page is written from the volume as read back from the files, as a user's own is. The
same paths give the same page byte for byte (the page names its source, here the ``/tmp`` path).
"""

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
VOLUME = "/tmp/spot_128x128x128_uint8"


def geovox(*args):
    subprocess.run([sys.executable, "-m", "geovox", *args], cwd=ROOT, check=True)


def main(out=ROOT / "docs" / "viewer" / "spot.html"):
    out = Path(out).resolve()
    geovox("convert", "data/spot/spot.obj", "-o", VOLUME + ".raw", "-r", "128", "--color")
    geovox("view", VOLUME + ".json", "--html", str(out))


if __name__ == "__main__":
    main(*sys.argv[1:2])
