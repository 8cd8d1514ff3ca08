"""Compressed inputs (zip and tar archives, gzip/bzip2/xz files, 3MF, COLLADA .zae, 3DXML), checked before they are inflated.

trimesh inflates every member of an archive into memory before it looks at
any, so a 2 MB zip of a 2 GB STL once took 20 GB and a minute. geovox
checks first, and refuses in one line before the memory is spent:

* a zip file (and the formats that are zip files) lists each member's
  inflated size in its central directory, and Python's :mod:`zipfile` (which
  trimesh and geovox's 3MF reader use) never inflates a member past the size
  listed, so the listed sizes are added up without inflating anything;
* a gzip, bzip2 or xz stream (a ``.tar.gz`` among them) states no size it
  must keep to, so it is inflated once, in pieces that are counted and
  dropped, and refused as soon as the count passes the limit.

The limit is :func:`geovox.io.limits.input_limit`: ``max_input_size``
where given, else a compression ratio no real mesh reaches or half the
available memory, whichever is smaller.
"""

from __future__ import annotations

import os
import zipfile

from ..errors import MeshError
from . import limits

__all__ = ["check_archive", "STREAMS"]

#: Openers of the single-stream compressions, by the file's first bytes.
STREAMS = {b"\x1f\x8b": "gzip", b"BZh": "bz2", b"\xfd7zXZ\x00": "lzma"}
_PIECE = 1 << 20


def check_archive(path: str, limit: limits.Limit = limits.Limit()) -> None:
    """Refuse ``path`` if it would inflate past the limit; return quietly otherwise.

    Parameters
    ----------
    path : str
        A zip, tar, gzip, bzip2 or xz file (anything else passes).
    limit : geovox.io.limits.Limit
        ``max_input_size``: the most bytes its contents may inflate to
        (default: :func:`geovox.io.limits.input_limit` of its size).

    Raises
    ------
    MeshError
        One line naming the file, what it would inflate to and the limit.
    """
    cap = limit.of(os.path.getsize(path))
    with open(path, "rb") as f:
        head = f.read(6)
    if head[:4] == b"PK\x03\x04" or zipfile.is_zipfile(path):
        _check_zip(path, cap, limit)
        return
    opener = next((name for magic, name in STREAMS.items() if head.startswith(magic)), None)
    if opener is not None:
        _check_stream(path, opener, cap, limit)


def _check_zip(path: str, cap: int, limit) -> None:
    try:
        with zipfile.ZipFile(path) as z:
            members = z.infolist()
    except (zipfile.BadZipFile, OSError, ValueError, EOFError):
        return  # not a zip after all: its reader says what is wrong
    total = sum(m.file_size for m in members)
    if total > cap:
        biggest = max(members, key=lambda m: m.file_size)
        raise limit.refuse(path, f"its {len(members):,} member{'s' if len(members) > 1 else ''}"
                                  f" ({biggest.filename!r} the largest, "
                                  f"{limits.size_text(biggest.file_size)}) inflated",
                           total, cap)


def _check_stream(path: str, opener: str, cap: int, limit) -> None:
    import importlib

    module = importlib.import_module(opener)
    seen = 0
    try:
        with module.open(path, "rb") as f:
            while True:
                piece = f.read(_PIECE)
                if not piece:
                    return
                seen += len(piece)
                if seen > cap:
                    raise limit.refuse(path, "inflates", None, cap)
    except MeshError:
        raise
    except (OSError, EOFError, ValueError):
        return  # a damaged stream: its reader says what is wrong
