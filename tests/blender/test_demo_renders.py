"""The demo's Blender side: lab/blender/render_demo.py on a small results folder, in a subprocess."""

import json
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

# The lab runs its Blender scripts in the project's own Blender (5.0) only: tools/run.sh runs these there.
pytestmark = pytest.mark.lab

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from demo_results import copy_of, quick_demo_results  # noqa: E402


def png_pixels(path):
    """(height, width, channels) uint8 of an 8-bit RGB/RGBA PNG, read with zlib only."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    pos, idat, width = 8, b"", None
    while pos < len(data):
        length, kind = struct.unpack(">I4s", data[pos:pos + 8])
        body = data[pos + 8:pos + 8 + length]
        if kind == b"IHDR":
            width, height, depth, colour = struct.unpack(">IIBB", body[:10])
            assert depth == 8
            channels = {2: 3, 6: 4}[colour]
        elif kind == b"IDAT":
            idat += body
        pos += 12 + length
    raw = np.frombuffer(zlib.decompress(idat), np.uint8)
    stride = width * channels
    rows = raw.reshape(height, stride + 1)
    out = np.zeros((height, stride), np.int32)
    for y in range(height):
        f, line = rows[y, 0], rows[y, 1:].astype(np.int32)
        prev = out[y - 1] if y else np.zeros(stride, np.int32)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prev) % 256
        else:
            cur = np.zeros(stride, np.int32)
            for x in range(stride):
                a = cur[x - channels] if x >= channels else 0
                b = prev[x]
                c = prev[x - channels] if x >= channels else 0
                if f == 1:
                    pred = a
                elif f == 3:
                    pred = (a + b) // 2
                else:
                    p = a + b - c
                    pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                    pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[x] = (line[x] + pred) % 256
        out[y] = cur
    return out.reshape(height, width, channels).astype(np.uint8)


def test_render_script_writes_pictures_and_a_blend(tmp_path, tmp_path_factory, worker_id):
    out = copy_of(quick_demo_results(tmp_path_factory, worker_id)[0], tmp_path / "results")
    p = subprocess.run([sys.executable, "-m", "lab.blender.render_demo", "--results", str(out),
                        "--samples", "2", "--resolution-percent", "10", "--first-target-only"],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    summary = json.loads((out / "results.json").read_text())
    pictures = sorted((out / "renders").glob("*.png"))
    names = {q.name for q in pictures}
    for g in summary["test_garments"]:
        assert f"fig7_{g}.png" in names
        assert f"fig3_{g}_on_{summary['targets'][0]}.png" in names
    for q in pictures:
        img = png_pixels(q)
        assert img.shape[0] > 10 and img.shape[1] > 10
        assert img[..., :3].std() > 5, f"{q.name} is blank"
    listing = subprocess.run(
        [sys.executable, "-c", "import bpy, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]); "
         "print('\\n'.join(o.name for o in bpy.data.objects))", str(out / "demo.blend")],
        capture_output=True, text=True, timeout=120)
    objects = set(listing.stdout.split())
    g, t = summary["test_garments"][0], summary["targets"][0]
    assert {f"{g}_source", f"{g}_on_{t}_ours", f"{g}_on_{t}_simulation"} <= objects, sorted(objects)[:20]
    assert not list(out.rglob(".tmp-*"))
