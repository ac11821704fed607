"""The house rules, checked on the code itself: what may import what, the core's layers, no import circle,
one public API, and one identity per module."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "garment_transfer"

#: Top-level modules a layer must never import.
BANNED = {
    "garment_transfer": {"bpy", "mathutils", "bmesh", "lab", "scripts", "benchmarks", "operators", "ui"},
    "lab": {"operators", "ui", "scripts", "benchmarks"},
}

#: The core's layers, from the ground up: each may import itself and the layers listed (``""``: the modules at
#: the package's root, errors, files and version).
LAYERS = {
    "": set(),
    "geometry": {""},
    "fitting": {"", "geometry"},
    "learning": {"", "geometry"},
    "rigging": {"", "geometry"},
    "pipeline": {"", "geometry", "fitting", "learning", "rigging"},
    "cli": {"", "geometry", "fitting", "learning", "rigging", "pipeline"},
}


def imported_top_levels(path: Path):
    """(line, top-level module) of every absolute import in a Python file."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.lineno, node.module.split(".")[0]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def is_module(name: str) -> bool:
    path = ROOT.joinpath(*name.split("."))
    return path.with_suffix(".py").is_file() or (path / "__init__.py").is_file()


def imports_of(path: Path):
    """(line, module, names, in a function body) of every import of a Python file, relative ones resolved to
    absolute module names; ``from package import submodule`` gives the submodule."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module_name(path) if path.name == "__init__.py" else module_name(path).rpartition(".")[0]
    nested = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            nested.update(id(n) for n in ast.walk(node) if n is not node)
    for node in ast.walk(tree):
        inner = id(node) in nested
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, [], inner
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[:len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module
            names = [a.name for a in node.names]
            subs = [f"{module}.{n}" for n in names if is_module(f"{module}.{n}")]
            if len(subs) < len(names):
                yield node.lineno, module, [n for n in names if f"{module}.{n}" not in subs], inner
            for sub in subs:
                yield node.lineno, sub, [], inner


def layer_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "garment_transfer":
        return None
    if len(parts) == 1:
        return "api"
    return parts[1] if (CORE / parts[1]).is_dir() else ""


def python_files(*folders):
    for folder in folders:
        yield from sorted((ROOT / folder).rglob("*.py"))


def test_core_and_lab_import_only_what_their_layer_may():
    wrong = []
    for layer, banned in BANNED.items():
        for path in (ROOT / layer).rglob("*.py"):
            if layer == "lab" and "blender" in path.relative_to(ROOT / layer).parts:
                continue  # lab/blender/ runs inside Blender: bpy is its point.
            wrong += [f"{path.relative_to(ROOT)}:{line} imports {mod}"
                      for line, mod in imported_top_levels(path) if mod in banned]
    assert not wrong, "\n".join(wrong)


def test_the_check_catches_a_banned_import(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("import numpy\nfrom bpy.types import Operator\nfrom . import mesh\n")
    assert [m for _, m in imported_top_levels(bad)] == ["numpy", "bpy"]


def test_the_core_layers_import_only_downwards():
    """geometry <- fitting, learning <- pipeline <- cli; the root modules (errors, files, version) under all."""
    wrong = []
    for path in python_files("garment_transfer"):
        here = layer_of(module_name(path))
        if here == "api" or path.name == "__main__.py":
            continue
        for line, module, _, _ in imports_of(path):
            there = layer_of(module)
            if there is None or there == here:
                continue
            if there == "api" or there not in LAYERS[here]:
                wrong.append(f"{path.relative_to(ROOT)}:{line} ({here or 'root'}) imports {module}")
    assert not wrong, "\n".join(wrong)


def test_no_import_hides_in_a_function_body_in_the_core():
    """The core's own modules are imported at the top of a module: an import inside a function would only hide
    a circle. Optional third-party packages (torch, dask, ...) may be imported where they are used."""
    wrong = [f"{path.relative_to(ROOT)}:{line} imports {module} inside a function"
             for path in python_files("garment_transfer") if path.name != "__main__.py"
             for line, module, _, inner in imports_of(path) if inner and layer_of(module) is not None]
    assert not wrong, "\n".join(wrong)


def circles(folders):
    """Every import circle among the modules of ``folders`` (imports anywhere in a module count)."""
    graph = {}
    for path in python_files(*folders):
        name = module_name(path)
        graph[name] = {m for _, m, _, _ in imports_of(path)
                       if m.split(".")[0] in {f.split("/")[0] for f in folders} and is_module(m) and m != name}
    found, state = [], {}

    def visit(node, stack):
        state[node] = "open"
        stack.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                found.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt, stack)
        stack.pop()
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
    return found


def test_no_import_circle_in_the_core_or_the_lab():
    found = circles(["garment_transfer", "lab"])
    assert not found, "\n".join(" -> ".join(c) for c in found)


def test_the_circle_check_finds_a_circle(tmp_path, monkeypatch):
    pkg = tmp_path / "lab"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("from .b import x\n")
    (pkg / "b.py").write_text("def x():\n    from .a import y\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert circles(["lab"]) == [["lab.a", "lab.b", "lab.a"]]


def test_public_api_lists_only_what_exists():
    import garment_transfer

    missing = [n for n in garment_transfer.__all__ if not hasattr(garment_transfer, n)]
    assert not missing and len(set(garment_transfer.__all__)) == len(garment_transfer.__all__)
    for sub in ("geometry", "fitting", "learning", "rigging", "pipeline", "cli"):
        module = __import__(f"garment_transfer.{sub}", fromlist=["__all__"])
        assert module.__doc__ and len(module.__doc__.split()) > 30, f"garment_transfer.{sub} says what it is"
        assert all(hasattr(module, n) for n in module.__all__), sub


def test_no_private_name_crosses_into_the_core_from_outside():
    """The Blender layer, the lab, the scripts and the tests use the core's public names only."""
    wrong = []
    for path in python_files("operators", "ui", "lab", "scripts", "tools", "tests"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        aliases = {}
        for line, module, names, _ in imports_of(path):
            if layer_of(module) is None:
                continue
            wrong += [f"{path.relative_to(ROOT)}:{line} imports {module}.{n}" for n in names
                      if n.startswith("_") and not n.startswith("__")]
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and "garment_transfer" in node.module:
                aliases.update({a.asname or a.name: node.module for a in node.names})
            elif isinstance(node, ast.Import):
                aliases.update({(a.asname or a.name).split(".")[0]: a.name for a in node.names
                                if a.name.startswith("garment_transfer")})
        wrong += [f"{path.relative_to(ROOT)}:{node.lineno} uses {node.value.id}.{node.attr}"
                  for node in ast.walk(tree)
                  if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                  and node.value.id in aliases and node.attr.startswith("_") and not node.attr.startswith("__")]
    assert not wrong, "\n".join(wrong)


def test_the_blender_layer_uses_only_the_public_api():
    """operators/ and ui/ import the core as ``from ..garment_transfer import name``, names of its ``__all__``:
    no module path, so an installed extension and a checkout load one core."""
    import garment_transfer

    wrong = []
    for path in python_files("operators", "ui"):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level == 2 and (node.module or "").startswith(
                    "garment_transfer"):
                if node.module != "garment_transfer":
                    wrong.append(f"{path.relative_to(ROOT)}:{node.lineno} imports ..{node.module}")
                wrong += [f"{path.relative_to(ROOT)}:{node.lineno} imports {a.name}, not in garment_transfer.__all__"
                          for a in node.names if a.name not in garment_transfer.__all__]
    assert not wrong, "\n".join(wrong)


def test_blender_layer_does_no_geometry():
    """operators/ and ui/ read objects and call the core: no scipy, no geometry of their own."""
    wrong = []
    for layer in ("operators", "ui"):
        for path in (ROOT / layer).rglob("*.py"):
            wrong += [f"{path.relative_to(ROOT)}:{line} imports {mod}"
                      for line, mod in imported_top_levels(path) if mod in {"scipy", "lab"}]
    assert not wrong, "\n".join(wrong)


def test_installed_core_is_this_checkout():
    """pip install -e . gives one garment_transfer: the one in this repository, from any folder; the lab is
    not installed (it runs from the checkout)."""
    code = ("import garment_transfer, importlib.util; print(garment_transfer.__file__); "
            "print(importlib.util.find_spec('lab'))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/",
                         check=True).stdout.split("\n")
    assert Path(out[0]).resolve() == ROOT / "garment_transfer" / "__init__.py"
    assert out[1] == "None"


@pytest.mark.parametrize("where", ["scripts", "operators", "ui", "garment_transfer"])
def test_no_test_loader_ships(where):
    """The extension ships the product: the loader that runs it from a checkout lives in tools/ (not shipped)."""
    assert not [p for p in (ROOT / where).rglob("*.py") if "extension_loader" in p.name]


def test_checkout_extension_shares_the_installed_core():
    """The extension loaded from the checkout (as the Blender tests and the batch script do) uses the installed
    core, not a second copy: one MeshError class in the process, and no import hook."""
    code = (
        "import sys; sys.path.insert(0, 'tools'); hooks = list(sys.meta_path)\n"
        "import importlib, garment_transfer, garment_transfer.errors as e\n"
        "from extension_loader import load_extension\n"
        "ext = load_extension()\n"
        "assert ext.garment_transfer is garment_transfer\n"
        "assert importlib.import_module(ext.__name__ + '.garment_transfer') is garment_transfer\n"
        "assert importlib.import_module(ext.__name__ + '.garment_transfer').MeshError is e.MeshError\n"
        "assert sys.meta_path == hooks, sys.meta_path\n"
        "print('ok')\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert p.stdout.strip() == "ok", p.stderr
