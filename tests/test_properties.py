"""Property-based tests: invariants that must hold on random meshes and deformations."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from meshes import icosphere, random_rotation

from garment_transfer.geometry.gradients import deformation_gradients
from garment_transfer.geometry.mesh import mesh_from_polygons, mesh_from_triangles
from garment_transfer.geometry.penetration import penetration
from garment_transfer.geometry.poisson import PoissonSolver
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.pipeline.metrics import discrete_curvature, mdc
from garment_transfer.pipeline.transfer import transfer_garment

# Derandomized: CI runs the same examples every time (a failure is reproducible, never flaky).
SETTINGS = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow])


def sheet(seed, nx, ny, wave):
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 1, ny))
    z = wave * np.sin(rng.uniform(1, 6) * x + rng.uniform(0, 3)) * np.cos(rng.uniform(1, 6) * y)
    V = np.stack([x, y, z], axis=-1).reshape(-1, 3) + rng.normal(scale=0.01, size=(nx * ny, 3))
    idx = np.arange(nx * ny).reshape(ny, nx)
    quads = np.stack([idx[:-1, :-1], idx[:-1, 1:], idx[1:, 1:], idx[1:, :-1]], axis=-1).reshape(-1, 4)
    return mesh_from_polygons(V, quads, name="sheet")


meshes = st.builds(sheet, st.integers(0, 10_000), st.integers(2, 9), st.integers(2, 9), st.floats(0, 0.3))


@SETTINGS
@given(meshes, st.integers(0, 10_000))
def test_rigid_motion_gives_its_rotation_and_translation_gives_identity(m, seed):
    rng = np.random.default_rng(seed)
    R = random_rotation(rng)
    t = rng.normal(size=3) * 10
    Q, degenerate = deformation_gradients(m.V, m.V + t, m.F)
    np.testing.assert_allclose(Q, np.broadcast_to(np.eye(3), Q.shape), atol=1e-9)
    Q, _ = deformation_gradients(m.V, m.V @ R.T + t, m.F)
    np.testing.assert_allclose(Q[~degenerate], np.broadcast_to(R, Q[~degenerate].shape), atol=1e-8)


@SETTINGS
@given(meshes, st.integers(0, 10_000), st.floats(0.5, 2.0), st.floats(-0.5, 0.5), st.floats(0, 0.5))
def test_reconstruction_from_exact_gradients_returns_the_mesh(m, seed, scale, shear, bend):
    rng = np.random.default_rng(seed)
    A = random_rotation(rng) @ np.array([[scale, shear, 0], [0, 1, 0], [0, 0, 1 / scale]])
    Y = m.V @ A.T + rng.normal(size=3)
    Y[:, 2] += bend * np.sin(3 * m.V[:, 0])       # bending: not affine
    Q, _ = deformation_gradients(m.V, Y, m.F)
    out = PoissonSolver(m.V, m.F, anchor_weight=1e-3).solve(Q, Y)
    assert np.max(np.abs(out - Y)) <= 1e-8 * max(1.0, np.max(np.abs(Y)))


@SETTINGS
@given(meshes, st.integers(0, 10_000))
def test_metrics_are_finite_and_in_range(m, seed):
    rng = np.random.default_rng(seed)
    W = m.V + rng.normal(scale=0.05, size=m.V.shape)
    r = discrete_curvature(W, m.F)
    assert np.all(np.isfinite(r)) and r.min() >= -1 - 1e-12 and r.max() <= 1 + 1e-12
    value = mdc(m.V, W, m.F)
    assert 0.0 <= value <= 2.0
    assert mdc(W, W, m.F) == 0.0
    V, F = icosphere(1)
    ratio, depth, inside = penetration(W - [0.5, 0.5, 0], TriangleSurface(V, F))
    assert 0.0 <= ratio <= 1.0 and depth >= 0.0 and inside.shape == (m.n_vertices,)


@settings(max_examples=10, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(0.8, 1.4), st.floats(0.8, 1.4), st.floats(0.9, 1.2), st.integers(0, 10_000))
def test_transfer_keeps_faces_and_is_finite_and_outside(sx, sy, sz, seed):
    V, F = icosphere(3)
    source = mesh_from_triangles(V, F, name="source")
    target = source.with_vertices(V * [sx, sy, sz], name="target")
    GV, GF = icosphere(2, radius=1.04)
    rng = np.random.default_rng(seed)
    GV = GV + rng.normal(scale=0.005, size=GV.shape)
    keep = GV[GF].mean(axis=1)[:, 2] < rng.uniform(-0.5, 0.5)
    garment = mesh_from_triangles(GV, GF[keep], name="garment")
    r = transfer_garment(source, target, garment)
    assert r.V.shape == garment.V.shape and np.all(np.isfinite(r.V))
    used = np.unique(garment.F)
    assert (TriangleSurface(target.V, target.F).signed_distance(r.V[used])[0] >= 0).all()
    assert r.penetrating_vertices == 0
