"""The documentation site: the benchmark page matches its result files, the site builds with
``mkdocs build --strict``, and its index and API pages render in headless Chromium (not blank,
no console error, ``voxelize``'s parameters shown).

The build needs the ``docs`` extra (``pip install -e '.[docs]'``); the browser checks need
Debian's ``chromium`` and ``chromium-driver`` (``.ci/run`` installs them as root) and selenium
(in the ``docs`` extra). Each part skips with the reason where its tools are absent.
"""

from __future__ import annotations

import functools
import http.server
import importlib.util
import io
import os
import shutil
import subprocess
import sys
import threading

import pytest

from conftest import ROOT

sys.path.insert(0, os.path.join(ROOT, "benchmarks"))
import tables  # noqa: E402  (benchmarks/tables.py)

CHROMIUM = next((p for p in ("/usr/bin/chromium", "/usr/bin/chromium-browser",
                             shutil.which("chromium") or "") if p and os.path.exists(p)), None)
CHROMEDRIVER = next((p for p in ("/usr/bin/chromedriver", shutil.which("chromedriver") or "")
                     if p and os.path.exists(p)), None)
#: The parameters of geovox.voxelize that the API page must show.
VOXELIZE_PARAMETERS = ("mesh", "resolution", "bounds", "backend", "shape", "voxel_size", "axis",
                       "color", "inside", "density", "supersample", "sdf", "band", "progress")


def test_benchmark_page_matches_result_files():
    """docs/benchmarks.md is what benchmarks/tables.py makes of benchmarks/results/*.json."""
    assert tables.main(["--check"]) == 0, "run python benchmarks/tables.py"


def test_result_files_say_how_they_were_measured():
    results = tables.load_results()
    assert {r["benchmark"] for r in results} >= {"users_path", "occupancy", "webgpu"}
    for result in results:
        for key in ("command", "date", "machine", "script"):
            assert result[key].strip(), (result["benchmark"], key)
        assert result["script"].startswith("benchmarks/bench_")
        assert os.path.exists(os.path.join(ROOT, result["script"])), result["script"]
        assert result["date"].startswith("2026-"), result["date"]
        for table in result["tables"]:
            assert table["rows"], (result["benchmark"], table.get("caption"))


def test_plots_come_from_same_run_peers():
    """Each plot has geovox and at least one peer series, numbers only, x and y paired."""
    plotted = [r for r in tables.load_results() if r.get("plot")]
    assert plotted
    for result in plotted:
        series = result["plot"]["series"]
        assert any(s.get("peer") for s in series) and any(not s.get("peer") for s in series)
        for s in series:
            assert len(s["x"]) == len(s["y"]) > 0
            assert all(isinstance(v, (int, float)) and v > 0 for v in s["x"] + s["y"])


def test_bad_result_file_is_refused(tmp_path):
    (tmp_path / "x.json").write_text('{"benchmark": "x", "title": "x", "command": "c", '
                                     '"date": "d", "machine": "m", "tables": [{"columns": '
                                     '["a", "b"], "rows": [["1"]]}]}', encoding="utf-8")
    with pytest.raises(ValueError, match="does not match the columns"):
        tables.load_results(tmp_path)
    (tmp_path / "x.json").write_text('{"benchmark": "x"}', encoding="utf-8")
    with pytest.raises(ValueError, match="no 'title'"):
        tables.load_results(tmp_path)


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built by ``mkdocs build --strict`` into a temporary folder."""
    if importlib.util.find_spec("mkdocs") is None or importlib.util.find_spec("mkdocstrings") is None:
        pytest.skip("mkdocs is not installed (pip install -e '.[docs]')")
    out = tmp_path_factory.mktemp("site")
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(out)],
                         cwd=ROOT, capture_output=True, text=True, timeout=300,
                         env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert run.returncode == 0, run.stdout + run.stderr
    return out


def test_site_has_every_page(site):
    for page in ("index.html", "getting-started/index.html", "formats/index.html",
                 "gallery/index.html", "benchmarks/index.html", "changelog/index.html",
                 "api/voxelize/index.html", "api/backends/index.html", "guide/colour/index.html",
                 "guide/labels/index.html", "guide/reference-grids/index.html",
                 "guide/html-viewer/index.html", "api/labels/index.html",
                 "api/reference/index.html", "api/viewer/index.html"):
        assert (site / page).is_file(), page
    assert (site / "img" / "bench_users_path.png").is_file()
    html = (site / "changelog" / "index.html").read_text(encoding="utf-8")
    assert "Unreleased" in html and "0.1.0" in html


def test_viewer_page_is_copied_untouched_and_embedded(site):
    """docs/viewer/spot.html (a real `geovox view --html` page) is in the site byte for byte, at
    most 1 MB, and the viewer guide embeds it in an iframe whose address resolves to it."""
    import re

    source = os.path.join(ROOT, "docs", "viewer", "spot.html")
    with open(source, "rb") as f:
        page = f.read()
    assert len(page) <= 1_000_000, len(page)
    assert b'id="geovox-meta"' in page and b"geovox-field-occupancy" in page
    assert (site / "viewer" / "spot.html").read_bytes() == page
    guide = site / "guide" / "html-viewer" / "index.html"
    frames = re.findall(r'<iframe[^>]*\ssrc="([^"]+)"', guide.read_text(encoding="utf-8"))
    assert frames, "no iframe in the viewer guide"
    assert (guide.parent / frames[0]).resolve() == (site / "viewer" / "spot.html").resolve()


def test_site_fetches_nothing_from_the_web(site):
    """No web fonts or third-party scripts: the pages read offline."""
    for page in ("index.html", "api/voxelize/index.html"):
        html = (site / page).read_text(encoding="utf-8")
        assert "fonts.googleapis.com" not in html and "fonts.gstatic.com" not in html, page
        assert 'src="http' not in html, page


@pytest.fixture(scope="module")
def server(site):
    """The built site over HTTP on 127.0.0.1 (the search's web worker needs http, not file)."""
    handler = functools.partial(_QuietHandler, directory=str(site))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/"
    httpd.shutdown()
    httpd.server_close()


class _QuietHandler(http.server.SimpleHTTPRequestHandler):
    def log_message(self, format, *args):
        pass


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    if CHROMIUM is None or CHROMEDRIVER is None:
        pytest.skip("chromium and chromedriver are not installed (apt-get install chromium "
                    "chromium-driver)")
    if importlib.util.find_spec("selenium") is None:
        pytest.skip("selenium is not installed (pip install -e '.[docs]')")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--window-size=1280,1000",
                 # SwiftShader's software WebGL2, for the embedded viewer page
                 "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                 f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()


def _render(browser, url):
    """Load ``url``; return (visible text, screenshot PNG bytes, console errors)."""
    browser.get_log("browser")  # drop what earlier pages logged
    browser.get(url)
    browser.execute_script("return document.readyState")
    text = browser.execute_script("return document.body.innerText")
    png = browser.get_screenshot_as_png()
    errors = [e for e in browser.get_log("browser") if e["level"] == "SEVERE"]
    return text, png, errors


def _not_blank(png):
    from PIL import Image

    img = Image.open(io.BytesIO(png)).convert("L")
    lo, hi = img.getextrema()
    colours = len(img.getcolors(maxcolors=1 << 16) or range(1 << 16))
    return hi - lo > 100 and colours > 20


def test_index_page_renders(browser, server):
    text, png, errors = _render(browser, server)
    assert not errors, errors
    assert _not_blank(png)
    assert "solid voxel volumes" in text
    assert "Getting started" in text  # the navigation


def test_api_page_shows_voxelize_parameters(browser, server):
    text, png, errors = _render(browser, server + "api/voxelize/")
    assert not errors, errors
    assert _not_blank(png)
    assert "geovox.voxelize" in text
    # The text of voxelize's own entry (mkdocstrings: the heading's id is the object's path).
    section = browser.execute_script(
        "const h = document.getElementById('geovox.api.voxelize');"
        "return h ? h.closest('.doc-object').innerText : '';")
    assert section.startswith("geovox.voxelize"), section[:200]
    assert "Parameters" in section and "Returns" in section and "Raises" in section
    missing = [p for p in VOXELIZE_PARAMETERS if p not in section]
    assert not missing, f"voxelize parameters not shown: {missing}"


def test_embedded_viewer_renders(browser, server):
    """The viewer guide's iframe draws spot (the page's own data-rendered flag, no data-error)."""
    import time

    from selenium.webdriver.common.by import By

    browser.get(server + "guide/html-viewer/")
    frame = browser.find_element(By.TAG_NAME, "iframe")
    browser.execute_script("arguments[0].scrollIntoView()", frame)  # loading="lazy"
    browser.switch_to.frame(frame)
    try:
        state = None
        deadline = time.monotonic() + 120
        while state is None and time.monotonic() < deadline:
            state = browser.execute_script(
                "const b = document.body; if (!b) return null;"
                "return b.dataset.error ? 'error: ' + b.dataset.error"
                "     : (b.dataset.rendered ? 'rendered' : null);")
            time.sleep(0.5)
        assert state == "rendered", state
        assert browser.execute_script("return window.geovoxViewer.meta.shape") == [128, 128, 128]
    finally:
        browser.switch_to.default_content()


def _python_blocks(page):
    with open(os.path.join(ROOT, "docs", page), encoding="utf-8") as f:
        text = f.read()
    return [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]


@pytest.mark.parametrize("axis", [0, 2])
def test_backend_example_gives_the_numpy_backends_crossings(axis):
    """The complete backend on the 'Writing a backend' page runs and is exact."""
    from conftest import SPOT

    from geovox.backends import get_backend
    from geovox.grid import make_grid
    from geovox.io.load import load_mesh
    from geovox.block import ray_start

    namespace = {}
    exec(_python_blocks("api/backends.md")[0], namespace)  # noqa: S102 - the page's own code
    mesh = load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=24)
    columns = grid.columns(axis, ray_start(mesh, grid, axis))
    mine = namespace["BoxBackend"]().cast(mesh, columns).sorted()
    ref = get_backend("numpy").cast(mesh, columns).sorted()
    assert len(mine) == len(ref) > 0
    for name in ("ray", "triangle", "depth", "bary"):
        assert (getattr(mine, name) == getattr(ref, name)).all(), name


def _readme():
    """The README, the project's front door."""
    return os.path.join(ROOT, "README.md")


def test_short_readme_keeps_its_limits():
    """At most 200 lines and 16 KB, the two commands as Getting started gives them, a Python
    example of at most 15 lines, no dated figures, and links that point at files."""
    path = _readme()
    with open(path, encoding="utf-8") as f:
        text = f.read()
    assert len(text.splitlines()) <= 200 and len(text.encode()) <= 16 * 1024
    with open(os.path.join(ROOT, "docs", "getting-started.md"), encoding="utf-8") as f:
        commands = [line for line in f.read().splitlines() if line.startswith("python3 -m venv")
                    and ("geovox convert" in line or "pytest" in line)]
    assert len(commands) == 2
    for command in commands:
        assert command in text.splitlines(), command
    python = _python_blocks_of(text)
    assert python and len(python[0].rstrip("\n").splitlines()) <= 15
    import re

    assert not re.search(r"20\d\d-\d\d-\d\d|\d\d:\d\d UTC", text), "dated figures"
    assert "docs/benchmarks.md" in text and "Open3D" in text
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", text):
        assert os.path.exists(os.path.join(ROOT, target)), target


def _python_blocks_of(text):
    return [b.split("```", 1)[0] for b in text.split("```python\n")[1:]]
