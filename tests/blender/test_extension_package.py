"""The built extension zip: its contents, and installed into a fresh Blender user folder (of the
Blender this test runs under: 4.2 LTS to 5.2), it enables, transfers with the scipy it bundles, and
disables cleanly.

Building needs the bundled packages' wheels for this platform: the first build downloads them from PyPI
into build/wheels/ (kept for later runs); without network and without that cache the test fails and says so.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
import zipfile

import pytest

from conftest import ROOT

sys.path.insert(0, str(ROOT / "tools"))

# The Pythons Blender runs: 3.11 (4.2 LTS to 5.0) and 3.13 (5.1, 5.2).
PYTHONS = [(3, 11), (3, 13)]
# Bundled packages whose module is named otherwise.
IMPORT_NAMES = {"libigl": "igl"}

INSTALL_AND_TRANSFER = r"""
import json, os, sys
import bpy, addon_utils
import numpy as np

zip_path = sys.argv[-1]
assert bpy.ops.extensions.package_install_files(
    filepath=zip_path, repo="user_default", enable_on_install=True) == {'FINISHED'}
out = {"enabled": "bl_ext.user_default.garment_transfer" in bpy.context.preferences.addons}

# Use the scipy, libigl and pyamg the extension installed, not those of the Python running this test.
bundled = os.path.join(os.environ["BLENDER_USER_RESOURCES"], "extensions", ".local", "lib",
                       "python%d.%d" % sys.version_info[:2], "site-packages")
out["installed"] = sorted(n for n in os.listdir(bundled) if n.endswith(".dist-info"))
out["libraries"] = sorted(n for _, _, files in os.walk(bundled) for n in files
                          if ".cpython-" in n or ".abi3." in n or n.endswith(".pyd"))
sys.path.insert(0, bundled)
for name in [m for m in sys.modules if m.split(".")[0] in ("scipy", "igl", "pyamg")]:
    del sys.modules[name]


def sphere(name, radius, scale=(1.0, 1.0, 1.0), upper_only=False):
    rings, segments = 24, 48
    theta = np.linspace(0, np.pi, rings + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    V = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    V = np.vstack([[0, 0, 1], V, [0, 0, -1]]) * radius * np.array(scale)
    faces = []
    ring = lambda i, j: 1 + i * segments + j % segments
    for j in range(segments):
        faces.append((0, ring(0, j), ring(0, j + 1)))
        faces.append((len(V) - 1, ring(rings - 2, j + 1), ring(rings - 2, j)))
    for i in range(rings - 2):
        for j in range(segments):
            faces.append((ring(i, j), ring(i + 1, j), ring(i + 1, j + 1), ring(i, j + 1)))
    if upper_only:
        faces = [f for f in faces if V[list(f), 2].mean() > 0.2 * radius]
        used = sorted({v for f in faces for v in f})
        remap = {v: k for k, v in enumerate(used)}
        V = V[used]
        faces = [tuple(remap[v] for v in f) for f in faces]
    me = bpy.data.meshes.new(name)
    me.from_pydata(V.tolist(), [], faces)
    obj = bpy.data.objects.new(name, me)
    bpy.context.scene.collection.objects.link(obj)
    return obj


s = bpy.context.scene.garment_transfer
s.source_body = sphere("body", 1.0)
s.target_body = sphere("wide", 1.0, scale=(1.25, 1.1, 0.95))
s.garment = sphere("cape", 1.04, upper_only=True)
out["transfer"] = sorted(bpy.ops.garment_transfer.transfer())
out["result"] = s.result.name
import scipy
out["scipy"] = scipy.__file__
out["modules"] = {}
for name, module in json.loads(os.environ["BUNDLED_MODULES"]).items():
    out["modules"][name] = __import__(module).__file__
addon_utils.disable("bl_ext.user_default.garment_transfer")
out["settings_after_disable"] = hasattr(bpy.types.Scene, "garment_transfer")
out["operator_after_disable"] = hasattr(bpy.types, "GARMENT_TRANSFER_OT_transfer")
print("RESULT" + json.dumps(out))
"""


@pytest.fixture(scope="session")
def built_zip(tmp_path_factory):
    from build_extension import current_platform

    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "build_extension.py"),
                           "--platform", current_platform(), "--output-dir", str(out)],
                          capture_output=True, text=True, timeout=600)
    if proc.returncode != 0:
        pytest.fail("building the extension failed (the scipy wheel is downloaded from PyPI once, "
                    f"then kept in build/wheels/):\n{proc.stderr}{proc.stdout}")
    (zip_path,) = out.glob("garment_transfer-*.zip")
    return zip_path


def wheel_pythons(wheel):
    """The CPython versions ((3, 11), (3, 13)) of the two Blender Pythons a wheel file installs on."""
    python_tag, abi_tag = wheel.rsplit("/", 1)[-1][:-4].split("-")[-3:-1]
    built_for = (int(python_tag[2]), int(python_tag[3:]))
    if abi_tag == "abi3":           # the stable ABI: this Python and every later one
        return {p for p in PYTHONS if p >= built_for}
    return {built_for} & set(PYTHONS)


def test_zip_holds_the_add_on_and_the_bundled_wheels_for_each_python(built_zip):
    from build_extension import bundled_packages, current_platform

    with zipfile.ZipFile(built_zip) as zf:
        names = zf.namelist()
        manifest = tomllib.loads(zf.read("blender_manifest.toml").decode())
    assert manifest["id"] == "garment_transfer" and manifest["version"] == "0.1.0"
    assert manifest["blender_version_min"] == "4.2.0"
    assert manifest["build"]["generated"]["platforms"] == [current_platform()]
    wheels = manifest["build"]["generated"]["wheels"]
    assert all(w.startswith("./wheels/") and w[2:] in names for w in wheels)
    assert sorted(n for n in names if n.startswith("wheels/")) == sorted(w[2:] for w in wheels)
    # Every bundled package has exactly one wheel for each of Blender's Pythons, and nothing else.
    packages = bundled_packages()
    assert {name for name, _ in packages} >= {"scipy"}
    for name, version in packages:
        mine = [w for w in wheels if w.rsplit("/", 1)[-1].lower().startswith(f"{name.lower()}-{version}-")]
        covered = [p for w in mine for p in wheel_pythons(w)]
        assert sorted(covered) == sorted(PYTHONS), (name, mine)
    assert len(wheels) == sum(1 for w in wheels for name, version in packages
                              if w.rsplit("/", 1)[-1].lower().startswith(f"{name.lower()}-{version}-"))
    for needed in ("__init__.py", "operators/transfer.py", "operators/convert.py", "ui/panels.py",
                   "garment_transfer/pipeline/transfer.py", "scripts/batch_transfer.py"):
        assert needed in names
    # What the zip holds, and nothing else: the extension's own code and the bundled wheels; no lab, no
    # demo data, no tests or tools.
    top = {n.split("/", 1)[0] for n in names}
    assert top == {"__init__.py", "blender_manifest.toml", "README.md", "operators", "ui", "garment_transfer",
                   "scripts", "wheels"}, top
    assert not any("__pycache__" in n or n.endswith(".obj") or n.endswith(".npz") for n in names)
    assert not any("numpy" in n or "torch" in n for n in names)
    assert not any("extension_loader" in n for n in names)      # the checkout's loader is a tool, not the product
    # Nothing of the development set-up either.
    assert not any(".venv" in n or ".egg-info" in n or n.startswith(("build/", "dist/")) for n in names)
    # The repository's manifest stays without the build's wheels.
    assert "wheels" not in tomllib.loads((ROOT / "blender_manifest.toml").read_text())


def test_installed_zip_enables_transfers_and_disables(built_zip, tmp_path):
    from build_extension import bundled_packages

    # The module each bundled package is imported as (libigl -> igl).
    modules = {name: IMPORT_NAMES.get(name, name) for name, _ in bundled_packages()}
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(tmp_path / "user"), BUNDLED_MODULES=json.dumps(modules))
    proc = subprocess.run([sys.executable, "-c", INSTALL_AND_TRANSFER, str(built_zip)],
                          capture_output=True, text=True, timeout=300, env=env, cwd=tmp_path)
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT")]
    assert proc.returncode == 0 and lines, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = json.loads(lines[-1][len("RESULT"):])
    assert out["enabled"]
    # Only the wheels of this Blender's Python were installed, one of each bundled package.
    here = "cpython-%d%d" % sys.version_info[:2]
    assert sorted(d.split("-")[0].lower() for d in out["installed"]) == sorted(n.lower() for n in modules), \
        out["installed"]
    assert out["libraries"] and all(here in n or ".abi3." in n for n in out["libraries"]), out["libraries"]
    assert out["transfer"] == ["FINISHED"] and out["result"] == "cape_on_wide"
    assert out["scipy"].startswith(str(tmp_path / "user"))
    for name, path in out["modules"].items():
        assert path.startswith(str(tmp_path / "user")), (name, path)
    assert not out["settings_after_disable"] and not out["operator_after_disable"]
