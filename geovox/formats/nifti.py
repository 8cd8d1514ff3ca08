"""NIfTI-1 (``.nii``, ``.nii.gz``) via nibabel: masks that open aligned with the scan.

The sform and the qform are both the grid's RAS affine (index of a voxel
centre -> world), with code 1 (scanner); occupancy is ``uint8`` 0/1, colour
``NAME_rgba.nii[.gz]`` (NIfTI's RGBA32), density and distance
``NAME_density`` / ``NAME_sdf`` beside it. On a grid over the mesh (no
``like``) the mesh's coordinates are taken as LPS, 3D Slicer's convention
for meshes, so the RAS affine flips x and y. Labels (``labels=``) go to
``NAME_labels.nii[.gz]`` (uint8, or uint16 above 255 labels; 0 the
background) with ``intent_code`` NIFTI_INTENT_LABEL (1002), the label table
as JSON in a NIfTI comment extension (code 6), which nibabel, ITK and 3D Slicer
keep and ignore.
"""

from __future__ import annotations

import os

import numpy as np

#: NIfTI's xform code for both forms: scanner-based anatomical coordinates.
XFORM_CODE = 1


def _nibabel():
    try:
        import nibabel
    except ImportError:
        from ..errors import BackendUnavailableError

        raise BackendUnavailableError("writing or reading NIfTI needs nibabel: "
                                      "pip install 'geovox[nifti]'") from None
    return nibabel


def ras_affine(volume) -> np.ndarray:
    """(4, 4) float64: index of a voxel centre -> RAS world for ``volume``'s grid."""
    from ..reference import RAS_FROM_LPS
    from .headers import origin_of

    ref = getattr(volume.grid, "reference", None)
    if ref is not None:
        return ref.affine_in("RAS")
    lps = np.eye(4)
    lps[:3, :3] = np.diag(np.asarray(volume.spacing, dtype=np.float64))
    lps[:3, 3] = origin_of(volume)
    return RAS_FROM_LPS @ lps


#: NIfTI extension code of a comment: where the label table goes, as JSON.
COMMENT = 6


def _image(nibabel, data, affine, description: str, table=None):
    img = nibabel.Nifti1Image(data, affine)
    hdr = img.header
    if table is not None:  # a label map: NIFTI_INTENT_LABEL, the table as a comment
        from .base import label_table_json

        hdr.set_intent("label")
        hdr.extensions.append(nibabel.nifti1.Nifti1Extension(
            COMMENT, label_table_json(table).encode("utf-8")))
    hdr.set_sform(affine, code=XFORM_CODE)
    hdr.set_qform(affine, code=XFORM_CODE)
    hdr.set_xyzt_units("mm")
    hdr["descrip"] = description.encode("ascii", "replace")[:79]
    return img


def field_path(path: str, name: str) -> str:
    """``NAME_rgba.nii.gz`` beside ``NAME.nii.gz`` (the double extension kept)."""
    lower = path.lower()
    ext = ".nii.gz" if lower.endswith(".nii.gz") else ".nii"
    return f"{path[:-len(ext)]}_{name}{path[-len(ext):]}"


def write_nifti(volume, path) -> list:
    """``NAME.nii[.gz]`` (uint8 0/1 mask), with ``_rgba``, ``_density``, ``_sdf`` as present."""
    from .base import atomic_outputs, scalar_fields

    nibabel = _nibabel()
    path = os.fspath(path)
    affine = ras_affine(volume)
    parts = [(path, volume.occupancy.view(np.uint8), "geovox mask: 1 inside")]
    if volume.colors is not None:
        rgba = np.ascontiguousarray(volume.colors).view(
            [("R", "u1"), ("G", "u1"), ("B", "u1"), ("A", "u1")])[..., 0]
        parts.append((field_path(path, "rgba"), rgba, "geovox colour RGBA"))
    for name, arr, _, values in scalar_fields(volume):
        parts.append((field_path(path, name), arr, f"geovox {name}: {values}"))
    written = []
    with atomic_outputs() as group:
        for target, data, description in parts:
            tmp = group.add(target)
            # nibabel picks gzip from the name; the temporary one ends in .tmp.
            labelled = target == field_path(path, "labels")
            img = _image(nibabel, data, affine, description, volume if labelled else None)
            with open(tmp, "wb") as f:
                if target.lower().endswith(".gz"):
                    import gzip

                    with gzip.GzipFile(fileobj=f, mode="wb", compresslevel=1, mtime=0) as gz:
                        gz.write(img.to_bytes())
                else:
                    f.write(img.to_bytes())
            written.append(target)
    return written


def read_nifti(path):
    """A Volume from a NIfTI mask (any 3-D NIfTI: inside where the value is > 0).

    The ``_rgba``, ``_density``, ``_sdf`` and ``_labels`` files beside it are
    read too, the label table from the labels' comment extension.
    """
    from ..reference import load_reference
    from ..volume import Volume

    nibabel = _nibabel()
    ref = load_reference(path)
    data = np.asarray(nibabel.load(path).dataobj).reshape(ref.shape)
    colors = None
    cpath = field_path(os.fspath(path), "rgba")
    if os.path.exists(cpath):
        c = np.asarray(nibabel.load(cpath).dataobj)
        colors = np.stack([c["R"], c["G"], c["B"], c["A"]], axis=-1)
    extra = {}
    for name in ("density", "sdf", "labels"):
        fpath = field_path(os.fspath(path), name)
        if os.path.exists(fpath):
            img = nibabel.load(fpath)
            extra[name] = np.asfortranarray(np.asarray(img.dataobj))
            if name == "labels":
                from .base import table_from_json

                text = next((e.get_content() for e in img.header.extensions
                             if e.get_code() == COMMENT), b"[]")
                extra["label_table"] = table_from_json(text)
    return Volume(occupancy=np.asfortranarray(data > 0), grid=ref.local_grid(), backend="?",
                  source=os.fspath(path), colors=colors, **extra)
