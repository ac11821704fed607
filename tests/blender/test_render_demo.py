"""lab/blender/render_demo.py on a tiny results folder: a .blend with the named objects and Cycles PNGs that show
the garments in their colours; a malformed folder fails with the file named."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

from garment_transfer.geometry.mesh import mesh_from_polygons
from garment_transfer.geometry.obj import write_obj
from lab.bench import tube_dress

# The lab runs its Blender scripts in the project's own Blender (5.0) only: tools/run.sh runs these there.
pytestmark = pytest.mark.lab

SCRIPT = "lab.blender.render_demo"
TARGETS = ["wide", "narrow"]
GARMENT = "dress"
PERCENT = 20


def capsule_body(width, depth=0.12, height=1.7, nu=24, nv=48):
    """A closed, roughly body-sized ellipsoid standing on z = 0."""
    theta = np.linspace(0, 2 * np.pi, nu, endpoint=False)
    phi = np.linspace(0, np.pi, nv + 1)[1:-1]
    s = np.sin(phi)[:, None]
    ring = np.stack([s * np.cos(theta) * width, s * np.sin(theta) * depth,
                     np.broadcast_to((1 - np.cos(phi))[:, None] * height / 2, (nv - 1, nu))], axis=2)
    V = np.vstack([[0, 0, 0], ring.reshape(-1, 3), [0, 0, height]])
    idx = 1 + np.arange((nv - 1) * nu).reshape(nv - 1, nu)
    polys = [[0, idx[0, (j + 1) % nu], idx[0, j]] for j in range(nu)]
    polys += [[idx[i, j], idx[i, (j + 1) % nu], idx[i + 1, (j + 1) % nu], idx[i + 1, j]]
              for i in range(nv - 2) for j in range(nu)]
    top = len(V) - 1
    polys += [[idx[-1, j], idx[-1, (j + 1) % nu], top] for j in range(nu)]
    return mesh_from_polygons(V, polys, name=f"body_{width}")


def make_results(folder):
    """What the demo writes, in miniature: source body 'src', two targets, one test garment."""
    meshes = folder / "meshes"
    meshes.mkdir(parents=True)
    bodies = {"src": capsule_body(0.16), "wide": capsule_body(0.21), "narrow": capsule_body(0.13)}
    for name, body in bodies.items():
        write_obj(meshes / f"body__{name}.obj", body)
    source = tube_dress(bodies["src"], 1200)
    write_obj(meshes / f"{GARMENT}__src__source.obj", source)
    for t in TARGETS:
        ours = tube_dress(bodies[t], 1200)
        assert ours.n_vertices == source.n_vertices
        wobble = 0.01 * np.sin(8 * ours.V[:, 2])[:, None] * np.array([1.0, 1.0, 0.0])
        write_obj(meshes / f"{GARMENT}__{t}__ours.obj", ours)
        write_obj(meshes / f"{GARMENT}__{t}__simulation.obj", ours, ours.V + wobble)
        change = np.linalg.norm(ours.V - source.V, axis=1) * np.linspace(0, 1, ours.n_vertices)
        np.save(meshes / f"{GARMENT}__{t}__ours_change.npy", change.astype(np.float32))
    (folder / "results.json").write_text(json.dumps(
        {"source": "src", "targets": TARGETS, "test_garments": [GARMENT], "rows": []}))
    return folder


def run_script(folder, *extra, timeout=120):
    cmd = [sys.executable, "-m", SCRIPT, "--results", str(folder), *extra]
    return subprocess.run(cmd, capture_output=True, encoding="utf-8", errors="replace", timeout=timeout)


def read_png(path):
    """(height, width, channels) uint8 pixels of an 8-bit RGB/RGBA PNG, checking signature and CRCs."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path.name} is not a PNG"
    pos, idat, header = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])
        assert zlib.crc32(kind + body) == crc, f"{path.name}: bad CRC in {kind!r}"
        if kind == b"IHDR":
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"IDAT":
            idat += body
        elif kind == b"IEND":
            break
        pos += 12 + length
    width, height, depth, colour, _, _, interlace = header
    assert depth == 8 and colour in (2, 6) and interlace == 0, header
    ch = 3 if colour == 2 else 4
    raw = np.frombuffer(zlib.decompress(idat), dtype=np.uint8).reshape(height, 1 + width * ch)
    out = np.zeros((height, width * ch), dtype=np.int32)
    for y in range(height):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        prev = out[y - 1] if y else np.zeros(width * ch, dtype=np.int32)
        if f in (0, 2):
            out[y] = (line + (prev if f == 2 else 0)) % 256
            continue
        row = np.zeros(width * ch, dtype=np.int32)
        for x in range(width * ch):
            left = row[x - ch] if x >= ch else 0
            if f == 1:
                pred = left
            elif f == 3:
                pred = (left + prev[x]) // 2
            else:  # Paeth
                up, ul = prev[x], (prev[x - ch] if x >= ch else 0)
                p = left + up - ul
                pa, pb, pc = abs(p - left), abs(p - up), abs(p - ul)
                pred = left if pa <= pb and pa <= pc else (up if pb <= pc else ul)
            row[x] = (line[x] + pred) % 256
        out[y] = row
    return out.reshape(height, width, ch)[:, :, :3]


def count(img, test):
    r, g, b = (img[:, :, i] for i in range(3))
    return int(np.count_nonzero(test(r, g, b)))


def blue(r, g, b):
    return (b > r + 60) & (b > g + 20)


def yellow(r, g, b):
    return (r > 150) & (g > 100) & (b < r - 80)


def green(r, g, b):
    return (g > r + 30) & (g > b + 30)


def red(r, g, b):
    return (r > g + 80) & (r > b + 80)


@pytest.mark.slow
def test_render_demo_writes_a_blend_and_renders_showing_the_garments(tmp_path):
    folder = make_results(tmp_path / "results")
    proc = run_script(folder, "--resolution-percent", str(PERCENT), "--samples", "4")
    assert proc.returncode == 0, proc.stderr[-3000:]
    last = proc.stdout.strip().splitlines()[-1]
    renders = folder / "renders"
    expected = {f"fig7_{GARMENT}.png": (960, 540), f"fig11_{GARMENT}.png": (1200, 400),
                f"fig3_{GARMENT}_on_wide.png": (720, 540)}
    assert "wrote:" in last and str(folder / "demo.blend") in last
    assert sorted(p.name for p in renders.iterdir()) == sorted(expected)
    images = {}
    for name, (w, h) in expected.items():
        assert str(renders / name) in last
        img = read_png(renders / name)
        assert img.shape[:2] == (h * PERCENT // 100, w * PERCENT // 100), name
        assert img.astype(float).var() > 0, f"{name} is blank"
        # A white backdrop at the edges, something drawn in the middle.
        assert img[0].min() > 200 and img[:, 0].min() > 200, f"{name}: the backdrop is not white"
        assert np.count_nonzero(img.max(axis=2) < 200) > 0.02 * img.shape[0] * img.shape[1], name
        images[name] = img
    fig7, fig11, fig3 = (images[n] for n in expected)
    # Source garment blue, ours yellow, simulation green: each column's garment is there.
    for test in (blue, yellow, green):
        assert count(fig7, test) > 10, test.__name__
    assert count(fig11, blue) > 10 and count(fig11, yellow) > count(fig11, blue)
    # Both ends of the heat map.
    assert count(fig3, blue) > 10 and count(fig3, red) > 5

    script = (
        "import bpy, json, sys\n"
        "bpy.ops.wm.open_mainfile(filepath=sys.argv[1])\n"
        "objs = {o.name: {'collections': [c.name for c in o.users_collection], 'type': o.type,"
        " 'materials': [m.name for m in o.data.materials] if o.type == 'MESH' else [],"
        " 'attributes': [a.name for a in o.data.attributes] if o.type == 'MESH' else [],"
        " 'smooth': all(p.use_smooth for p in o.data.polygons) if o.type == 'MESH' else None,"
        " 'x': o.location.x} for o in bpy.data.objects}\n"
        "colls = {c.name: {'children': sorted(k.name for k in c.children), 'render': not c.hide_render}"
        " for c in bpy.data.collections}\n"
        "print('JSON' + json.dumps({'objects': objs, 'collections': colls,"
        " 'engine': bpy.context.scene.render.engine,"
        " 'camera': bpy.context.scene.camera.name if bpy.context.scene.camera else None}))\n")
    p = subprocess.run([sys.executable, "-c", script, str(folder / "demo.blend")], capture_output=True,
                       encoding="utf-8", errors="replace", timeout=60)
    assert p.returncode == 0, p.stderr[-2000:]
    info = json.loads([ln for ln in p.stdout.splitlines() if ln.startswith("JSON")][0][4:])
    objs = info["objects"]
    names = [f"{GARMENT}_source"] + [f"{GARMENT}_on_{t}_{m}" for t in TARGETS for m in ("ours", "simulation")]
    for name in names:
        assert name in objs, sorted(objs)
        where = f"{GARMENT} source" if name.endswith("source") else f"{GARMENT} on {name.split('_')[2]}"
        assert objs[name]["collections"] == [where], objs[name]
        assert objs[f"{name}_body"]["collections"] == [where]
        assert objs[f"{name}_body"]["type"] == "MESH" and objs[f"{name}_body"]["materials"] == ["body_grey"]
        assert objs[name]["smooth"]
    assert objs[f"{GARMENT}_source"]["materials"] == ["garment_source"]
    assert objs[f"{GARMENT}_on_wide_ours"]["materials"] == ["garment_ours"]
    assert objs[f"{GARMENT}_on_wide_simulation"]["materials"] == ["garment_simulation"]
    assert "ours_change" in objs[f"{GARMENT}_on_wide_ours"]["attributes"]
    xs = [objs[n]["x"] for n in names]
    assert xs == sorted(xs) and len(set(xs)) == len(xs), "columns side by side along X"
    assert info["engine"] == "CYCLES" and info["camera"]
    colls = info["collections"]
    children = [f"{GARMENT} source"] + [f"{GARMENT} on {t}" for t in TARGETS]
    assert colls[GARMENT]["children"] == sorted(children)
    # F12 in the .blend renders the fig7 layout: source and first target only.
    assert sorted(c for c in children if colls[c]["render"]) == sorted(children[:2])


@pytest.mark.parametrize("breakage, named", [
    ("no_folder", "does not exist"),
    ("no_json", "results.json not found"),
    ("bad_json", "results.json cannot be read"),
    ("no_targets", "'targets'"),
    ("missing_mesh", "dress__narrow__ours.obj not found"),
    ("bad_mesh", "body__wide.obj"),
    ("bad_change", "dress__wide__ours_change.npy"),
])
def test_render_demo_names_what_is_wrong_with_the_results_folder(tmp_path, breakage, named):
    folder = make_results(tmp_path / "results")
    meshes = folder / "meshes"
    if breakage == "no_folder":
        folder = tmp_path / "nowhere"
    elif breakage == "no_json":
        (folder / "results.json").unlink()
    elif breakage == "bad_json":
        (folder / "results.json").write_text("{not json")
    elif breakage == "no_targets":
        (folder / "results.json").write_text(json.dumps({"source": "src", "targets": [],
                                                         "test_garments": [GARMENT]}))
    elif breakage == "missing_mesh":
        (meshes / f"{GARMENT}__narrow__ours.obj").unlink()
    elif breakage == "bad_mesh":
        (meshes / "body__wide.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7\n")
    elif breakage == "bad_change":
        np.save(meshes / f"{GARMENT}__wide__ours_change.npy", np.zeros(5, dtype=np.float32))
    proc = run_script(folder, "--resolution-percent", "5", "--samples", "1", timeout=60)
    assert proc.returncode == 1, proc.stdout
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("render_demo: error:") and named in last, last
    assert not (folder / "renders").exists() and not (folder / "demo.blend").exists()


def test_render_columns_draws_each_column_in_its_colours_and_names_a_missing_file(tmp_path):
    # A body in decimetres, Y up (MakeHuman's frame) beside one in metres, Z up: both stand on the floor
    # of one figure, the garment of the first blue, of the second yellow.
    body = capsule_body(0.16)
    dress = tube_dress(body, 1200)
    yup = np.stack([body.V[:, 0], body.V[:, 2], -body.V[:, 1]], axis=1) * 10.0
    write_obj(tmp_path / "body_dm.obj", body, yup)
    write_obj(tmp_path / "dress_dm.obj", dress,
              np.stack([dress.V[:, 0], dress.V[:, 2], -dress.V[:, 1]], axis=1) * 10.0)
    write_obj(tmp_path / "body_m.obj", body)
    write_obj(tmp_path / "dress_m.obj", dress)
    dm, m = {"scale": 0.1, "up": "Y"}, {"scale": 1.0, "up": "Z"}
    spec = {"size": [240, 160], "columns": [
        {"meshes": [dict(obj=str(tmp_path / "body_dm.obj"), kind="body", **dm),
                    dict(obj=str(tmp_path / "dress_dm.obj"), kind="source", **dm)]},
        {"meshes": [dict(obj=str(tmp_path / "body_m.obj"), kind="body", **m),
                    dict(obj=str(tmp_path / "dress_m.obj"), kind="ours", **m)]}]}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    out = tmp_path / "figure.png"
    cmd = [sys.executable, "-m", "lab.blender.render_columns", "--spec", str(tmp_path / "spec.json"),
           "--out", str(out), "--samples", "4"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert p.returncode == 0, p.stderr
    px = read_png(out)[:, :, :3].astype(int)
    half = px.shape[1] // 2
    blue = (px[:, :, 2] > px[:, :, 0] + 60)
    yellow = (px[:, :, 0] > px[:, :, 2] + 60) & (px[:, :, 1] > px[:, :, 2] + 30)
    assert blue[:, :half].sum() > 100 and blue[:, half:].sum() == 0
    assert yellow[:, half:].sum() > 100 and yellow[:, :half].sum() == 0
    (tmp_path / "dress_m.obj").unlink()
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=180)
    assert p.returncode == 1 and "dress_m.obj" in p.stderr
