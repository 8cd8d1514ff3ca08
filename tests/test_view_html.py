"""geovox view --html: the self-contained page, its embedded data, and what Chromium shows."""

from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zlib

import numpy as np
import pytest

from geovox.cli import main
from geovox.errors import OutputError, ParameterError
from geovox.grid import Grid
from geovox.view import html as H
from geovox.volume import Volume

SPOT = os.path.join(os.path.dirname(__file__), "..", "data", "spot", "spot.obj")


# ---- fixtures: volumes built from analytic shapes ------------------------------------------------

def _volume(occ, colors=None, lo=(0.0, 0.0, 0.0), hi=None, **extra):
    occ = np.asfortranarray(occ)
    hi = hi or tuple(float(n) for n in occ.shape)
    vol = Volume(occupancy=occ, grid=Grid(np.asarray(lo, float), np.asarray(hi, float), occ.shape),
                 backend="numpy", source="fixture", colors=colors)
    for name, value in extra.items():
        setattr(vol, name, value)
    return vol


def _centred(n):
    c = (np.arange(n) + 0.5) / n - 0.5
    return np.meshgrid(c, c, c, indexing="ij")


def two_material_box(n=32):
    """A box filling the middle of the grid: red where x < 0, blue where x >= 0."""
    x, y, z = _centred(n)
    occ = (abs(x) < 0.4) & (abs(y) < 0.3) & (abs(z) < 0.3)
    colors = np.zeros((n, n, n, 4), np.uint8)
    colors[occ & (x < 0)] = (220, 30, 30, 255)
    colors[occ & (x >= 0)] = (30, 60, 230, 255)
    return _volume(occ, colors)


def layered_sphere(n=40):
    """A sphere, white within a voxel of its surface and green deeper inside."""
    x, y, z = _centred(n)
    r = np.sqrt(x * x + y * y + z * z)
    occ = r < 0.45
    colors = np.zeros((n, n, n, 4), np.uint8)
    colors[occ] = (235, 235, 235, 255)
    colors[r < 0.38] = (30, 200, 40, 255)
    return _volume(occ, colors)


TABLE = [{"value": 1, "name": "left ball", "color": [230, 40, 40, 255]},
         {"value": 2, "name": "right ball", "color": [40, 210, 60, 255]},
         {"value": 300, "name": "floor", "color": [70, 110, 240, 255]}]


def labelled_scene(n=48, dtype=np.uint16):
    """Two balls and a floor slab with labels 1, 2 and 300 (uint16), 0 around them."""
    x, y, z = _centred(n)
    labels = np.zeros((n, n, n), dtype)
    labels[(x + 0.2) ** 2 + y ** 2 + z ** 2 < 0.18 ** 2] = 1
    labels[(x - 0.2) ** 2 + y ** 2 + z ** 2 < 0.18 ** 2] = 2
    labels[(y < -0.3) & (y > -0.4) & (abs(x) < 0.45) & (abs(z) < 0.45)] = 300
    return _volume(labels > 0, labels=np.asfortranarray(labels), label_table=TABLE)


# ---- a decoder of the page, written from the module's docstring, independent of the viewer ------

def decode_page(text):
    """``(meta, {name: array})`` from a page's embedded blocks."""
    meta = json.loads(re.search(r'<script type="application/json" id="geovox-meta">(.*?)</script>',
                                text, re.DOTALL).group(1))
    shape = tuple(meta["shape"])
    out = {}
    for name, info in meta["fields"].items():
        b64 = re.search(rf'<script type="application/octet-stream" id="geovox-field-{name}">'
                        rf'([A-Za-z0-9+/=]*)</script>', text).group(1)
        raw = zlib.decompress(base64.b64decode(b64))
        n = int(np.prod(shape))
        if info["dtype"] == "bits":
            flat = np.unpackbits(np.frombuffer(raw, np.uint8), bitorder="little")[:n].astype(bool)
        else:
            flat = np.frombuffer(raw, np.dtype(info["dtype"]).newbyteorder("<"))
        if name == "colors":
            out[name] = flat.reshape(shape[::-1] + (4,)).transpose(2, 1, 0, 3)
        else:
            out[name] = flat.reshape(shape, order="F")
    return meta, out


# ---- Python: the page ----------------------------------------------------------------------------

def full_volume(n=12):
    rng = np.random.default_rng(5)
    occ = rng.random((n, n + 1, n + 2)) < 0.4
    colors = rng.integers(0, 256, occ.shape + (4,), dtype=np.uint8)
    labels = rng.integers(0, 700, occ.shape).astype(np.uint16)
    vol = _volume(occ, colors, lo=(-1.5, 2.0, 0.25), hi=(1.5, 5.0, 0.75),
                  labels=labels, label_table=TABLE)
    vol.density = rng.random(occ.shape).astype(np.float32)
    vol.sdf = (rng.standard_normal(occ.shape) * 0.1).astype(np.float32)
    return vol


def test_page_holds_no_external_url(tmp_path):
    text = H.render_page(full_volume())
    for pattern in (r"""(?:src|href)\s*=\s*["']?\s*(?!#)[a-z]*:?//""",
                    r"""url\(\s*["']?\s*[a-z]*:?//""", r"""\bimport\s*\(|\bimport\s+[^;]*\bfrom\b""",
                    r"""\bfetch\s*\(""", r"""https?:|wss?:|ftp:"""):
        assert not re.search(pattern, text, re.IGNORECASE), pattern
    assert not re.search(r"""\b(?:src|href)\s*=""", text), "nothing is loaded by reference"
    # The viewer really is inlined, not referenced.
    assert "geovoxViewer" in text and "#version 300 es" in text and "gv-canvas" in text
    # What goes into the page is text there, markers and tags included.
    odd = H.render_page(two_material_box(4), title="a /*@@CSS@@*/ <script>", source="</script>")
    assert odd.count("#gv-main {") == 1  # the style sheet went in once, where it belongs
    assert "a /*@@CSS@@*/ &lt;script&gt; - geovox" in odd and odd.count("</script>") == text.count(
        "</script>") - 3


def test_embedded_data_decodes_to_exactly_the_arrays():
    vol = full_volume()
    meta, fields = decode_page(H.render_page(vol))
    assert meta["factor"] == 1 and meta["shape"] == list(vol.shape)
    np.testing.assert_array_equal(fields["occupancy"], vol.occupancy)
    np.testing.assert_array_equal(fields["colors"], vol.colors)
    np.testing.assert_array_equal(fields["labels"], vol.labels)
    assert fields["labels"].dtype == np.uint16
    np.testing.assert_array_equal(fields["density"], vol.density)
    np.testing.assert_array_equal(fields["sdf"], vol.sdf)
    assert meta["inside_count"] == vol.inside_count
    assert meta["bounds"] == [list(vol.bounds[0]), list(vol.bounds[1])]
    assert [e["value"] for e in meta["label_table"]] == [1, 2, 300]
    np.testing.assert_allclose(meta["spacing"], vol.spacing)


def test_downsampling_keeps_max_alpha_weighted_and_nearest():
    vol = full_volume(10)  # 10 x 11 x 12 at most 4 a side: factor 3, shown 4 x 4 x 4
    meta, fields = decode_page(H.render_page(vol, max_side=4))
    f = 3
    assert meta["factor"] == f and meta["shape"] == [4, 4, 4]
    assert meta["original_shape"] == [10, 11, 12] and meta["inside_count"] == vol.inside_count
    assert meta["rules"]["occupancy"] == "max" and meta["rules"]["labels"] == "nearest"
    np.testing.assert_allclose(meta["shown_spacing"], np.asarray(vol.spacing) * f)
    for i, j, k in np.ndindex(4, 4, 4):
        block = (slice(i * f, i * f + f), slice(j * f, j * f + f), slice(k * f, k * f + f))
        assert fields["occupancy"][i, j, k] == vol.occupancy[block].any()
        near = tuple(min(a * f + f // 2, n - 1) for a, n in zip((i, j, k), vol.shape))
        assert fields["labels"][i, j, k] == vol.labels[near]
        assert fields["sdf"][i, j, k] == vol.sdf[near]
        c = vol.colors[block].reshape(-1, 4).astype(float)
        want_rgb = (c[:, :3] * c[:, 3:]).sum(0) / max(c[:, 3].sum(), 1)
        np.testing.assert_allclose(fields["colors"][i, j, k, :3], want_rgb, atol=0.5 + 1e-9)
        assert abs(int(fields["colors"][i, j, k, 3]) - c[:, 3].mean()) <= 0.5 + 1e-9
    # Thin things stay: one inside voxel makes its block inside.
    one = np.zeros((9, 9, 9), bool)
    one[4, 4, 4] = True
    assert H.downsample("occupancy", one, 3).sum() == 1
    # A colour next to empty (alpha 0) voxels is not darkened by them.
    col = np.zeros((2, 2, 2, 4), np.uint8)
    col[0, 0, 0] = (200, 100, 50, 255)
    np.testing.assert_array_equal(H.downsample("colors", col, 2)[0, 0, 0], (200, 100, 50, 32))


def test_spot_128_with_colour_is_at_most_4_mb(tmp_path):
    import geovox

    vol = geovox.voxelize(SPOT, resolution=128, color=True)
    path = H.to_html(vol, tmp_path / "spot.html")
    assert os.path.getsize(path) <= 4_000_000
    with open(path, encoding="utf-8") as fh:
        meta, fields = decode_page(fh.read())
    np.testing.assert_array_equal(fields["occupancy"], vol.occupancy)
    np.testing.assert_array_equal(fields["colors"], vol.colors)
    assert meta["source"] == "spot.obj"


def test_bad_labels_and_max_side_name_the_parameter(tmp_path):
    vol = two_material_box(8)
    for bad, words in ((dict(labels=np.zeros((8, 8, 8), np.int32)), "`labels`"),
                       (dict(labels=np.zeros((8, 8, 8), np.uint8),
                             label_table=[{"value": 1, "color": [1, 2]}]), "`label_table[0]`"),
                       (dict(labels=np.zeros((8, 8, 8), np.uint8),
                             label_table=[{"name": "x"}]), "`label_table[0]`")):
        v = _volume(vol.occupancy, **bad)
        with pytest.raises(ParameterError, match=re.escape(words)):
            H.to_html(v, tmp_path / "x.html")
    with pytest.raises(ParameterError, match="`max_side`"):
        H.to_html(vol, tmp_path / "x.html", max_side=0)
    with pytest.raises(OutputError, match="does not exist"):
        H.to_html(vol, tmp_path / "no" / "x.html")
    assert os.listdir(tmp_path) == []


def test_cli_reads_the_readme_sidecar_and_other_formats(tmp_path, capsys):
    """`geovox view spot_NxNxN_uint8.json --html spot.html` after the README's convert."""
    from geovox import formats

    raw = tmp_path / "spot_32x32x32_uint8.raw"
    assert main(["convert", SPOT, "-o", str(raw), "-r", "32", "--color", "-q"]) == 0
    want = formats.read(str(raw))
    for src in (tmp_path / "spot_32x32x32_uint8.json", raw):
        out = tmp_path / "spot.html"
        assert main(["view", str(src), "--html", str(out)]) == 0
        assert "wrote" in capsys.readouterr().out
        meta, fields = decode_page(out.read_text(encoding="utf-8"))
        np.testing.assert_array_equal(fields["occupancy"], want.occupancy)
        np.testing.assert_array_equal(fields["colors"], want.colors)
        assert meta["source"] == os.path.basename(src)
    for ext in (".h5", ".npz"):
        formats.write(want, str(tmp_path / f"v{ext}"))
        assert main(["view", str(tmp_path / f"v{ext}"), "--html", str(tmp_path / "v.html")]) == 0
        np.testing.assert_array_equal(
            decode_page((tmp_path / "v.html").read_text(encoding="utf-8"))[1]["occupancy"],
            want.occupancy)
    # A mesh is voxelised first, with the grid options.
    assert main(["view", SPOT, "-r", "20", "--html", str(tmp_path / "m.html")]) == 0
    meta = decode_page((tmp_path / "m.html").read_text(encoding="utf-8"))[0]
    assert max(meta["original_shape"]) == 20 and "colors" not in meta["fields"]
    # --max-side downsamples.
    assert main(["view", str(raw), "--max-side", "16", "--html", str(tmp_path / "d.html")]) == 0
    assert decode_page((tmp_path / "d.html").read_text(encoding="utf-8"))[0]["factor"] == 2


def test_cli_bad_input_one_line_status_2_nothing_left(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("neither a volume nor a mesh\n")
    (tmp_path / "bad.json").write_text("{\"what\": 1}\n")
    (tmp_path / "folder.html").mkdir()
    before = sorted(os.listdir(tmp_path))
    for argv, words in (
            ([str(tmp_path / "notes.txt"), "--html", str(tmp_path / "o.html")], "cannot be read"),
            ([str(tmp_path / "bad.json"), "--html", str(tmp_path / "o.html")], "sidecar"),
            ([str(tmp_path / "missing.obj"), "--html", str(tmp_path / "o.html")], "not found"),
            ([SPOT, "-r", "8", "--html", str(tmp_path / "no" / "o.html")], "does not exist"),
            ([SPOT, "-r", "8", "--html", str(tmp_path / "folder.html")], "is a folder"),
            ([SPOT, "-r", "8", "--html", str(tmp_path / "o.html"), "--mesh", SPOT], "--html"),
            ([SPOT, "-r", "8", "--html", str(tmp_path / "o.html"), "--max-side", "0"],
             "--max-side"),
            ([SPOT, "-r", "8", "--screenshot", str(tmp_path / "o.png"), "--max-side", "64"],
             "--max-side is for --html")):
        assert main(["view", *argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err and "Traceback" not in err, err
    assert sorted(os.listdir(tmp_path)) == before


def test_static_files_ship_and_import_stays_light():
    from importlib import resources

    for name in H._STATIC:
        assert resources.files("geovox.view").joinpath("static", name).is_file(), name
    root = os.path.join(os.path.dirname(__file__), "..")
    with open(os.path.join(root, "pyproject.toml")) as fh:
        assert '"geovox.view" = ["static/*"]' in fh.read()
    with open(os.path.join(root, "MANIFEST.in")) as fh:
        assert "recursive-include geovox/view/static" in fh.read()
    code = "import sys, geovox; print(sorted(m for m in sys.modules if m.startswith('geovox.')))"
    mods = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=root, check=True).stdout
    assert "geovox.view" not in mods and "numpy" not in mods


# ---- in Chromium ---------------------------------------------------------------------------------

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
FLAGS = ("--headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
         "--disable-background-networking --disable-component-update --disable-sync "
         "--use-angle=swiftshader --enable-unsafe-swiftshader --window-size=640,520").split()


def _chromium(extra=()):
    """A headless Chromium driven through the system chromedriver, and its profile folder."""
    if not (os.path.isfile(CHROMIUM) and os.path.isfile(CHROMEDRIVER)):
        pytest.skip("needs Debian's chromium and chromium-driver (apt-get install chromium "
                    "chromium-driver; .ci/run installs them as root)")
    webdriver = pytest.importorskip("selenium.webdriver", reason="needs selenium (the test extra)")
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="geovox-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in [*FLAGS, *extra, f"--user-data-dir={profile}"]:
        options.add_argument(flag)
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options), profile


@pytest.fixture(scope="module")
def browser():
    driver, profile = _chromium()
    yield driver
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)


def open_page(browser, path, timeout=90.0):
    """Load ``path`` and wait for data-rendered or data-error; the error (or None)."""
    browser.get("file://" + os.path.abspath(path))
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        rendered, error = browser.execute_script(
            "return [document.body.dataset.rendered || null, document.body.dataset.error || null]")
        if rendered or error:
            return error
        time.sleep(0.1)
    raise AssertionError(f"{path}: neither data-rendered nor data-error after {timeout} s")


def snapshot(browser):
    """The 3D canvas as an (h, w, 3) uint8 array (rendered afresh by the page's hook)."""
    from PIL import Image

    url = browser.execute_script("return window.geovoxViewer.snapshot()")
    with Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))) as im:
        return np.asarray(im.convert("RGB"))


def background(img):
    """The colour of the corners (the page's background)."""
    return img[2, 2].astype(int)


def share(mask):
    return float(np.count_nonzero(mask)) / mask.size


def reds(img):
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (r > 70) & (r > 2 * g) & (r > 2 * b)


def blues(img):
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (b > 70) & (b > 2 * r) & (b > 1.5 * g)


def greens(img):
    r, g, b = (img[..., i].astype(int) for i in range(3))
    return (g > 70) & (g > 2 * r) & (g > 2 * b)


def test_chromium_renders_spot_in_colour(browser, tmp_path):
    import geovox

    vol = geovox.voxelize(SPOT, resolution=48, color=True)
    error = open_page(browser, H.to_html(vol, tmp_path / "spot.html"))
    assert error is None
    img = snapshot(browser)
    differs = np.abs(img.astype(int) - background(img)).sum(axis=2) > 24
    assert share(differs) >= 0.05
    distinct = np.unique(img[differs].reshape(-1, 3), axis=0)
    assert len(distinct) >= 200, "shading gives many distinct colours"
    info = browser.find_element("id", "gv-info").text
    assert "48" in info and f"{vol.inside_count:,}" in info and "spot.obj" in info
    bounds = browser.execute_script("return window.geovoxViewer.boundsText()")
    assert [float(v) for v in bounds.split()[1:]] == pytest.approx(
        list(vol.bounds[0]) + list(vol.bounds[1]), abs=1e-3)


def test_chromium_two_material_box_shows_both_colours(browser, tmp_path):
    assert open_page(browser, H.to_html(two_material_box(), tmp_path / "box.html")) is None
    img = snapshot(browser)
    assert share(reds(img)) > 0.02 and share(blues(img)) > 0.02


def test_chromium_label_toggle_and_downsampling_notice(browser, tmp_path):
    vol = labelled_scene(48)
    assert open_page(browser, H.to_html(vol, tmp_path / "labels.html", max_side=24)) is None
    banner = browser.find_element("id", "gv-banner")
    assert banner.is_displayed() and "Downsampled by 2" in banner.text
    legend = browser.find_element("id", "gv-legend").text
    assert "left ball" in legend and "right ball" in legend and "floor (300)" in legend
    before = snapshot(browser)
    assert share(greens(before)) > 0.01 and share(reds(before)) > 0.01
    assert browser.execute_script("return window.geovoxViewer.toggleLabel(2)") is False
    after = snapshot(browser)
    assert share(np.abs(after.astype(int) - before).sum(axis=2) > 30) > 0.01
    assert share(greens(after)) < 0.001 and share(reds(after)) > 0.01


def test_chromium_clipping_box_exposes_the_inside(browser, tmp_path):
    assert open_page(browser, H.to_html(layered_sphere(), tmp_path / "sphere.html")) is None
    whole = snapshot(browser)
    assert share(greens(whole)) < 0.001
    # The camera looks from -x, -z: keeping z >= the middle shows the cut face.
    bounds = browser.execute_script("return window.geovoxViewer.setClip([0, 0, 0.5], [1, 1, 1])")
    assert bounds == "--bounds 0 0 20 40 40 40"
    assert browser.find_element("id", "gv-bounds").get_attribute("value") == bounds
    cut = snapshot(browser)
    assert share(greens(cut)) > 0.02


def test_chromium_says_what_went_wrong(browser, tmp_path):
    text = H.render_page(two_material_box(8))
    broken = re.sub(r'(id="geovox-field-colors">)[A-Za-z0-9+/=]{8}', r"\1AAAAAAAA", text)
    (tmp_path / "broken.html").write_text(broken, encoding="utf-8")
    error = open_page(browser, tmp_path / "broken.html")
    assert error and "colors" in error
    assert browser.find_element("id", "gv-error").is_displayed()


def test_chromium_without_webgl2_says_so(tmp_path):
    driver, profile = _chromium(["--disable-webgl", "--disable-3d-apis"])
    try:
        error = open_page(driver, H.to_html(two_material_box(8), tmp_path / "box.html"))
        assert error and "WebGL2" in error
        assert "WebGL2" in driver.find_element("id", "gv-error").text
        assert driver.execute_script("return document.body.dataset.rendered") is None
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)
