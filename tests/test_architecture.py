"""The house rules, checked on the code itself: what may import what, and one identity per module."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

#: Top-level modules a layer must never import.
BANNED = {
    "garment_transfer": {"bpy", "mathutils", "bmesh", "lab", "scripts", "benchmarks", "operators", "ui"},
    "lab": {"operators", "ui", "scripts", "benchmarks"},
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


def test_blender_layer_does_no_geometry():
    """operators/ and ui/ read objects and call the core: no scipy, no geometry of their own."""
    wrong = []
    for layer in ("operators", "ui"):
        for path in (ROOT / layer).rglob("*.py"):
            wrong += [f"{path.relative_to(ROOT)}:{line} imports {mod}"
                      for line, mod in imported_top_levels(path) if mod in {"scipy", "lab"}]
    assert not wrong, "\n".join(wrong)


def test_installed_core_is_this_checkout():
    """pip install -e . gives one garment_transfer: the one in this repository, from any folder."""
    code = "import garment_transfer, lab; print(garment_transfer.__file__); print(lab.__file__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd="/",
                         check=True).stdout.split()
    assert Path(out[0]).resolve() == ROOT / "garment_transfer" / "__init__.py"
    assert Path(out[1]).resolve() == ROOT / "lab" / "__init__.py"


def test_checkout_extension_shares_the_installed_core():
    """The extension loaded from the checkout (as the Blender tests and the batch script do) imports
    the installed core, not a second copy: one MeshError class in the process."""
    code = (
        "import sys; sys.path.insert(0, 'scripts')\n"
        "import importlib, garment_transfer.errors as e\n"
        "from extension_loader import _CoreAlias, load_extension\n"
        "sys.meta_path.insert(0, _CoreAlias('probe'))\n"
        "import types; pkg = types.ModuleType('probe'); pkg.__path__ = ['.']; sys.modules['probe'] = pkg\n"
        "m = importlib.import_module('probe.garment_transfer.errors')\n"
        "assert m is e and m.__spec__.name == 'garment_transfer.errors', m.__spec__\n"
        "assert importlib.import_module('probe.garment_transfer') is importlib.import_module('garment_transfer')\n"
        "print('ok')\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert p.stdout.strip() == "ok", p.stderr
