"""A body model's targets as a shape basis (``garment_transfer.body_model``) and its sparse fit."""

import io
import zipfile
from pathlib import Path

import numpy as np
import pytest
from numpy.lib import format as npformat

from garment_transfer.errors import MeshError, TopologyMismatchError
from garment_transfer.fitting import registration, shape_basis
from garment_transfer.fitting.body_model import (
    HM08_BODY_VERTICES,
    TARGET_UNIT,
    makehuman_shape_basis,
    read_makehuman_targets,
)
from garment_transfer.geometry.mesh import mesh_from_triangles, vertex_normals
from garment_transfer.geometry.obj import read_obj
from lab.registration import remesh

ROOT = Path(__file__).resolve().parents[1]
RINGS, AROUND = 223, 60          # 223 x 60 = 13,380 vertices: the hm08 body's count


def column(height=17.0):
    """An upright frustum of the hm08 body's vertex count (decimetres, Y up), wider at the top (so that
    the alignment knows up from down)."""
    assert RINGS * AROUND == HM08_BODY_VERTICES
    a = np.linspace(0, 2 * np.pi, AROUND, endpoint=False)
    y = np.linspace(0, height, RINGS)
    r = np.repeat(1.2 + 0.6 * y / height, AROUND)
    V = np.stack([r * np.tile(np.cos(a), RINGS), np.repeat(y, AROUND), r * np.tile(np.sin(a), RINGS)], 1)
    F = []
    for r in range(RINGS - 1):
        for i in range(AROUND):
            p, q = r * AROUND + i, r * AROUND + (i + 1) % AROUND
            F += [[p, q + AROUND, q], [p, p + AROUND, q + AROUND]]
    return mesh_from_triangles(V, np.array(F), name="column")


def write_archive(path, targets, extra=None):
    """A targets.npz as MakeHuman's: targets/<group>/<name>.index.npy (uint16) and .vector.npy (int16)."""
    with zipfile.ZipFile(path, "w") as zf:
        for name, (index, vector) in targets.items():
            for suffix, arr in ((".index.npy", np.asarray(index, np.uint16)),
                                (".vector.npy", np.asarray(vector, np.int16))):
                buf = io.BytesIO()
                npformat.write_array(buf, arr, allow_pickle=True)
                zf.writestr(f"targets/{name}{suffix}", buf.getvalue())
        for name, arr in (extra or {}).items():
            buf = io.BytesIO()
            npformat.write_array(buf, arr, allow_pickle=True)
            zf.writestr(name, buf.getvalue())
    return path


def delta(index, vec):
    index = np.asarray(index)
    return index, np.tile(np.asarray(vec, float), (index.size, 1))


@pytest.fixture
def archive(tmp_path):
    rng = np.random.default_rng(0)
    legs = np.arange(0, 4000)
    up = rng.integers(-300, 300, size=(legs.size, 3))
    return write_archive(tmp_path / "targets.npz", {
        "measure/measure-hips-circ-decr": (legs, -up),                       # opposite of incr: one column
        "measure/measure-hips-circ-incr": (legs, up),
        "hip/hip-scale-depth-decr": delta(legs, [0, 0, -100]),               # not opposite: two columns
        "hip/hip-scale-depth-incr": delta(np.arange(5000, 6000), [0, 0, 200]),
        "macrodetails/african-female-young": delta(legs, [10, 0, 0]),
        "macrodetails/african-male-young": delta(legs, [40, 0, 0]),
        "macrodetails/asian-female-young": delta(legs, [0, 10, 0]),
        "macrodetails/asian-male-young": delta(legs, [0, 70, 0]),
        "macrodetails/caucasian-female-young": delta(legs, [0, 0, 10]),
        "macrodetails/caucasian-male-young": delta(legs, [0, 0, 100]),
        "macrodetails/african-female-old": delta(legs, [500, 0, 0]),          # not a young adult: left out
        "armslegs/r-hand-scale-incr": delta(np.arange(9000, 9100), [5, 5, 5]),  # a hand's own: left out
        "armslegs/r-upperarm-fat-incr": (np.array([100, 13380, 19000]), [[1, 2, 3], [9, 9, 9], [9, 9, 9]]),
        "head/head-age-incr": delta(np.arange(12000, 13000), [0, 50, 0]),    # a face group: not asked for
    }, extra={"license": np.array(["CC0"], dtype=object)})


def test_the_basis_has_one_column_per_slider(archive):
    source = column()
    model = makehuman_shape_basis(source, archive)
    assert model.units == 1.0 and model.up == "Y"
    names = model.names
    assert "measure/measure-hips-circ-incr(+-)" in names and "measure/measure-hips-circ-decr" not in names
    assert {"hip/hip-scale-depth-decr", "hip/hip-scale-depth-incr"} <= set(names)
    assert not any("old" in n or "hand" in n or n.startswith("head/") for n in names)
    assert model.basis.shape == (len(names), HM08_BODY_VERTICES, 3)
    assert np.array_equal(model.bounds, np.tile([-1.0, 1.0], (len(names), 1)))
    _, raw = read_makehuman_targets(archive, ["measure"])
    hips = model.basis[names.index("measure/measure-hips-circ-incr(+-)")]
    assert np.allclose(hips, raw[1]) and np.allclose(hips, -raw[0])
    # The gender: the male less the female ethnic targets, averaged over the three.
    gender = model.basis[names.index("macrodetails/gender")]
    assert np.allclose(gender[:4000], [30 * TARGET_UNIT, 60 * TARGET_UNIT, 90 * TARGET_UNIT] / np.array(3.0))
    # Indices beyond the body's vertices (helper geometry) are dropped.
    fat = model.basis[names.index("armslegs/r-upperarm-fat-incr")]
    assert np.allclose(fat[100], [1e-3, 2e-3, 3e-3]) and np.count_nonzero(np.abs(fat).sum(1)) == 1


def test_the_basis_follows_the_source_units_and_axes(archive):
    source = column()
    dm = makehuman_shape_basis(source, archive)
    # The same body in metres, Z up (Blender's frame: MakeHuman's (x, y, z) is (x, -z, y)).
    V = source.V * 0.1
    blender = mesh_from_triangles(np.stack([V[:, 0], -V[:, 2], V[:, 1]], 1), source.F, name="column_m")
    m = makehuman_shape_basis(blender, archive)
    assert m.units == pytest.approx(0.1) and m.up == "Z"
    D = dm.basis * 0.1
    assert np.allclose(m.basis, np.stack([D[..., 0], -D[..., 2], D[..., 1]], -1))


def test_a_source_of_another_mesh_is_refused_naming_the_archive(archive):
    V = column().V[:500]
    other = mesh_from_triangles(V, np.array([[0, 1, 61], [1, 62, 61]]), name="scan")
    with pytest.raises(TopologyMismatchError, match=r"scan: has 500 vertices, but the targets of .*targets\.npz "
                                                    r"are for MakeHuman's hm08 body \(13380"):
        makehuman_shape_basis(other, archive)


def test_archives_that_are_not_targets_are_refused_naming_the_file(tmp_path, archive):
    source = column()
    with pytest.raises(MeshError, match="missing.npz: file not found.*pip download"):
        makehuman_shape_basis(source, tmp_path / "missing.npz")
    text = tmp_path / "notes.npz"
    text.write_text("not a zip")
    with pytest.raises(MeshError, match="notes.npz: not a MakeHuman targets archive"):
        makehuman_shape_basis(source, text)
    pickled = write_archive(tmp_path / "pickled.npz", {"measure/measure-x-incr": (np.arange(3), np.ones((3, 3)))})
    with zipfile.ZipFile(pickled, "a") as zf:
        buf = io.BytesIO()
        npformat.write_array(buf, np.array([{"a": 1}], dtype=object), allow_pickle=True)
        zf.writestr("targets/measure/measure-y-incr.index.npy", buf.getvalue())
        zf.writestr("targets/measure/measure-y-incr.vector.npy", buf.getvalue())
    with pytest.raises(MeshError, match="pickled.npz: member targets/measure/measure-y-incr.* not a plain numpy"):
        makehuman_shape_basis(source, pickled)
    with pytest.raises(MeshError, match="holds no body targets"):
        makehuman_shape_basis(source, archive, groups=("nose",))
    lying = mesh_from_triangles(column().V[:, [1, 0, 2]], column().F, name="lying")
    with pytest.raises(MeshError, match="lying: is longest along X"):
        makehuman_shape_basis(lying, archive)


# --- the sparse fit: a target made from known slider weights, re-meshed, is recovered ---

@pytest.fixture(scope="module")
def sliders():
    """The procedural mannequin with a basis of many sliders: its other shapes (5), halfway mixtures of
    them (near-collinear with them, as a body model's sliders are) and regional bumps (24)."""
    names = ("banana", "pear", "heavy", "slim", "apple", "hourglass")
    bodies = {n: read_obj(ROOT / "data" / "demo" / "bodies" / f"{n}.obj", name=n) for n in names}
    source = bodies["banana"]
    V = source.V
    shapes = shape_basis.shape_basis_from_bodies(source, [bodies[n] for n in names[1:]])
    rng = np.random.default_rng(1)
    height = np.ptp(V[:, 2])
    bumps = []
    N = vertex_normals(V, source.F)
    for _ in range(24):
        c = V[rng.integers(V.shape[0])]
        r = rng.uniform(0.05, 0.15) * height
        bumps.append(0.01 * height * np.exp(-np.sum((V - c) ** 2, 1) / r ** 2)[:, None] * N)
    basis = np.concatenate([shapes, 0.5 * (shapes[[0, 2]] + shapes[[1, 4]]), np.array(bumps)])
    return source, basis


def test_a_target_of_known_sparse_weights_remeshed_is_recovered(sliders):
    source, basis = sliders
    k = basis.shape[0]
    weights = np.zeros(k)
    truth_at = [1, 3, 9, 20]                 # pear, apple and two bumps
    weights[truth_at] = [0.7, 0.4, -0.6, 0.8]
    truth = source.V + np.tensordot(weights, basis, axes=1)
    U, G = remesh(truth, source.F, 12000)
    target = mesh_from_triangles(U, G, name="sliders_remeshed")
    bounds = np.tile([-1.0, 1.0], (k, 1))
    reg = registration.register(source, target, cache=False, shape_basis=basis, shape_bounds=bounds,
                                body_model=True)
    height = np.ptp(truth, axis=0).max()
    assert reg.quality["shape_used"] == 1.0
    assert np.abs(reg.shape_weights - weights).max() < 0.02
    # The distractors stay (nearly) at 0: the sparse prior picks the sliders that made the target.
    others = np.delete(reg.shape_weights, truth_at)
    assert np.abs(others).sum() < 0.02
    err = np.linalg.norm(reg.V - truth, axis=1)
    assert err.mean() < 1e-3 * height
    # The plain ridge of a bodies' blend spreads the same target over the near-collinear columns.
    ridge = registration.register(source, target, cache=False, shape_basis=basis, shape_bounds=bounds)
    assert np.abs(ridge.shape_weights - weights).max() > 2 * np.abs(reg.shape_weights - weights).max()


def run(*args):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "garment_transfer", *map(str, args)], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)


def test_cli_register_with_a_body_model_and_its_refusal(tmp_path):
    import json

    from garment_transfer.geometry.obj import write_obj

    source = column()
    V = source.V
    low = np.flatnonzero(V[:, 1] < 8.0)
    widen = np.zeros((low.size, 3))
    widen[:, [0, 2]] = V[low][:, [0, 2]] * 300          # the lower half 30% wider at weight 1
    archive = write_archive(tmp_path / "targets.npz", {
        "hip/hip-scale-horiz-decr": (low, -widen), "hip/hip-scale-horiz-incr": (low, widen),
        "torso/torso-scale-depth-incr": delta(np.flatnonzero(V[:, 1] > 10.0), [0, 0, 200])})
    truth = V.copy()
    truth[low] += 0.5 * widen * TARGET_UNIT
    perm = np.random.default_rng(2).permutation(V.shape[0])
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    src, tgt, out = tmp_path / "column.obj", tmp_path / "wider.obj", tmp_path / "fit.obj"
    write_obj(src, source)
    write_obj(tgt, mesh_from_triangles(truth[perm], inv[source.F], name="wider"))
    p = run("register", "--source-body", src, "--target-body", tgt, "--out", out, "--body-model", archive,
            "--no-cache", "--json")
    assert p.returncode == 0, p.stderr
    weights = json.loads(p.stdout)["body_model_weights"]
    assert weights["hip/hip-scale-horiz-incr(+-)"] == pytest.approx(0.5, abs=0.02)
    assert abs(weights.get("torso/torso-scale-depth-incr", 0.0)) < 0.02
    fitted = read_obj(out)
    assert np.linalg.norm(fitted.V - truth, axis=1).mean() < 1e-3 * 17.0
    # A source of another mesh: refused, naming the archive, nothing written.
    banana = ROOT / "data" / "demo" / "bodies" / "banana.obj"
    out2 = tmp_path / "fit2.obj"
    p = run("register", "--source-body", banana, "--target-body", tgt, "--out", out2, "--body-model", archive,
            "--no-cache")
    assert p.returncode == 1 and "targets.npz are for MakeHuman's hm08 body" in p.stderr
    assert not out2.exists()
