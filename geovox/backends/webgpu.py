"""WebGPU backend: the exact pair search on a GPU through ``wgpu`` (wgpu-py).

Any adapter that wgpu finds runs it: a GPU through Vulkan, Metal or DX12, or
Mesa's software Vulkan driver lavapipe (Debian package ``mesa-vulkan-drivers``),
which is how the tests run it on machines without a GPU.

The decision stays exact. The host splits each triangle's column bounding
box into tiles of at most ``TILE`` x ``TILE`` columns and computes, in int64
from :class:`geovox.exact.Projection`'s ``coef``, the three tie-resolved edge
values at each tile's first column and their steps per column and per row.
The shader only adds those 64-bit values, held as two u32 halves with an
explicit carry, and tests their signs, so it needs nothing beyond core WGSL
(no int64 extension, no float) and finds exactly the (ray, triangle) pairs of
``Projection.edge_values > 0``. It returns each crossing with its three edge
values; the host then computes depth and barycentrics with
``Projection.interpolate`` in float64, the very function the NumPy backend
uses, so every depth is bit for bit the NumPy backend's and no voxel can flip.
That host pass touches only the crossings, not every candidate column, which
is why it is cheaper than the NumPy backend's own.

Traps this module works around (wgpu 0.32.0, Mesa 22.3.6):

* llvmpipe silently stops an invocation after 65,535 loop iterations in
  total, with no error: one invocation handles one tile in each of the two
  passes (count, then emit), at most ``TILE * TILE + TILE`` iterations.
* A storage binding over 128 MiB (the default limit) is a validation
  error: the tiles are dispatched in chunks whose summed tile areas, an upper
  bound on their crossings, fit the output binding.
* ``queue.on_submitted_work_done_sync()`` raises TypeError in wgpu 0.32.0;
  the blocking ``queue.read_buffer`` of the tile counts is the sync point.
* Mesa prints ``XDG_RUNTIME_DIR is invalid or not set`` on every adapter
  request when that variable is unset (harmless; silenced here).
* With both a Vulkan and an OpenGL driver the same device appears twice;
  :func:`adapter` takes Vulkan, Metal or DX12 and never OpenGL unless
  ``WGPU_BACKEND_TYPE=OpenGL`` asks for it.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

import numpy as np

from ..errors import BackendUnavailableError
from ..exact import Projection
from ..grid import Columns
from ..parallel import for_blocks
from .base import Backend, Hits

#: Columns per tile side: bounds the loop iterations of one invocation.
TILE = 16
#: Invocations per workgroup (the shader's ``@workgroup_size``).
WORKGROUP = 64
#: u32 words per tile record and per crossing record.
TILE_WORDS = 22
HIT_WORDS = 8
#: Crossings reconstructed on the host per block (float64 temporaries of
#: about 100 bytes each).
HOST_BLOCK = 1 << 19
#: What to install, for the one-line error.
DRIVER_HINT = ("a Vulkan, Metal or DX12 driver (for a software one on Debian or Ubuntu: "
               "`apt-get install mesa-vulkan-drivers`)")

#: 64-bit two's complement arithmetic on (low, high) u32 pairs: only what
#: the search needs, an addition with carry and a sign test.
WGSL_INT64 = """
fn add64(a: vec2<u32>, b: vec2<u32>) -> vec2<u32> {
    let lo = a.x + b.x;
    // The low half overflowed exactly when the sum is below an operand.
    return vec2<u32>(lo, a.y + b.y + select(0u, 1u, lo < a.x));
}

fn positive(a: vec2<u32>) -> bool {
    // The sign is the high half's top bit: bitcast keeps the bits.
    let hi = bitcast<i32>(a.y);
    return hi > 0 || (hi == 0 && a.x != 0u);
}
"""

# One invocation per tile, in two passes over the same tiles. Tile record
# (22 u32): edge values at the tile's first column c0, c1, c2, steps per
# column ki0..2 and per row kj0..2 (each a (low, high) pair), then the active
# triangle, i0, j0 and width | height << 16. `count` writes each tile's number
# of crossings; the host turns them into offsets (an exclusive prefix sum);
# `emit` writes each tile's crossings from its offset, as (ray, triangle, w0,
# w1, w2), 8 u32 read by the host as four little-endian int64. The output is
# thus in tile order (triangle, then tile, then row, then column), the same
# on every run, with no atomics.
WGSL_SEARCH = WGSL_INT64 + """
struct Params {
    ntiles: u32,
    nu: u32,
    total: u32,
    pad: u32,
}

@group(0) @binding(0) var<storage, read> tiles: array<u32>;
@group(0) @binding(1) var<storage, read_write> hits: array<u32>;
@group(0) @binding(2) var<storage, read_write> counts: array<u32>;
@group(0) @binding(3) var<uniform> params: Params;

struct Tile {
    c0: vec2<u32>, c1: vec2<u32>, c2: vec2<u32>,
    ki0: vec2<u32>, ki1: vec2<u32>, ki2: vec2<u32>,
    kj0: vec2<u32>, kj1: vec2<u32>, kj2: vec2<u32>,
    t: u32, i0: u32, j0: u32, width: u32, height: u32,
}

fn pair(base: u32) -> vec2<u32> {
    return vec2<u32>(tiles[base], tiles[base + 1u]);
}

fn load(k: u32) -> Tile {
    let b = k * 22u;
    return Tile(pair(b), pair(b + 2u), pair(b + 4u),
                pair(b + 6u), pair(b + 8u), pair(b + 10u),
                pair(b + 12u), pair(b + 14u), pair(b + 16u),
                tiles[b + 18u], tiles[b + 19u], tiles[b + 20u],
                tiles[b + 21u] & 0xffffu, tiles[b + 21u] >> 16u);
}

fn index(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.x + gid.y * groups.x * 64u;
}

@compute @workgroup_size(64)
fn count(@builtin(global_invocation_id) gid: vec3<u32>,
         @builtin(num_workgroups) groups: vec3<u32>) {
    let k = index(gid, groups);
    if (k >= params.ntiles) {
        return;
    }
    let p = load(k);
    var n = 0u;
    var r0 = p.c0;
    var r1 = p.c1;
    var r2 = p.c2;
    for (var dj = 0u; dj < p.height; dj++) {
        var e0 = r0;
        var e1 = r1;
        var e2 = r2;
        for (var di = 0u; di < p.width; di++) {
            if (positive(e0) && positive(e1) && positive(e2)) {
                n += 1u;
            }
            e0 = add64(e0, p.ki0);
            e1 = add64(e1, p.ki1);
            e2 = add64(e2, p.ki2);
        }
        r0 = add64(r0, p.kj0);
        r1 = add64(r1, p.kj1);
        r2 = add64(r2, p.kj2);
    }
    counts[k] = n;
}

@compute @workgroup_size(64)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>,
        @builtin(num_workgroups) groups: vec3<u32>) {
    let k = index(gid, groups);
    if (k >= params.ntiles) {
        return;
    }
    // counts now holds each tile's offset.
    var o = counts[k];
    var stop = params.total;
    if (k + 1u < params.ntiles) {
        stop = counts[k + 1u];
    }
    if (o == stop) {
        return;
    }
    let p = load(k);
    var r0 = p.c0;
    var r1 = p.c1;
    var r2 = p.c2;
    for (var dj = 0u; dj < p.height; dj++) {
        var e0 = r0;
        var e1 = r1;
        var e2 = r2;
        let row = (p.j0 + dj) * params.nu + p.i0;
        for (var di = 0u; di < p.width; di++) {
            if (positive(e0) && positive(e1) && positive(e2)) {
                let h = o * 8u;
                hits[h] = row + di;
                hits[h + 1u] = p.t;
                hits[h + 2u] = e0.x;
                hits[h + 3u] = e0.y;
                hits[h + 4u] = e1.x;
                hits[h + 5u] = e1.y;
                hits[h + 6u] = e2.x;
                hits[h + 7u] = e2.y;
                o += 1u;
            }
            e0 = add64(e0, p.ki0);
            e1 = add64(e1, p.ki1);
            e2 = add64(e2, p.ki2);
        }
        r0 = add64(r0, p.kj0);
        r1 = add64(r1, p.kj1);
        r2 = add64(r2, p.kj2);
    }
}
"""

_lock = threading.Lock()
# The device buffers are shared: one search at a time (colour casts the
# three axes from two threads).
_busy = threading.Lock()
_state: dict = {}


@contextlib.contextmanager
def _quiet_native_stderr():
    """Hide what native code writes to fd 2 (Mesa's XDG_RUNTIME_DIR line).

    Only while adapters are opened, and only where that variable is unset,
    which is when Mesa prints its harmless complaint once per adapter.
    """
    if os.environ.get("XDG_RUNTIME_DIR"):
        yield
        return
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _import_wgpu():
    try:
        import wgpu
    except ImportError as exc:
        raise BackendUnavailableError(
            "backend 'webgpu' needs the 'wgpu' package: install it with "
            "`pip install 'geovox[gpu]'` (or `pip install wgpu`), or use --backend numpy"
        ) from exc
    return wgpu


def _choose(adapters):
    """The adapter to use: GPUs before CPUs, never OpenGL unless forced."""
    forced = os.environ.get("WGPU_BACKEND_TYPE", "").strip().lower()
    kinds = {"discretegpu": 0, "integratedgpu": 1, "virtualgpu": 2, "unknown": 3, "cpu": 4}
    ranked = []
    for n, a in enumerate(adapters):
        info = a.info
        api = str(info.get("backend_type", "")).lower()
        if forced and api != forced:
            continue
        if api == "opengl" and forced != "opengl":
            continue
        kind = str(info.get("adapter_type", "")).lower()
        ranked.append((kinds.get(kind, 3), n, a))
    return min(ranked, key=lambda r: r[:2])[2] if ranked else None


def adapter():
    """The wgpu adapter this backend uses (opened once per process).

    Raises
    ------
    BackendUnavailableError
        ``wgpu`` is not installed, or no usable adapter exists (the message
        names the driver to install).
    """
    with _lock:
        if "adapter" not in _state:
            wgpu = _import_wgpu()
            try:
                with _quiet_native_stderr():
                    found = _choose(wgpu.gpu.enumerate_adapters_sync())
            except Exception as exc:  # the native library's failures are plain exceptions
                raise BackendUnavailableError(
                    f"backend 'webgpu' could not list GPU adapters ({exc}); it needs {DRIVER_HINT}"
                ) from exc
            if found is None:
                raise BackendUnavailableError(
                    f"backend 'webgpu' found no GPU adapter: it needs {DRIVER_HINT}"
                )
            _state["adapter"] = found
        return _state["adapter"]


def describe() -> str:
    """One line for ``geovox backends``: the adapter, or what is missing."""
    try:
        import wgpu  # noqa: F401
    except ImportError:
        return "missing (pip install 'geovox[gpu]')"
    try:
        info = adapter().info
    except BackendUnavailableError:
        return f"missing: no GPU adapter; needs {DRIVER_HINT}"
    return (f"available: {info.get('device') or info.get('vendor')} "
            f"({info.get('adapter_type')}, {info.get('backend_type')})")


def _device():
    """(device, {entry point: pipeline}), created once per process."""
    a = adapter()
    with _lock:
        if "device" not in _state:
            wgpu = _import_wgpu()
            try:
                device = a.request_device_sync()
            except Exception as exc:  # the native library's failures are plain exceptions
                raise BackendUnavailableError(
                    f"backend 'webgpu' could not open the adapter {a.summary!r} ({exc}); "
                    "use --backend numpy") from exc
            module = device.create_shader_module(code=WGSL_SEARCH)
            _state["pipelines"] = {
                name: device.create_compute_pipeline(
                    layout="auto", compute={"module": module, "entry_point": name})
                for name in ("count", "emit")}
            _state["device"] = device
            _state["wgpu"] = wgpu
            _state["buffers"] = {}
        return _state["device"], _state["pipelines"]


def make_tiles(proj: Projection):
    """Split every active triangle's bounding box into tiles.

    Parameters
    ----------
    proj : Projection

    Returns
    -------
    tiles : (n, TILE_WORDS) uint32
        The records the shader reads (see ``WGSL_SEARCH``).
    area : (n,) int64
        Columns in each tile, an upper bound on its crossings.
    """
    width = np.maximum(proj.imax - proj.imin + 1, 0)
    height = np.maximum(proj.jmax - proj.jmin + 1, 0)
    tx = -(-width // TILE)
    ty = -(-height // TILE)
    per = tx * ty
    n = int(per.sum())
    if n == 0:
        return np.zeros((0, TILE_WORDS), np.uint32), np.zeros(0, np.int64)
    if int(per.max()) == 1:  # the usual case: every triangle is one tile
        t = np.flatnonzero(per)
        i0, j0 = proj.imin[t], proj.jmin[t]
        w, h = width[t], height[t]
    else:
        t = np.repeat(np.arange(len(per)), per)
        local = np.arange(n, dtype=np.int64) - np.repeat(np.cumsum(per) - per, per)
        i0 = proj.imin[t] + TILE * (local % tx[t])
        j0 = proj.jmin[t] + TILE * (local // tx[t])
        w = np.minimum(TILE, proj.imax[t] + 1 - i0)
        h = np.minimum(TILE, proj.jmax[t] + 1 - j0)
    cf = proj.coef[t]  # (n, 3, 3): K0, Ki, Kj per edge
    rec = np.empty((n, TILE_WORDS // 2), np.int64)
    # Exact int64: the edge values of columns in the bounding box are far
    # below 2**63 (see geovox.exact).
    rec[:, 0:3] = cf[:, :, 0] + cf[:, :, 1] * i0[:, None] + cf[:, :, 2] * j0[:, None]
    rec[:, 3:6] = cf[:, :, 1]
    rec[:, 6:9] = cf[:, :, 2]
    # Two u32 words in one int64, low word first (little-endian).
    rec[:, 9] = t | (i0 << 32)
    rec[:, 10] = j0 | ((w | (h << 16)) << 32)
    return rec.view(np.uint32), w * h


def _chunks(area: np.ndarray, max_hits: int, max_tiles: int):
    """Consecutive tile ranges ``(start, stop, bound)`` whose summed area fits."""
    ends = np.cumsum(area)
    start, base = 0, 0
    while start < len(area):
        stop = int(np.searchsorted(ends, base + max_hits, side="right"))
        stop = min(max(stop, start + 1), start + max_tiles)
        yield start, stop, int(ends[stop - 1] - base)
        base = int(ends[stop - 1])
        start = stop


def _buffer(name: str, nbytes: int, usage):
    """A device buffer of at least ``nbytes``, kept and grown between calls."""
    device = _state["device"]
    buffers = _state["buffers"]
    old = buffers.get(name)
    if old is None or old.size < nbytes:
        if old is not None:
            old.destroy()
        # Grow by doubling (capped by the caller's limit) so that calls on
        # similar lattices reuse one buffer.
        size = max(nbytes, 2 * old.size if old is not None else 0, 256)
        size = min(size, max(nbytes, _state["max_binding"]))
        buffers[name] = device.create_buffer(size=-(-size // 4) * 4, usage=usage)
    return buffers[name]


def search(proj: Projection, max_hits: int | None = None) -> np.ndarray:
    """Every (ray, active triangle) crossing with its exact edge values.

    Parameters
    ----------
    proj : Projection
    max_hits : int, optional
        Crossings per dispatch (default: as many as one storage binding
        holds); smaller values only split the work into more dispatches.

    Returns
    -------
    (m, 4) int64
        Per crossing: ``ray | triangle << 32`` (``triangle`` indexes the active
        triangles of ``proj``), then the tie-resolved edge values ``w0, w1,
        w2`` equal to ``proj.edge_values``. Rows are in tile order (active
        triangle, then tile, then row, then column), the same on every run.
    """
    if sys.byteorder != "little":  # the records are read as little-endian int64
        raise BackendUnavailableError("backend 'webgpu' needs a little-endian host")
    columns = proj.columns
    if columns.count >= 1 << 32 or len(proj) >= 1 << 32:
        raise BackendUnavailableError(
            "backend 'webgpu' indexes rays and triangles with 32 bits; this lattice "
            f"({columns.nu} x {columns.nv}) or mesh is larger: use --backend numpy")
    device, _ = _device()
    limits = device.limits
    _state["max_binding"] = int(limits["max-storage-buffer-binding-size"])
    cap_hits = _state["max_binding"] // (4 * HIT_WORDS)
    if max_hits is not None:
        cap_hits = max(TILE * TILE, min(cap_hits, int(max_hits)))
    max_groups = int(limits["max-compute-workgroups-per-dimension"])
    cap_tiles = min(_state["max_binding"] // (4 * TILE_WORDS), max_groups * WORKGROUP)

    tiles, area = make_tiles(proj)
    with _busy:
        try:
            parts = _dispatch(tiles, area, columns.nu, cap_hits, cap_tiles)
        except _state["wgpu"].GPUError as exc:  # out of device memory, device lost, ...
            raise BackendUnavailableError(
                f"backend 'webgpu' failed on the device ({type(exc).__name__}: "
                f"{str(exc).strip().splitlines()[0] if str(exc).strip() else 'no message'}); "
                "use --backend numpy") from exc
    if not parts:
        return np.zeros((0, 4), np.int64)
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def _dispatch(tiles, area, nu, cap_hits, cap_tiles) -> list:
    """Run the two passes over chunks of tiles; the crossing records of each."""
    device, pipelines = _state["device"], _state["pipelines"]
    max_groups = int(device.limits["max-compute-workgroups-per-dimension"])
    usage = _state["wgpu"].BufferUsage
    parts = []
    for start, stop, bound in _chunks(area, cap_hits, cap_tiles):
        ntiles = stop - start
        tile_buf = _buffer("tiles", ntiles * TILE_WORDS * 4, usage.STORAGE | usage.COPY_DST)
        hit_buf = _buffer("hits", bound * HIT_WORDS * 4, usage.STORAGE | usage.COPY_SRC)
        count_buf = _buffer("counts", ntiles * 4,
                            usage.STORAGE | usage.COPY_DST | usage.COPY_SRC)
        params = _buffer("params", 16, usage.UNIFORM | usage.COPY_DST)
        device.queue.write_buffer(tile_buf, 0, np.ascontiguousarray(tiles[start:stop]))
        device.queue.write_buffer(params, 0, np.array([ntiles, nu, 0, 0], np.uint32))
        groups = -(-ntiles // WORKGROUP)
        gx = min(groups, max_groups)

        def run(entry):
            pipeline = pipelines[entry]
            bind = device.create_bind_group(layout=pipeline.get_bind_group_layout(0), entries=[
                {"binding": b, "resource": {"buffer": buf, "offset": 0, "size": size}}
                for b, buf, size in ((0, tile_buf, ntiles * TILE_WORDS * 4),
                                     (1, hit_buf, hit_buf.size),
                                     (2, count_buf, ntiles * 4),
                                     (3, params, 16))
                # layout="auto" keeps only the bindings the entry point uses.
                if entry == "emit" or b != 1])
            encoder = device.create_command_encoder()
            cpass = encoder.begin_compute_pass()
            cpass.set_pipeline(pipeline)
            cpass.set_bind_group(0, bind)
            cpass.dispatch_workgroups(gx, -(-groups // gx), 1)
            cpass.end()
            device.queue.submit([encoder.finish()])

        run("count")
        # The blocking read is the sync point (on_submitted_work_done_sync
        # raises TypeError in wgpu 0.32.0).
        counts = np.frombuffer(device.queue.read_buffer(count_buf, 0, ntiles * 4), np.uint32)
        ends = np.cumsum(counts, dtype=np.int64)
        found = int(ends[-1])
        if found > bound:  # cannot happen: a tile has at most `area` crossings
            raise RuntimeError(f"webgpu search overflowed its output ({found} > {bound})")
        if not found:
            continue
        device.queue.write_buffer(count_buf, 0, (ends - counts).astype(np.uint32))
        device.queue.write_buffer(params, 0, np.array([ntiles, nu, found, 0], np.uint32))
        run("emit")
        data = device.queue.read_buffer(hit_buf, 0, found * HIT_WORDS * 4)
        parts.append(np.frombuffer(data, np.int64).reshape(found, 4))
    return parts


def to_hits(proj: Projection, records: np.ndarray, jobs: int = 1) -> Hits:
    """Hits from :func:`search`'s records: depth and barycentrics on the host.

    ``Projection.interpolate`` in float64, as in every backend, so the depths
    are bit for bit those of the NumPy backend.

    Parameters
    ----------
    proj : Projection
        The projection the records were searched in.
    records : (m, 4) int64
        From :func:`search`.
    jobs : int
        Threads for the interpolation (the result does not depend on it).

    Returns
    -------
    Hits
        In the records' order.
    """
    m = len(records)
    ray = records[:, 0] & np.int64(0xFFFFFFFF)
    t = records[:, 0] >> np.int64(32)
    depth = np.empty(m, np.float64)
    bary = np.empty((m, 2), np.float64)

    def block(a, b):
        depth[a:b], bary[a:b] = proj.interpolate(t[a:b], records[a:b, 1:4])

    for_blocks(block, m, HOST_BLOCK, jobs)
    return Hits(ray=ray, depth=depth, triangle=proj.tri[t], bary=bary)


class WebgpuBackend(Backend):
    """Exact pair search on a WebGPU adapter (GPU, or lavapipe in software)."""

    name = "webgpu"

    def __init__(self):
        # Only the package here (the registry turns its ImportError into the
        # install hint); a missing adapter is reported by cast(), with the
        # driver to install.
        import wgpu  # noqa: F401

    def cast(self, mesh, columns: Columns, jobs: int = 1) -> Hits:
        proj = Projection(mesh.triangles, columns)
        if len(proj) == 0:
            return Hits.empty()
        return to_hits(proj, search(proj), jobs=jobs)
