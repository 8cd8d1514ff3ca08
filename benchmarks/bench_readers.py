"""geovox's own readers: GLB and PLY against OBJ, whole process, and the zip bomb.

1. **Speed** (issue 36: GLB and PLY each within 1.3x of the same model as OBJ).
   Each model is written as OBJ, binary PLY, GLB and glTF (+ .bin) from the
   same arrays; every round runs a fresh ``python -m geovox convert MODEL -o
   out.raw -r 128 -q`` of each, in an order that rotates from round to round
   (paired: the machine's load falls on all of them alike). Reported: the
   median wall time per format and its ratio to OBJ's median, and the ratio's
   spread over the rounds (each round's own ratio).
2. **Loading alone**, in one process: ``geovox.load_mesh`` against what geovox
   did before (``trimesh.load`` then the adaptor), best of a few.
3. **The zip bomb**: a ~2 MB zip of one STL that inflates to 2 GB, converted
   by a fresh process under ``/usr/bin/time``: exit status, its one line,
   wall time and peak memory (issue 36: one line, within 5 s and 1 GiB).

    python benchmarks/bench_readers.py [--rounds 7] [--resolution 128] [--no-bomb]
        [--results benchmarks/results/readers.json]

``--results FILE`` also writes the three tables as a result file for
``benchmarks/tables.py`` (the machine line and the notes are to be checked by
hand).

The sweep of public test files against trimesh is ``benchmarks/sweep_readers.py``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
import zipfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MODELS = {"spot": os.path.join(ROOT, "data", "spot", "spot.obj"),
          "bunny": os.path.join(ROOT, "tests", "data", "bunny_watertight", "bunny_oded.obj")}
# The 70k-triangle scan, where the shared corpus is beside the checkout.
_STANFORD = os.path.join(ROOT, "..", "shared", "corpus", "stanford_bunny", "bunny.obj")
if os.path.exists(_STANFORD):
    MODELS["stanford bunny"] = _STANFORD
FORMATS = ("obj", "ply", "glb", "gltf", "stl")


def write_formats(name: str, source: str, folder: str) -> dict:
    """The model's triangles as OBJ, PLY, GLB, glTF and STL (no materials: geometry alone)."""
    import trimesh

    import geovox

    mesh = geovox.load_mesh(source)
    t = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    folder = os.path.join(folder, name)  # a glTF's buffer files are named alike
    os.makedirs(folder, exist_ok=True)
    out = {}
    for ext in FORMATS:
        path = os.path.join(folder, f"{name}.{ext}")
        if ext == "gltf":
            files = trimesh.Scene(t).export(file_type="gltf")
            for k, data in files.items():
                with open(os.path.join(folder, k if k != "model.gltf" else f"{name}.gltf"),
                          "wb") as f:
                    f.write(data)
        else:
            t.export(path)
        out[ext] = path
    return out


def convert_time(path: str, out: str, resolution: int) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "geovox", "convert", path, "-o", out, "-r",
                    str(resolution), "-q"], check=True, cwd=ROOT, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def speed(rounds: int, resolution: int, folder: str) -> list:
    print(f"## whole process, geovox convert -r {resolution} ({rounds} rounds, rotating order)")
    print("| model | format | triangles | median s | ratio to OBJ (median) | ratio range |")
    print("|---|---|---|---|---|---|")
    import geovox

    rows = []
    for name, source in MODELS.items():
        paths = write_formats(name, source, folder)
        faces = len(geovox.load_mesh(paths["obj"]).faces)
        times = {ext: [] for ext in FORMATS}
        for r in range(rounds + 1):
            order = FORMATS[r % len(FORMATS):] + FORMATS[:r % len(FORMATS)]
            got = {ext: convert_time(paths[ext], os.path.join(folder, "v.raw"), resolution)
                   for ext in order}
            if r:  # the first round warms the file cache
                for ext in FORMATS:
                    times[ext].append(got[ext])
        for ext in FORMATS:
            ratios = [a / b for a, b in zip(times[ext], times["obj"])]
            rows.append([name, ext, f"{faces:,}", f"{statistics.median(times[ext]):.3f}",
                         f"{statistics.median(times[ext]) / statistics.median(times['obj']):.2f}",
                         f"{min(ratios):.2f}-{max(ratios):.2f}"])
            print("| " + " | ".join(rows[-1]) + " |", flush=True)
    return rows


def loading(folder: str) -> list:
    import warnings

    import trimesh

    import geovox
    from geovox.io.adaptor import from_trimesh

    print("\n## loading alone, in one process (best of 5)")
    print("| model | format | geovox s | trimesh + adaptor s | speed-up |")
    print("|---|---|---|---|---|")
    rows = []
    for name in MODELS:
        for ext in ("ply", "glb", "gltf"):
            path = os.path.join(folder, name, f"{name}.{ext}")

            def ours():
                geovox.load_mesh(path)

            def theirs():
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    from_trimesh(trimesh.load(path, process=False), source=path)

            best = []
            for fn in (ours, theirs):
                fn()
                runs = []
                for _ in range(5):
                    t = time.perf_counter()
                    fn()
                    runs.append(time.perf_counter() - t)
                best.append(min(runs))
            rows.append([name, ext, f"{best[0]:.4f}", f"{best[1]:.4f}",
                         f"{best[1] / best[0]:.1f}x"])
            print("| " + " | ".join(rows[-1]) + " |", flush=True)
    return rows


def bomb(folder: str) -> list:
    path = os.path.join(folder, "bomb.zip")
    size = 2 * 10**9
    # 40 million zero-area triangles: a binary STL header, then 50-byte zero records
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        with z.open("bomb.stl", "w", force_zip64=True) as f:
            n = (size - 84) // 50
            f.write(b"\0" * 80 + np.uint32(n).tobytes())
            block = bytes(50 * 20000)
            left = n * 50
            while left:
                f.write(block[:min(left, len(block))])
                left -= min(left, len(block))
    print(f"\n## the zip bomb: {os.path.getsize(path) / 1e6:.1f} MB zip of a "
          f"{size / 1e9:.0f} GB STL")
    cmd = ["/usr/bin/time", "-f", "%e s %M KB", sys.executable, "-m", "geovox", "convert",
           path, "-o", os.path.join(folder, "bomb.raw"), "-r", "128"]
    got = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    lines = got.stderr.strip().splitlines()
    # /usr/bin/time adds its format line last and, on a non-zero exit, a "Command exited" line
    ours = [line for line in lines[:-1] if not line.startswith(("Command exited",
                                                                 "Command terminated"))]
    print(f"exit {got.returncode}; stderr lines: {len(ours)}")
    for line in lines:
        print(f"    {line}")
    wall, _, peak, _ = lines[-1].split()
    return [[f"{os.path.getsize(path) / 1e6:.1f} MB zip of a {size / 1e9:.0f} GB STL",
             str(got.returncode), str(len(ours)),
             " / ".join(ours).replace(path, "BOMB.zip").replace("`", "'"),
             f"{float(wall):.2f}", f"{int(peak) / 1024:.0f}"]]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=7)
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--no-bomb", action="store_true")
    ap.add_argument("--results", help="also write the tables as a result file here")
    args = ap.parse_args(argv)
    load = os.getloadavg()[0]
    start = datetime.datetime.now(datetime.timezone.utc)
    print(f"# bench_readers: {time.strftime('%Y-%m-%d %H:%M')}, {platform.node()}, "
          f"{os.cpu_count()} cores, load {load:.1f}, Python {platform.python_version()}")
    with tempfile.TemporaryDirectory() as folder:
        fast = speed(args.rounds, args.resolution, folder)
        alone = loading(folder)
        zipped = [] if args.no_bomb else bomb(folder)
    end = datetime.datetime.now(datetime.timezone.utc)
    if args.results:
        write_results(args, fast, alone, zipped, start, end, (load, os.getloadavg()[0]))
    return 0


def write_results(args, fast, alone, zipped, start, end, load) -> None:
    """The three tables as ``benchmarks/results/readers.json`` (schema: ``tables.py``)."""
    import geovox

    tables = [
        {"caption": f"Whole process, `geovox convert MODEL -o out.raw -r {args.resolution} -q`, "
                    f"{args.rounds} rounds in rotating order (median wall time; the ratio to "
                    f"OBJ's median, and the range of each round's own ratio)",
         "columns": ["model", "format", "triangles", "median (s)", "ratio to OBJ (median)",
                     "ratio range"],
         "rows": fast},
        {"caption": "Loading alone, in one process: `geovox.load_mesh` against `trimesh.load` "
                    "then the adaptor (best of 5)",
         "columns": ["model", "format", "geovox (s)", "trimesh + adaptor (s)", "speed-up"],
         "rows": alone},
    ]
    if zipped:
        tables.append({
            "caption": "The zip bomb: a fresh `geovox convert BOMB.zip -o out.raw -r 128` "
                       "under /usr/bin/time",
            "columns": ["input", "exit status", "stderr lines", "message", "wall (s)",
                        "peak RSS (MiB)"],
            "rows": zipped})
    result = {
        "benchmark": "readers",
        "title": "geovox's own readers: GLB, glTF, PLY and STL against OBJ, and the zip bomb "
                 "(issue 36)",
        "script": "benchmarks/bench_readers.py",
        "command": "python benchmarks/bench_readers.py " + " ".join(
            [f"--rounds {args.rounds}", f"--resolution {args.resolution}"]
            + (["--no-bomb"] if args.no_bomb else []) + [f"--results {args.results}"]),
        "date": f"{start:%Y-%m-%d}, {start:%H:%M}-{end:%H:%M} UTC",
        "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python "
                   f"{platform.python_version()}; load average {load[0]:.2f} before, "
                   f"{load[1]:.2f} after",
        "models": [f"{name} = {os.path.relpath(path, ROOT)}".replace(
            "../shared/corpus/", "the shared corpus's ") for name, path in MODELS.items()],
        "notes": f"geovox {geovox.__version__}. Each model's triangles written as OBJ, binary "
                 f"PLY, GLB, glTF (+ .bin) and binary STL by trimesh from the same arrays "
                 f"(geometry alone); the first round of the whole-process runs warms the file "
                 f"cache and is not counted.",
        "tables": tables,
    }
    with open(args.results, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1, ensure_ascii=False)
        f.write("\n")


if __name__ == "__main__":
    sys.exit(main())
