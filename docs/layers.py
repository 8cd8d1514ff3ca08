"""Draw geovox's layers (docs/img/layers.svg) from the import-linter contract in pyproject.toml.

Run from the repository root: ``python docs/layers.py`` (writes the picture) or
``python docs/layers.py --check`` (exit 1 if the picture is not the contract's; the tests run it).
The contract is the one source: CONTRIBUTING.md and the docs show this picture of it.
"""

from __future__ import annotations

import argparse
import os
import sys
import tomllib
from html import escape

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OUT = os.path.join(ROOT, "docs", "img", "layers.svg")

#: What each layer is, in a few words (shown at its left).
ROLES = ["the command line", "many models", "the public API and tools", "the runners",
         "one block", "the plan", "output targets", "labels", "the stages", "nearest points",
         "reading and writing",
         "options and primitives", "the ground", "errors"]

WIDTH, ROW, GAP, LEFT = 980, 38, 10, 190


def layers() -> list:
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as f:
        contract = tomllib.load(f)["tool"]["importlinter"]["contracts"][0]
    return contract["layers"]


def svg() -> str:
    rows = layers()
    height = len(rows) * (ROW + GAP) + GAP + 28
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{WIDTH}" height="{height}" '
           f'viewBox="0 0 {WIDTH} {height}" font-family="sans-serif" font-size="13">',
           f'<rect width="{WIDTH}" height="{height}" fill="white"/>',
           f'<text x="{LEFT}" y="18" fill="#444">imports point down; "|" siblings never import '
           f'each other, ":" siblings may (no circle)</text>']
    for r, layer in enumerate(rows):
        y = 28 + GAP + r * (ROW + GAP)
        independent = "|" in layer
        names = [n.strip() for n in layer.replace("|", ":").split(":")]
        role = ROLES[r] if r < len(ROLES) else ""
        out.append(f'<text x="8" y="{y + ROW / 2 + 5}" fill="#666">{escape(role)}</text>')
        w = (WIDTH - LEFT - 8 - GAP * (len(names) - 1)) / len(names)
        for k, name in enumerate(names):
            x = LEFT + k * (w + GAP)
            dash = "" if independent or len(names) == 1 else ' stroke-dasharray="4 3"'
            out.append(f'<rect x="{x:.1f}" y="{y}" width="{w:.1f}" height="{ROW}" rx="5" '
                       f'fill="#e8edf9" stroke="#3f51b5"{dash}/>')
            out.append(f'<text x="{x + w / 2:.1f}" y="{y + ROW / 2 + 5}" text-anchor="middle">'
                       f'{escape(name)}</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if the picture is out of date")
    args = ap.parse_args(argv)
    text = svg()
    if args.check:
        with open(OUT, encoding="utf-8") as f:
            return 0 if f.read() == text else 1
    with open(OUT, "w", encoding="utf-8") as f:
        f.write(text)
    print("wrote", OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
