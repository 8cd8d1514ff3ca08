"""How much a file may grow to once read: the guard against small files that claim a lot.

A 2 MB zip can hold a 2 GB STL, a 1 KB glTF can declare an accessor of a
billion zeros, a Draco or meshopt buffer can decode to far more than it
stores, and a PLY header can announce more vertices than its bytes hold.
Every reader asks :func:`input_limit` how many bytes the file may become,
and refuses in one line (:func:`refuse`) before it allocates more.

The default limit is the smaller of

* :data:`RATIO` times the file's own size (but at least :data:`FLOOR`):
  real meshes compress a few to one (binary STL about 1.2:1 under deflate,
  ASCII formats 3-8:1), while zeros compress 1000:1; and
* :data:`MEMORY_SHARE` of the memory available now.

Instancing is another matter: a glTF node with ``EXT_mesh_gpu_instancing``,
a mesh that many nodes share, a 3MF component placed many times. The file
stores a part once and says where its copies go, so a forest of one tree
placed ten thousand times is a small file of many triangles, not a bomb.
What the placed copies take is counted before they are built, against
:data:`MEMORY_SHARE` of the memory available (:func:`scene_limit`), not
against the file's size; the bytes a reader decodes (accessors, compressed
streams, counts a header claims) stay under the file-size rule.

``max_input_size`` (the option, ``--max-input-size`` on the command line)
replaces both with a number of bytes, for a model that really is that
compressible or a service that wants a tighter bound. Time and processor
are not bounded here: a service should bound those from outside (see
docs/guide/input-formats.md).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from ..errors import MeshError
from ..memory import available_memory

__all__ = ["Limit", "RATIO", "FLOOR", "MEMORY_SHARE", "input_limit", "scene_limit", "refuse",
           "size_text", "parse_size"]

#: Inflated bytes per stored byte that no real mesh reaches.
RATIO = 100
#: Below this many bytes an input is never refused for its ratio.
FLOOR = 64 << 20
#: The share of the available memory one input may grow to.
MEMORY_SHARE = 0.5


@dataclass(frozen=True)
class Limit:
    """The option ``max_input_size`` as the readers use it, made once by :func:`geovox.io.load.load_mesh`.

    Attributes
    ----------
    most : int or None
        Bytes an input may become; None: the default rule (:func:`input_limit`).
    """

    most: int | None = None

    def of(self, stored: int) -> int:
        """The limit for a file of ``stored`` bytes."""
        return input_limit(stored, self.most)

    def refuse(self, path: str, what: str, need, limit: int) -> MeshError:
        """The one line for ``what`` past ``limit`` (see :func:`refuse`)."""
        return refuse(path, what, need, limit, self.most is not None)

    def scene(self) -> int | None:
        """The most bytes a file's placed instances may take (see :func:`scene_limit`)."""
        return scene_limit(self.most)

    def refuse_scene(self, path: str, what: str, need: int, limit: int) -> MeshError:
        """The one line for a scene whose instances would take ``need`` bytes past ``limit``."""
        why = ("max_input_size, --max-input-size" if self.most is not None else
               f"{MEMORY_SHARE:.0%} of the memory available now; --max-input-size sets it")
        return MeshError(f"{path}: {what} would take {size_text(need)}, more than "
                         f"{size_text(limit)} ({why}); not read")


def input_limit(stored: int, most: int | None = None) -> int:
    """The most bytes a file of ``stored`` bytes may become once read or inflated.

    Parameters
    ----------
    stored : int
        The file's size (an archive's, or a model's with the buffers it names).
    most : int or None
        The option ``max_input_size``: the limit itself, when given.
    """
    if most is not None:
        return int(most)
    limit = max(RATIO * int(stored), FLOOR)
    memory = available_memory()
    return limit if memory is None else min(limit, int(MEMORY_SHARE * memory))


def scene_limit(most: int | None = None) -> int | None:
    """The most bytes the instances a file places may take once built, or None where unknown.

    Not a ratio of the file's size: instancing is the format's own
    compression, and what it costs is memory. :data:`MEMORY_SHARE` of the
    memory available now (of the machine's memory where that is not known).

    Parameters
    ----------
    most : int or None
        The option ``max_input_size``: the limit itself, when given.
    """
    if most is not None:
        return int(most)
    memory = available_memory()
    if memory is None:
        try:  # no /proc/meminfo (macOS): the machine's memory, still a bound
            memory = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, OSError, ValueError):
            return None
    return int(MEMORY_SHARE * memory)


def parse_size(text: str) -> int:
    """``"500M"`` -> 500_000_000: bytes, with an optional k/M/G/T (powers of 1000, or KiB..TiB of 1024).

    Raises
    ------
    ValueError
        Not a positive size (argparse says so, naming the option).
    """
    import re

    m = re.fullmatch(r"\s*([0-9]+(?:\.[0-9]*)?)\s*([kmgt]?)(i?)b?\s*", str(text), re.I)
    if m is None:
        raise ValueError(f"not a size: {text!r}")
    power = "kmgt".find(m.group(2).lower()) + 1 if m.group(2) else 0
    value = int(float(m.group(1)) * (1024 if m.group(3) else 1000) ** power)
    if value <= 0:
        raise ValueError(f"not a positive size: {text!r}")
    return value


def size_text(n: float) -> str:
    """``"2.0 GB"``: a byte count for messages (decimal units, as file managers show)."""
    for unit, size in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= size:
            return f"{n / size:,.1f} {unit}"
    return f"{int(n):,} bytes"


def refuse(path: str, what: str, need, limit: int, given: bool = False) -> MeshError:
    """The one-line error (to raise) for ``what`` needing ``need`` bytes past ``limit``.

    ``need`` None: ``what`` is a verb that went past the limit ("inflates");
    ``given``: the limit is the option's, not the default rule's.
    """
    why = ("max_input_size, --max-input-size" if given else
           f"the limit for a file of this size: {RATIO} times its size, at most half the "
           f"memory available; --max-input-size sets it")
    if need is None:
        return MeshError(f"{path}: {what} past {size_text(limit)} ({why}); not read")
    return MeshError(f"{path}: {what} would take {size_text(need)}, more than "
                     f"{size_text(limit)} ({why}); not read")
