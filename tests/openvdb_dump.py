"""Read a .vdb with OpenVDB's own Python module and dump every grid into an .npz.

Run by tests/test_vdb.py in a subprocess with the interpreter that has
``pyopenvdb`` (Debian's python3-openvdb is for the system Python), so the
test environment needs no OpenVDB of its own::

    python3 openvdb_dump.py FILE.vdb OUT.npz NX NY NZ
"""

import sys

import numpy as np
import pyopenvdb as vdb

path, out = sys.argv[1], sys.argv[2]
shape = tuple(int(n) for n in sys.argv[3:6])
grids, file_meta = vdb.readAll(path)
arrays = {"grid_names": np.array([g.name for g in grids])}
for g in grids:
    vector = isinstance(g, vdb.Vec3SGrid)
    dense = np.zeros(shape + ((3,) if vector else ()), np.float32)
    g.copyToArray(dense, ijk=(0, 0, 0))
    # Active voxels and tiles, each as its index-space box.
    active = np.zeros(shape, bool)
    for item in g.iterOnValues():
        (x0, y0, z0), (x1, y1, z1) = item["min"], item["max"]
        active[max(x0, 0):x1 + 1, max(y0, 0):y1 + 1, max(z0, 0):z1 + 1] = True
    t = g.transform
    bbox = g.evalActiveVoxelBoundingBox()
    prefix = g.name + "/"
    arrays.update({
        prefix + "values": dense,
        prefix + "active": active,
        prefix + "count": np.int64(g.activeVoxelCount()),
        prefix + "leaves": np.int64(g.leafCount()),
        prefix + "class": np.array(str(g.gridClass)),
        prefix + "type": np.array(g.valueTypeName),
        prefix + "background": np.asarray(g.background, np.float32),
        prefix + "bbox": np.array(bbox, dtype=np.int64),
        prefix + "meta_bbox": np.array([g.metadata.get("file_bbox_min", (0, 0, 0)),
                                        g.metadata.get("file_bbox_max", (-1, -1, -1))], np.int64),
        prefix + "meta_count": np.int64(g.metadata.get("file_voxel_count", -1)),
        # World positions of index points (0,0,0), (1,0,0), (0,1,0), (0,0,1).
        prefix + "world": np.array([t.indexToWorld(p) for p in
                                    [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)]]),
    })
np.savez(out, **arrays)
