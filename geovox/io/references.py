"""Files a model refers to: one rule for every format.

A model file may name other files: an OBJ its ``mtllib`` and ``map_Kd``
images, a glTF its buffers and images, a COLLADA or PLY its textures. Every
reader of geovox finds them here, under one of two rules:

``"anywhere"`` (the default)
    A relative name is looked up from the model's folder, ``..`` included
    (``../textures/wood.png``), and an absolute name where it says.
``"folder"``
    Only files under the model's own folder are read, for services that
    convert files they did not make. A name that leaves the folder (an
    absolute path, a ``..`` escape, a symbolic link pointing out) is not
    read; the reference is said in a warning and the file counts as
    missing (a material falls back to its colour).

Under both rules a name whose file is not where it says is also looked for
beside the model by its bare name (files exported on another machine name
``C:\\Users\\...\\wood.png``); that file is inside the folder, so both rules
read it. URLs (``https://...``, ``file://...``) are never fetched.
"""

from __future__ import annotations

import os
import re

from ..errors import ParameterError
from ..options import References

__all__ = ["RULES", "check_rule", "is_url", "inside", "Refused", "why_not_read", "instead",
           "locate", "data_uri", "resolver"]

#: The rules :func:`check_rule` accepts.
RULES = tuple(References)

# "https://", "file://", "s3://": a URL (one letter would be a Windows drive, "C:/x").
_URL = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]+://")


def check_rule(references) -> str:
    """``references`` validated: ``"anywhere"`` or ``"folder"`` (None: the default)."""
    if references is None:
        return "anywhere"
    if references not in RULES:
        raise ParameterError(f"`references` must be 'anywhere' or 'folder', got {references!r}")
    return references


def is_url(name: str) -> bool:
    """Whether a reference is a URL (never fetched), not a file name."""
    return bool(_URL.match(name.strip()))


def inside(path: str, folder: str) -> bool:
    """Whether ``path`` lies under ``folder`` once symbolic links and ``..`` are resolved."""
    real, root = os.path.realpath(path), os.path.realpath(folder)
    return real == root or real.startswith(root.rstrip(os.sep) + os.sep)


class Refused(FileNotFoundError):
    """A reference not read under the rule; its text is geovox's own line about it."""


def why_not_read(name: str) -> str:
    """Why a refused reference was not read: a URL, or a file outside the model's folder."""
    if is_url(name.strip()):
        return "it is a URL, and geovox never fetches URLs"
    if os.path.isabs(name.strip().strip('"').replace("\\", "/")):
        return ("it is an absolute path, and with references='folder' only files under the "
                "model's folder are read, by relative names")
    return ("it lies outside the model's folder, and with references='folder' only files under "
            "that folder are read")


def instead(name: str, found: str) -> str:
    """What was read for a refused reference that has a file of its bare name beside the model."""
    return (f"{name!r} is not read ({why_not_read(name)}); {os.path.basename(found)!r} beside "
            f"the model is read instead")


def locate(name: str, folder: str, rule: str, root: str | None = None) -> tuple:
    """Find the file a model names.

    Parameters
    ----------
    name : str
        The reference as written (backslashes, quotes and surrounding spaces
        allowed; no URL escapes).
    folder : str
        The folder relative names start from (the model's, or that of the
        material file naming a texture).
    rule : {"anywhere", "folder"}
    root : str, optional
        The model's folder, which ``"folder"`` keeps reads under (default
        ``folder``).

    Returns
    -------
    (path, refused) : (str or None, bool)
        The file to read, or None where none is found; ``refused`` is True
        when the name as written is a URL, or under ``"folder"`` leaves
        ``root``. A refused name may still give a path: the file of its
        bare name beside the model.
    """
    name = name.strip().strip('"').replace("\\", "/")
    root = folder if root is None else root
    refused = is_url(name) or rule == "folder" and (
        os.path.isabs(name) or not inside(os.path.join(folder, name), root))
    candidates = [] if refused else [name] if os.path.isabs(name) else []
    if not refused:
        candidates.append(os.path.join(folder, name))
    candidates.append(os.path.join(folder, os.path.basename(name)))
    for c in candidates:
        if os.path.isfile(c):
            if rule != "folder" or inside(c, root):
                return c, refused
            refused = True  # a symbolic link in the folder that points out of it
    try:
        lower = os.path.basename(name).lower()
        for entry in os.listdir(folder):
            c = os.path.join(folder, entry)
            if entry.lower() == lower and os.path.isfile(c) and (rule != "folder"
                                                                  or inside(c, root)):
                return c, refused
    except OSError:
        pass
    return None, refused


def data_uri(uri: str) -> bytes:
    """The bytes of a ``data:`` URI (base64 or percent-escaped); never a file, so always read.

    Raises
    ------
    ValueError
        Base64 that does not decode.
    """
    import base64
    import binascii
    import urllib.parse

    head, _, payload = uri.partition(",")
    if not head.endswith(";base64"):
        return urllib.parse.unquote_to_bytes(payload)
    try:
        return base64.b64decode(payload)
    except (binascii.Error, ValueError):
        raise ValueError("base64 that does not decode") from None


def resolver(path: str, rule: str, said: list):
    """A trimesh resolver for the files the model ``path`` names, under ``rule``.

    For each reference it does not read it appends ``(name, line)`` to
    ``said`` (the line: geovox's own words about it) and raises
    :class:`Refused`, which trimesh's readers take as a missing file; a
    refused name read from beside the model instead is said there too.
    """
    import trimesh

    folder = os.path.dirname(os.path.abspath(path))

    class _Resolver(trimesh.resolvers.FilePathResolver):
        def get(self, name):
            found, refused = locate(name, folder, rule)
            if refused:
                line = (instead(name, found) if found is not None
                        else f"{name!r} is not read: {why_not_read(name)}")
                said.append((name, line))
                if found is None:
                    raise Refused(line)
            if found is None:
                raise FileNotFoundError(name)
            with open(found, "rb") as f:
                return f.read()

        def namespaced(self, namespace):
            return self  # names stay relative to the model's folder

    return _Resolver(path, allow_anywhere=True)
