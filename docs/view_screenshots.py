"""Make docs/view_spot.png, docs/view_spot_clipped.png and docs/view_labels.png.

Run from the repository root: ``python docs/view_screenshots.py`` (needs the test extra's
selenium and Debian's chromium + chromium-driver; renders with SwiftShader, no GPU needed).
"""

import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))  # this checkout's geovox
import geovox
from geovox.view.html import to_html

FLAGS = ("--headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
         "--disable-background-networking --disable-component-update --disable-sync "
         "--use-angle=swiftshader --enable-unsafe-swiftshader --hide-scrollbars").split()


def browser(width=1280, height=800):
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in FLAGS + [f"--user-data-dir={tempfile.mkdtemp()}", f"--window-size={width},{height}"]:
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride",
                           {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False})
    return driver


def shoot(driver, page, png, *scripts):
    driver.get("file://" + os.path.abspath(page))
    while not driver.execute_script("return document.body.dataset.rendered || document.body.dataset.error"):
        time.sleep(0.2)
    assert not driver.execute_script("return document.body.dataset.error"), png
    for js in scripts:
        driver.execute_script(js)
        driver.execute_script("window.geovoxViewer.snapshot()")  # draws now
    driver.save_screenshot(png)
    print("wrote", png)


def spot_labels(vol):
    """Spot's parts as labels, by position (y up, the head towards -z)."""
    _, y, z = np.meshgrid(*(vol.grid.centres(a) for a in range(3)), indexing="ij")
    labels = np.where(vol.occupancy, 2, 0).astype(np.uint8)  # body
    labels[vol.occupancy & (z < -0.1) & (y > -0.3)] = 1  # head
    labels[vol.occupancy & (y < -0.38)] = 3  # legs
    labels[vol.occupancy & (y > 0.72)] = 4  # horns
    vol.labels = np.asfortranarray(labels)
    vol.label_table = [{"value": 1, "name": "head", "color": [236, 178, 76, 255]},
                       {"value": 2, "name": "body", "color": [120, 170, 235, 255]},
                       {"value": 3, "name": "legs", "color": [120, 200, 120, 255]},
                       {"value": 4, "name": "horns", "color": [220, 90, 90, 255]}]
    return vol


def main(out="docs"):
    tmp = tempfile.mkdtemp()
    vol = geovox.voxelize("data/spot/spot.obj", resolution=128, color=True)
    vol.source = "spot_128x128x128_uint8.json"
    page = to_html(vol, os.path.join(tmp, "spot.html"))
    driver = browser()
    try:
        shoot(driver, page, os.path.join(out, "view_spot.png"))
        shoot(driver, page, os.path.join(out, "view_spot_clipped.png"),
              "window.geovoxViewer.setClip([0.5, 0, 0.3], [1, 1, 1])",
              "window.geovoxViewer.setCamera({yaw: -2.2, pitch: 0.45})",
              "window.geovoxViewer.setSlice(0, 64)")
        labelled = spot_labels(geovox.voxelize("data/spot/spot.obj", resolution=128))
        page = to_html(labelled, os.path.join(tmp, "labels.html"), source="spot_parts (labels)")
        shoot(driver, page, os.path.join(out, "view_labels.png"),
              "window.geovoxViewer.toggleLabel(2, false)",
              "window.geovoxViewer.setCamera({yaw: -2.3})")
    finally:
        driver.quit()


if __name__ == "__main__":
    main(*sys.argv[1:])
