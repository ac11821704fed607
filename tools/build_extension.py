"""Build the Blender extension zip(s): the add-on plus scipy and libigl wheels for each platform.

    .venv/bin/python tools/build_extension.py                         # every platform, into dist/
    .venv/bin/python tools/build_extension.py --platform linux-x64    # one platform

Blender bundles numpy but not scipy or libigl, so each platform's zip carries that platform's
wheels of both (downloaded with pip into build/wheels/, reused on later runs). Torch is not bundled: training asks
the user to install it. The repository's blender_manifest.toml stays as it is: the wheels and platforms
are written into a temporary build copy of the sources, which Blender's own extension tool
(blender_ext.py, shipped inside the bpy module) then validates and builds with --split-platforms.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import os
import platform as host_platform
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# Blender platform -> pip --platform tags. pip extends a macOS tag to older macOS versions; Linux
# wheels of recent scipy are manylinux_2_28 (the glibc Blender 4.2 itself needs), older ones 2014.
# Intel macOS: Blender 4.2 needs macOS 11.2; libigl's wheels need 10.15, scipy's 10.14.
PLATFORM_TAGS = {
    "linux-x64": ["manylinux_2_28_x86_64", "manylinux2014_x86_64"],
    "macos-arm64": ["macosx_12_0_arm64"],
    "macos-x64": ["macosx_11_0_x86_64"],
    "windows-x64": ["win_amd64"],
}
PYTHON_VERSION = "3.11"

# Top-level folders never copied into the build (the manifest's own exclusions apply afterwards).
NOT_COPIED = {".git", ".venv", "build", "dist", "results", "wheels", "__pycache__", ".pytest_cache",
              ".hypothesis", ".ruff_cache"}


class BuildError(Exception):
    pass


def current_platform():
    """The Blender platform name of this machine, e.g. ``linux-x64``."""
    machine = host_platform.machine().lower()
    arch = "arm64" if machine in ("arm64", "aarch64") else "x64"
    system = {"linux": "linux", "darwin": "macos", "win32": "windows"}.get(sys.platform, sys.platform)
    return f"{system}-{arch}"


def find_blender_ext():
    """Path of Blender's blender_ext.py inside the installed bpy module."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise BuildError("the bpy module is not installed in this Python; it carries blender_ext.py "
                         "(pip install bpy==5.0.1, or run with .venv/bin/python)")
    for folder in spec.submodule_search_locations:
        found = sorted(Path(folder).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
        if found:
            return found[-1]
    raise BuildError("blender_ext.py not found inside the bpy module")


def download_wheel(package, version, platform, cache):
    """The wheel of ``package==version`` for a Blender platform, from cache or downloaded by pip."""
    folder = cache / platform
    pattern = f"{package}-{version}-*.whl"
    found = sorted(folder.glob(pattern))
    if found:
        return found[0]
    folder.mkdir(parents=True, exist_ok=True)
    # Download beside the cache and move in when complete: builds running at the same time never
    # see a partial wheel.
    with tempfile.TemporaryDirectory(dir=folder, prefix=".download-") as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--disable-pip-version-check",
               "--only-binary=:all:", "--no-deps", "--python-version", PYTHON_VERSION, "--dest", tmp]
        for tag in PLATFORM_TAGS[platform]:
            cmd += ["--platform", tag]
        cmd.append(f"{package}=={version}")
        proc = subprocess.run(cmd, capture_output=True, text=True)
        got = sorted(Path(tmp).glob(pattern))
        if proc.returncode != 0 or not got:
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-3:]
            raise BuildError(f"could not download the {package} {version} wheel for {platform} "
                             f"(pip download needs access to PyPI): " + " | ".join(tail))
        os.replace(got[0], folder / got[0].name)
    return folder / got[0].name


def manifest_with_wheels(text, wheels, platforms):
    """The manifest text with top-level ``wheels`` and ``platforms`` (before the first table)."""
    lines = text.splitlines()
    first_table = next((i for i, ln in enumerate(lines) if ln.lstrip().startswith("[")), len(lines))
    added = ["platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]",
             "wheels = [", *(f'  "./wheels/{w.name}",' for w in wheels), "]", ""]
    return "\n".join(lines[:first_table] + added + lines[first_table:]) + "\n"


def stage_sources(stage, wheels, platforms):
    """Copy the add-on into the empty folder ``stage`` with the wheels and a manifest listing them."""
    ignore_top = shutil.ignore_patterns(*NOT_COPIED)
    for entry in ROOT.iterdir():
        if entry.name in NOT_COPIED:
            continue
        if entry.is_dir():
            shutil.copytree(entry, stage / entry.name, ignore=ignore_top)
        else:
            shutil.copy2(entry, stage / entry.name)
    (stage / "wheels").mkdir()
    for wheel in wheels:
        shutil.copy2(wheel, stage / "wheels" / wheel.name)
    text = (ROOT / "blender_manifest.toml").read_text(encoding="utf-8")
    (stage / "blender_manifest.toml").write_text(manifest_with_wheels(text, wheels, platforms),
                                                 encoding="utf-8")


def run_blender_ext(blender_ext, *args):
    proc = subprocess.run([sys.executable, str(blender_ext), *args], capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"blender_ext.py {args[0]} failed:\n{proc.stdout}{proc.stderr}")
    return proc.stdout


def build(platforms, output_dir, cache, scipy_version=None, log=print):
    """Build one zip per platform into ``output_dir``; return their paths."""
    unknown = [p for p in platforms if p not in PLATFORM_TAGS]
    if unknown:
        raise BuildError(f"unknown platform(s) {unknown}; choose from {sorted(PLATFORM_TAGS)}")
    bundled = [("scipy", scipy_version or importlib.metadata.version("scipy")),
               ("libigl", importlib.metadata.version("libigl"))]
    blender_ext = find_blender_ext()
    wheels = []
    for platform in platforms:
        for package, version in bundled:
            wheel = download_wheel(package, version, platform, cache)
            log(f"{platform}: {wheel.name}")
            wheels.append(wheel)
    output_dir.mkdir(parents=True, exist_ok=True)
    before = {p: p.stat().st_mtime_ns for p in output_dir.glob("*.zip")}
    with tempfile.TemporaryDirectory(prefix="garment_transfer_build_") as stage:
        stage_sources(Path(stage), wheels, platforms)
        run_blender_ext(blender_ext, "validate", stage)
        run_blender_ext(blender_ext, "build", "--source-dir", stage, "--output-dir", str(output_dir),
                        "--split-platforms")
    built = sorted(p for p in output_dir.glob("*.zip") if before.get(p) != p.stat().st_mtime_ns)
    for path in built:
        log(f"built {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return built


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--platform", action="append", choices=sorted(PLATFORM_TAGS),
                        help="Blender platform to build for (repeatable; default: all; "
                             f"this machine: {current_platform()})")
    parser.add_argument("--output-dir", type=Path, default=ROOT / "dist")
    parser.add_argument("--wheel-cache", type=Path, default=ROOT / "build" / "wheels",
                        help="where downloaded wheels are kept between builds")
    parser.add_argument("--scipy-version", default=None,
                        help="scipy version to bundle (default: the one installed here)")
    args = parser.parse_args(argv)
    try:
        build(args.platform or sorted(PLATFORM_TAGS), args.output_dir.resolve(),
              args.wheel_cache.resolve(), args.scipy_version)
    except BuildError as exc:
        print(f"build_extension: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
