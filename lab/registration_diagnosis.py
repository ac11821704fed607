"""Why a garment transferred through a registered body differs from its transfer through the true body.

Run ``python -m lab.registration_diagnosis TARGET SIZE [--prior] [--garments N]`` (MakeHuman data;
``female_average`` registered onto TARGET re-meshed to SIZE triangles, as in ``lab.registration``).
It prints, per garment (mm):

- ``difference``: the transfer through the registration (``transfer_to_any_body``) against the
  transfer through the true body (``transfer_garment``), both with their penetration fixes;
- ``no fix``: both without them;
- ``anchors alone`` / ``field alone``: the garment's Poisson solve with the true body's field and the
  fitted body's anchors, and the other way round, against the solve with both of the true body;
- ``anchors``: where the fitted and the true body carry the garment's bound points
  (``binding.carry``), and ``on surface``: their part on the body surface (without the normal offset);
- ``body at binding``: the body's vertex error at the vertex nearest each bound point;
- the difference per body region (``lab.registration.body_regions``) and each region's share of the
  garment's vertices.

And for the body: its vertex error (mean and area-weighted) and the error of its per-triangle
deformation gradients (Frobenius norm of the difference from the true body's, mean and
area-weighted). Units: the MakeHuman files are in decimetres (1 unit = 100 mm).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from garment_transfer.fitting.registration import register
from garment_transfer.geometry.binding import carry
from garment_transfer.geometry.embedding import unembed, unembed_with_matrix
from garment_transfer.geometry.gradients import deformation_gradients
from garment_transfer.geometry.mesh import mesh_from_triangles, vertex_areas
from garment_transfer.geometry.obj import read_obj
from garment_transfer.pipeline.any_body import transfer_to_any_body
from garment_transfer.pipeline.transfer import prepare_garment, transfer_garment

from .registration import MAKEHUMAN, MM_PER_UNIT, REGIONS, SOURCE, body_regions, leave_one_out_basis, remesh


def _triangle_areas(V, F):
    return 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)


def _solve_parts(prepared, source, body_V):
    """The garment's field and anchors from one shape of the source body."""
    F = np.asarray(source.F)
    B = deformation_gradients(source.V, body_V, F)[0]
    if prepared.embed_index is None:
        Q = unembed_with_matrix(B, F, prepared.embed_matrix)
    else:
        Q = unembed(B, prepared.embed_index, prepared.embed_weights)
    return Q, carry(prepared.binding, body_V, F)


def diagnose(target_name, size, prior=False, garments=3):
    manifest = json.loads((MAKEHUMAN / "manifest.json").read_text())
    source = read_obj(MAKEHUMAN / "bodies" / f"{SOURCE}.obj", name=SOURCE)
    truth = read_obj(MAKEHUMAN / "bodies" / f"{target_name}.obj", name=target_name)
    U, G = remesh(truth.V, truth.F, size)
    target = mesh_from_triangles(U, G, name=f"{target_name}_{size}")
    basis = leave_one_out_basis(source, target_name, manifest["bodies"])[1] if prior else None
    reg = register(source, target, cache=False, shape_basis=basis)
    F = np.asarray(source.F)
    R = reg.V
    e = np.linalg.norm(R - truth.V, axis=1) * MM_PER_UNIT
    va = vertex_areas(truth.V, F)
    gerr = np.linalg.norm(deformation_gradients(source.V, R, F)[0] - deformation_gradients(source.V, truth.V, F)[0],
                          axis=(1, 2))
    ta = _triangle_areas(source.V, F)
    print(f"{target_name} {size} triangles{', prior' if prior else ''}: body vertex error mean {e.mean():.2f} mm, "
          f"area-weighted {np.sum(e * va) / va.sum():.2f} mm; gradient error (Frobenius) mean {gerr.mean():.3f}, "
          f"area-weighted {np.sum(gerr * ta) / ta.sum():.3f}", flush=True)
    regions = body_regions(source.V)
    totals = {}
    for name in manifest["garments"][:garments]:
        garment = read_obj(MAKEHUMAN / "garments" / name / f"{SOURCE}.obj", name=name)
        through_truth = transfer_garment(source, truth, garment, method="direct").V
        through_reg = transfer_to_any_body(source, target, garment, registration=reg, method="direct")[0].V
        no_fix_truth = transfer_garment(source, truth, garment, method="direct", fix_penetration=False).V
        no_fix_reg = transfer_to_any_body(source, target, garment, registration=reg, method="direct",
                                          fix_penetration=False)[0].V
        prepared = prepare_garment(source, garment)
        Qt, At = _solve_parts(prepared, source, truth.V)
        Qr, Ar = _solve_parts(prepared, source, R)
        both_true = prepared.solver.solve(Qt, At)
        b = prepared.binding
        on_t = b.linear_part(F, truth.V.shape[0]) @ truth.V
        on_r = b.linear_part(F, R.shape[0]) @ R

        def mm(D):
            return float(np.linalg.norm(D, axis=1).mean() * MM_PER_UNIT)

        diff = np.linalg.norm(through_reg - through_truth, axis=1) * MM_PER_UNIT
        nearest = F[b.triangle, np.argmax(b.bary, axis=1)]
        row = {"difference": float(diff.mean()), "no fix": mm(no_fix_reg - no_fix_truth),
               "anchors alone": mm(prepared.solver.solve(Qt, Ar) - both_true),
               "field alone": mm(prepared.solver.solve(Qr, At) - both_true),
               "anchors": mm(Ar - At), "on surface": mm(on_r - on_t),
               "body at binding": float(e[nearest].mean()),
               "untransferred": mm(garment.V - through_truth)}
        for k, v in row.items():
            totals.setdefault(k, []).append(v)
        where = regions[nearest]
        print(f"  {name}: " + ", ".join(f"{k} {v:.2f}" for k, v in row.items()), flush=True)
        print("    per region: " + ", ".join(f"{k} {diff[where == k].mean():.1f} ({(where == k).mean():.0%})"
                                          for k in REGIONS if (where == k).any()), flush=True)
    print("  mean: " + ", ".join(f"{k} {np.mean(v):.2f}" for k, v in totals.items()), flush=True)
    return totals


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m lab.registration_diagnosis", description=__doc__.split("\n")[0])
    p.add_argument("target", help="a MakeHuman body (e.g. male_average)")
    p.add_argument("size", type=int, help="re-mesh size in triangles (e.g. 50000)")
    p.add_argument("--prior", action="store_true", help="with the leave-one-out shape basis")
    p.add_argument("--garments", type=int, default=3, help="the first N garments of the manifest")
    args = p.parse_args(argv)
    if not MAKEHUMAN.is_dir():
        raise SystemExit(f"MakeHuman data not found at {MAKEHUMAN}")
    diagnose(args.target, args.size, args.prior, args.garments)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
