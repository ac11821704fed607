"""``python -m garment_transfer weights``: a garment's weights from its body, written whole, checked."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from meshes import icosphere

from garment_transfer import mesh_from_triangles, read_obj, read_weights, skin_weights, write_obj, write_weights

ROOT = Path(__file__).resolve().parents[1]


def run(*args):
    return subprocess.run([sys.executable, "-m", "garment_transfer", "weights", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)


def files(tmp_path):
    V, F = icosphere(3)
    body = tmp_path / "body.obj"
    write_obj(body, mesh_from_triangles(V, F, "body"))
    up = 0.5 * (V[:, 2] + 1)
    # Five groups of which up to three overlap, so that the influences are limited.
    W = np.stack([1 - up, up, 0.3 * up * (1 - up), 0.2 * (V[:, 0] > 0), 0.1 * (V[:, 1] > 0)], axis=1)
    weights = tmp_path / "body_weights.json"
    write_weights(weights, skin_weights(["a", "b", "c", "d", "e"], W))
    G, GF = icosphere(2, radius=1.03)
    G[G[:, 2] < -0.7] *= [1.6, 1.6, 1.0]            # a flared hem, away from the body
    garment = tmp_path / "garment.obj"
    write_obj(garment, mesh_from_triangles(G, GF, "garment"))
    return body, weights, garment, G.shape[0]


def test_weights_command_writes_normalised_weights_with_few_influences(tmp_path):
    body, weights, garment, n = files(tmp_path)
    out = tmp_path / "garment_weights.json"
    p = run("--body", body, "--weights", weights, "--garment", garment, "--out", out, "--max-influences", "2",
            "--json")
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert data["inpainted"] > 0 and data["matched"] + data["inpainted"] == n and data["warnings"] == []
    w = read_weights(out, n)
    assert w.groups == ("a", "b", "c", "d", "e")
    assert np.allclose(w.sums(), 1, atol=1e-5) and w.influences().max() == 2 == data["most_influences"]
    p = run("--body", body, "--weights", weights, "--garment", garment, "--out", out, "--rule", "nearest",
            "--max-influences", "8")
    assert p.returncode == 0, p.stderr
    assert read_weights(out, n).influences().max() == 5


def test_weights_command_refuses_bad_input_and_writes_nothing(tmp_path):
    body, weights, garment, n = files(tmp_path)
    out = tmp_path / "out.json"
    other = tmp_path / "other_weights.json"
    other.write_text(json.dumps({"weights": {"a": [[99999, 1.0]]}}))
    p = run("--body", body, "--weights", other, "--garment", garment, "--out", out)
    assert p.returncode == 1 and "other_weights.json" in p.stderr and "another mesh" in p.stderr
    p = run("--body", body, "--weights", weights, "--garment", garment, "--out", weights)
    assert p.returncode == 1 and "body_weights.json" in p.stderr
    far = tmp_path / "far.obj"
    G, GF = icosphere(2, centre=(0, 0, 9.0))
    write_obj(far, mesh_from_triangles(G, GF, "far"))
    p = run("--body", body, "--weights", weights, "--garment", far, "--out", out)
    assert p.returncode == 1 and "far.obj" in p.stderr and "far from the body" in p.stderr
    p = run("--body", body, "--weights", weights, "--garment", garment, "--out", out, "--max-influences", "0")
    assert p.returncode == 2
    assert not out.exists() and sorted(f.name for f in tmp_path.iterdir()) == [
        "body.obj", "body_weights.json", "far.obj", "garment.obj", "other_weights.json"]


def test_weights_that_leave_cloth_unweighted_are_said_in_the_json_and_weights_that_move_nothing_are_refused(tmp_path):
    body, weights, garment, n = files(tmp_path)
    V = read_obj(body).V
    full = read_weights(weights, len(V))
    # The body's weights left empty on its top cap (a region not painted).
    bare = V[:, 2] > 0.5
    capless = tmp_path / "capless.json"
    write_weights(capless, skin_weights(full.groups, full.dense() * ~bare[:, None]))
    for rule in ("inpaint", "nearest"):
        out = tmp_path / f"{rule}.json"
        p = run("--body", body, "--weights", capless, "--garment", garment, "--out", out, "--rule", rule, "--json")
        assert p.returncode == 0, p.stderr
        data = json.loads(p.stdout)
        written = read_weights(out, n)
        # The count is the file's: its vertices with no weight.
        assert data["unweighted"] == int((written.sums() <= 0).sum()) > 0, rule
        assert data["warnings"][-1].startswith(f"{data['unweighted']} of the {n} vertices of {garment} have no weight "
                                               f"({int(bare.sum())} of the body's {len(V)} vertices have none in "
                                               f"{capless}, "), rule
    # Weights on the body's lowest vertex only, and a hat over its top: the hat would not move with the bones;
    # refused, naming the weights file, nothing written.
    bottom = int(np.argmin(V[:, 2]))
    lone = tmp_path / "lone.json"
    lone.write_text(json.dumps({"weights": {"a": [[bottom, 1.0]]}}))
    G, GF = icosphere(2, radius=1.03)
    cap = np.flatnonzero(G[:, 2] > 0.6)
    local = np.full(len(G), -1)
    local[cap] = np.arange(cap.size)
    hat = tmp_path / "hat.obj"
    write_obj(hat, mesh_from_triangles(G[cap], local[GF[np.isin(GF, cap).all(axis=1)]], "hat"))
    for rule in ("inpaint", "nearest"):
        out = tmp_path / f"lone_{rule}.json"
        p = run("--body", body, "--weights", lone, "--garment", hat, "--out", out, "--rule", rule)
        assert p.returncode == 1, p.stderr
        assert p.stderr.startswith(f"error: {lone}: none of the {cap.size} vertices of {hat} has a weight"), p.stderr
        assert not out.exists()
