"""The sub-package layout (issue 21): every old import path still works, as the same module.

``geovox.obj`` and the other moved modules are one module object under two names; the
packages ``geovox.inside``, ``geovox.colour`` and ``geovox.cli`` show their main module's
names live, and refuse a patch that their module's code would not see. ``geovox.mesh``, the
loader before it was the data model (the old ``geovox.surface``), shows the loader's names
(``geovox.io.load``) the same way, importing the loader only when one is asked for. Nothing
is left at an old path, so git follows each move as a whole-file rename.
"""

import importlib
import importlib.util
import os
import subprocess
import sys

import pytest

import geovox

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: old module -> new module, for every module the layout moved
MOVED = {
    "geovox.obj": "geovox.io.obj",
    "geovox.gltf": "geovox.io.gltf",
    "geovox.ply": "geovox.io.ply",
    "geovox.threemf": "geovox.io.threemf",
    "geovox.references": "geovox.io.references",
    "geovox.repair": "geovox.inside.repair",
    "geovox.nearest": "geovox.colour.nearest",
    "geovox.surface": "geovox.mesh",
}
#: module that became a package -> the module whose names the package shows
PACKAGES = {
    "geovox.colour": "geovox.colour.shading",
    "geovox.cli": "geovox.cli.commands",
}
#: the loader's names that code, tests, benchmarks and docs reached as geovox.mesh.X
LOADER_NAMES = ["load_mesh", "readable_extensions", "from_trimesh", "_trimesh_load"]


def test_the_alias_table_is_the_layout():
    assert geovox._MOVED == MOVED


@pytest.mark.parametrize("old", sorted(MOVED) + sorted(PACKAGES))
def test_no_file_is_left_at_an_old_path(old):
    path = os.path.join(ROOT, *old.split("."))
    assert not os.path.exists(path + ".py"), path
    if old in PACKAGES:
        assert os.path.isfile(os.path.join(path, "__init__.py"))


@pytest.mark.parametrize("old, new", sorted(MOVED.items()))
def test_an_old_path_is_the_same_module(old, new):
    by_old = importlib.import_module(old)
    assert by_old is importlib.import_module(new) is sys.modules[old] is sys.modules[new]
    assert by_old.__name__ == new and by_old.__spec__.name == new  # its own spec, kept
    assert getattr(geovox, old.rsplit(".", 1)[1]) is by_old  # `from geovox import obj`


def test_old_from_imports():
    from geovox import nearest, obj, repair
    from geovox.gltf import fan_faces
    from geovox.nearest import nearest_inside
    from geovox.obj import read_obj
    from geovox.ply import read_plain_ply
    from geovox.references import locate
    from geovox.repair import repair as repair_fn
    from geovox.threemf import flatten

    assert read_obj is obj.read_obj is geovox.io.obj.read_obj
    assert nearest_inside is nearest.nearest_inside is geovox.colour.nearest.nearest_inside
    assert repair_fn is repair.repair is geovox.inside.repair.repair
    assert fan_faces is geovox.io.gltf.fan_faces and read_plain_ply is geovox.io.ply.read_plain_ply
    assert locate is geovox.io.references.locate and flatten is geovox.io.threemf.flatten


@pytest.mark.parametrize("package, module", sorted(PACKAGES.items()))
def test_a_package_shows_its_modules_names(package, module):
    pkg, mod = importlib.import_module(package), importlib.import_module(module)
    names = [n for n in vars(mod) if not n.startswith("__")]
    assert names
    for name in names:
        assert getattr(pkg, name) is getattr(mod, name), name
    assert set(names) <= set(dir(pkg))
    with pytest.raises(AttributeError, match="no attribute 'not_a_name'"):
        pkg.not_a_name  # noqa: B018


def test_old_names_of_the_packages():
    from geovox.cli import build_parser, main, main_exit
    from geovox.colour import colour_volume, exact_colours, relevant_crossings, shade

    assert main is geovox.cli.commands.main and main_exit is geovox.cli.commands.main_exit
    assert build_parser is geovox.cli.commands.build_parser
    assert colour_volume is geovox.colour.shading.colour_volume
    assert (exact_colours, relevant_crossings, shade) == (
        geovox.colour.shading.exact_colours, geovox.colour.shading.relevant_crossings,
        geovox.colour.shading.shade)


@pytest.mark.parametrize("package, name", [("geovox.colour", "CHUNK_VOXELS"),
                                           ("geovox.cli", "main")])
def test_a_patch_of_the_package_is_refused_with_where_to_set_it(monkeypatch, package, name):
    pkg = importlib.import_module(package)
    before = getattr(pkg, name)
    with pytest.raises(AttributeError, match=rf"set it there") as caught:
        monkeypatch.setattr(pkg, name, object())
    assert f"{PACKAGES[package]}.{name}" in str(caught.value)
    monkeypatch.undo()  # putting back the value it shows is no copy, and no error
    with pytest.raises(AttributeError, match="set it there"):
        delattr(pkg, name)
    assert getattr(pkg, name) is before and name not in vars(pkg)


def test_a_package_keeps_its_own_names_and_submodules():
    import geovox.colour
    import geovox.colour.nearest

    assert geovox.colour.nearest is sys.modules["geovox.colour.nearest"]
    geovox.colour.own_name_for_this_test = 1  # not the module's: the package's own
    try:
        assert vars(geovox.colour)["own_name_for_this_test"] == 1
    finally:
        del geovox.colour.own_name_for_this_test


def test_old_paths_in_a_fresh_process_import_lazily_and_warn_nothing():
    code = ("import sys, warnings\nwarnings.simplefilter('error')\nimport geovox\n"
            "assert not [m for m in sys.modules if m.startswith(('geovox.io', 'geovox.inside',"
            " 'geovox.colour', 'geovox.cli'))], 'imported at import geovox'\n"
            "import geovox.obj, geovox.nearest, geovox.repair\n"
            "from geovox.inside import choose\nfrom geovox.colour import shade\n"
            "from geovox.cli import main\nassert geovox.obj is geovox.io.obj\nprint('ok')\n")
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-W", "error", "-c", code], capture_output=True,
                         text=True, env=env, cwd=ROOT)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_the_console_script_and_python_dash_m_still_reach_main():
    with open(os.path.join(ROOT, "pyproject.toml"), encoding="utf-8") as f:
        assert 'geovox = "geovox.cli:main_exit"' in f.read()
    module, _, name = "geovox.cli:main_exit".partition(":")
    assert getattr(importlib.import_module(module), name) is geovox.cli.commands.main_exit
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-m", "geovox", "--version"], capture_output=True,
                         text=True, env=env, cwd=ROOT)
    assert out.returncode == 0 and geovox.__version__ in out.stdout + out.stderr, out.stderr


@pytest.mark.parametrize("package", ["io", "inside", "colour", "cli"])
def test_relative_imports_in_the_sub_packages_name_real_modules(package):
    # An edit merged in from a branch that still had the module at geovox/X.py may bring a
    # `from .errors import ...` (one level: geovox/<package>/errors, which does not exist),
    # often inside a function, where it fails only on the path that runs it.
    import ast

    folder = os.path.join(ROOT, "geovox", package)
    for name in sorted(os.listdir(folder)):
        if not name.endswith(".py"):
            continue
        with open(os.path.join(folder, name), encoding="utf-8") as f:
            tree = ast.parse(f.read())
        for node in ast.walk(tree):
            if not (isinstance(node, ast.ImportFrom) and node.level):
                continue
            where = f"geovox/{package}/{name}:{node.lineno}"
            parent = "geovox" + f".{package}" * (node.level == 1)
            if node.module is None:  # from .. import x: a module or a name of the package
                pkg = importlib.import_module(parent)
                for alias in node.names:
                    assert hasattr(pkg, alias.name) or importlib.util.find_spec(
                        f"{parent}.{alias.name}"), f"{where}: {parent}.{alias.name}"
            else:
                assert importlib.util.find_spec(f"{parent}.{node.module}"), (
                    f"{where}: {'.' * node.level}{node.module} is not a module")


def test_the_data_model_is_geovox_mesh_and_geovox_surface_is_it():
    import geovox.io.load
    import geovox.mesh
    from geovox.surface import Material, Mesh, build_mesh, check_mesh, texels

    assert geovox.mesh.__file__ == os.path.join(ROOT, "geovox", "mesh.py")
    assert geovox.io.load.__file__ == os.path.join(ROOT, "geovox", "io", "load.py")
    assert (Material, Mesh, build_mesh, check_mesh, texels) == (
        geovox.mesh.Material, geovox.mesh.Mesh, geovox.mesh.build_mesh, geovox.mesh.check_mesh,
        geovox.mesh.texels)
    assert Mesh.__module__ == "geovox.mesh" and geovox.Mesh is Mesh
    assert geovox.io.load.Mesh is Mesh  # the loader builds the data model's Mesh, not a copy


@pytest.mark.parametrize("name", LOADER_NAMES)
def test_geovox_mesh_still_gives_the_loaders_names(name):
    import geovox.io
    import geovox.io.load
    import geovox.mesh

    assert getattr(geovox.mesh, name) is getattr(geovox.io.load, name)
    assert name in dir(geovox.mesh) and name not in vars(geovox.mesh)  # forwarded, not a copy
    if not name.startswith("_"):
        assert getattr(geovox.io, name) is getattr(geovox.io.load, name)


def test_every_loader_name_is_reached_through_geovox_mesh():
    import geovox.io.load
    import geovox.mesh

    for name in vars(geovox.io.load):
        if not name.startswith("__"):
            assert getattr(geovox.mesh, name) is getattr(geovox.io.load, name), name
    from geovox.mesh import from_trimesh, load_mesh, readable_extensions

    assert (load_mesh, from_trimesh, readable_extensions) == (
        geovox.io.load.load_mesh, geovox.io.load.from_trimesh, geovox.io.load.readable_extensions)
    assert geovox.load_mesh is load_mesh
    with pytest.raises(AttributeError, match="'geovox.mesh' has no attribute 'not_a_name'"):
        geovox.mesh.not_a_name  # noqa: B018


def test_a_patch_of_the_loader_is_seen_through_geovox_mesh_and_by_the_pipeline(monkeypatch):
    import geovox.io.load
    import geovox.mesh

    seen = []
    real = geovox.io.load.load_mesh

    def counting(*a, **k):
        seen.append(a[0])
        return real(*a, **k)

    monkeypatch.setattr(geovox.io.load, "load_mesh", counting)
    assert geovox.mesh.load_mesh is counting
    path = os.path.join(ROOT, "data", "spot", "spot.obj")
    geovox.voxelize(path, resolution=8)
    # The pipeline reads the loader where the patch was set (a loaded Mesh handed on to a
    # later stage's load_mesh passes through: only the path is a load).
    assert [s for s in seen if not isinstance(s, geovox.Mesh)] == [path]
    monkeypatch.undo()
    assert geovox.mesh.load_mesh is real


def test_a_patch_of_a_loader_name_on_geovox_mesh_is_refused(monkeypatch):
    import geovox.mesh

    before = geovox.mesh.load_mesh
    with pytest.raises(AttributeError, match="set it there") as caught:
        monkeypatch.setattr(geovox.mesh, "load_mesh", object())
    assert "geovox.io.load.load_mesh" in str(caught.value)
    monkeypatch.undo()
    assert geovox.mesh.load_mesh is before and "load_mesh" not in vars(geovox.mesh)
    monkeypatch.setattr(geovox.mesh, "WRAP_MODES", {})  # the data model's own: a plain patch
    assert geovox.mesh.WRAP_MODES == {}


def test_the_data_model_imports_without_the_loader():
    # The loader imports the data model; the data model names the loader and imports it only
    # when a loader name is asked for, so `from geovox.mesh import Mesh` (report, inside)
    # stays light and there is no import cycle, in either order.
    code = ("import sys\nimport geovox.mesh\n"
            "assert 'geovox.io.load' not in sys.modules and 'geovox.io' not in sys.modules\n"
            "from geovox.surface import Mesh\nassert Mesh is geovox.mesh.Mesh\n"
            "assert 'geovox.io.load' not in sys.modules\n"
            "f = geovox.mesh.load_mesh\nassert f is sys.modules['geovox.io.load'].load_mesh\n"
            "print('ok')\n")
    first_the_loader = "import geovox.io.load\nimport geovox.mesh\nprint('ok')\n"
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for c in (code, first_the_loader):
        out = subprocess.run([sys.executable, "-W", "error", "-c", c], capture_output=True,
                             text=True, env=env, cwd=ROOT)
        assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
