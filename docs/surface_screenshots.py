"""Make docs/surface_truck.png and docs/surface_sheet.png: solid, surface and both, side by side.

Run from the repository root: ``python docs/surface_screenshots.py`` (needs the test extra's
selenium and Debian's chromium + chromium-driver; renders with SwiftShader, no GPU needed).
The truck is tests/data/wild/truck.obj (a real, messy model with thin parts: its cab's
panels, mirrors and wheel arches); the sheet glTF's Mesh_PrimitiveMode_04 sample (one open
square, from the Khronos sample models).
"""

import os
import sys
import tempfile
import warnings

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # this checkout's geovox
import geovox  # noqa: E402
from geovox.view.html import to_html  # noqa: E402

from view_screenshots import browser, shoot  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
MODELS = {"truck": (os.path.join(ROOT, "tests", "data", "wild", "truck.obj"), 128),
          "sheet": (os.path.join(ROOT, "tests", "data", "wild", "Mesh_PrimitiveMode_04.gltf"), 64)}


def panels(driver, name, tmp):
    from PIL import Image, ImageDraw

    path, res = MODELS[name]
    shots = []
    for kind in ("solid", "surface", "both"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            vol = geovox.voxelize(path, resolution=res, occupancy=kind, color=True)
        page = os.path.join(tmp, f"{name}_{kind}.html")
        to_html(vol, page)
        png = os.path.join(tmp, f"{name}_{kind}.png")
        shoot(driver, page, png)
        img = Image.open(png).convert("RGB").crop((0, 40, 490, 560))  # the 3D view, not the panel
        ImageDraw.Draw(img).text((12, 8), f"--occupancy {kind}: {vol.inside_count:,} voxels",
                                 fill=(255, 255, 255), font_size=16)
        shots.append(img)
    w, h = shots[0].size
    out = Image.new("RGB", (3 * w, h))
    for k, img in enumerate(shots):
        out.paste(img, (k * w, 0))
    target = os.path.join(HERE, f"surface_{name}.png")
    out.save(target, optimize=True)
    print("wrote", target)


def main():
    driver = browser(width=800, height=600)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for name in MODELS:
                panels(driver, name, tmp)
    finally:
        driver.quit()


if __name__ == "__main__":
    main()
