"""The pose fit: a garment carried from the rest body to the same body posed, kept outside it, counted under
every split of the quads."""

import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
from meshes import grid, icosphere, random_rotation, require_makehuman

from garment_transfer import (Rig, bvh_rotations, every_split, fit_poses, fit_to_pose, inpainted_weights, mdc,
                              mesh_from_polygons, mesh_from_triangles, prepare_garment, read_bvh, read_joints,
                              read_mdd, read_obj, read_pc2, read_skeleton, read_weights, transfer_garment,
                              write_mdd, write_obj, write_pc2)
from garment_transfer.geometry.pc2 import pc2_bytes
from garment_transfer.pipeline import self_contact
from garment_transfer.geometry.proximity import TriangleSurface
from garment_transfer.geometry import clearance
from garment_transfer.geometry.clearance import separate
from garment_transfer.geometry.obstacle import Obstacle, garment_crossings
from garment_transfer.geometry.intersections import self_intersections
from garment_transfer.geometry.readings import kept_triangle_readings, readings_of
from garment_transfer.geometry.self_check import beyond_source, pairs_in_full
from garment_transfer.pipeline.pose_fit import (CONTACT_GAP, CONTACT_RINGS, at_contact_and_inside, crossing_counts,
                                                free_readings, garment_readings, kept_split, posed_counts,
                                                poses_to_files)

ROOT = Path(__file__).resolve().parents[1]


def test_the_pose_fits_readings_by_polygon_are_its_triangles_of_every_split():
    # A crumpled sheet of quads as the body, part of it in contact; another as the garment through it.
    rng = np.random.default_rng(3)
    body = grid(12, 10, size=2.0)
    body = body.with_vertices(body.V + rng.normal(scale=0.05, size=body.V.shape))
    cloth = grid(9, 8, size=1.6, wave=0.4)
    V = cloth.V + [0.2, 0.1, -0.05] + rng.normal(scale=0.03, size=cloth.V.shape)
    contact = np.zeros(body.V.shape[0], bool)
    contact[rng.choice(body.V.shape[0], 12, replace=False)] = True
    body_F = kept_split(body)
    soup = kept_triangle_readings(body_F[~contact[body_F].any(axis=1)])
    R = free_readings(body, contact)

    def triangles(F):
        return sorted(tuple(sorted(t)) for t in F.tolist())

    assert triangles(R.F) == triangles(soup.F) and len(R.F) < 4 * body.n_faces
    assert np.array_equal(R.E, soup.E) and np.array_equal(R.split, soup.split)
    G, G_soup = garment_readings(cloth), kept_triangle_readings(kept_split(cloth))
    assert np.array_equal(G.split, G_soup.split) and np.array_equal(G.E, G_soup.E)
    assert garment_readings(cloth.with_vertices(V)) is G                   # kept for every pose: topology made once
    assert triangles(G.F) == triangles(G_soup.F)

    def through(G, R):
        c = garment_crossings(V, G, Obstacle(body.V, R))
        a = {(tuple(e), tuple(sorted(R.F[t]))) for e, t in zip(c["a_pairs"].tolist(), c["a_triangles"])}
        b = {(tuple(e), tuple(sorted(G.F[t]))) for e, t in zip(c["b_pairs"].tolist(), c["b_triangles"])}
        return a, b

    a, b = through(G, R)
    assert (a, b) == through(G_soup, soup) and len(a) > 5 and len(b) > 5
    # The pass clears the same crossings either way (the same moves, up to the order of sums).
    W, info = separate(V, G, body.V, Obstacle(body.V, R), 0.02, keep_offset=False)
    W_soup, info_soup = separate(V, G_soup, body.V, Obstacle(body.V, soup), 0.02, keep_offset=False)
    assert info["crossings_before"] == info_soup["crossings_before"] > 10
    assert info["crossings_after"] == info_soup["crossings_after"]
    np.testing.assert_allclose(W, W_soup, atol=1e-12)


def test_every_split_holds_both_diagonals_and_every_fan():
    quads = grid(4, 3)
    F = every_split(quads)
    assert np.array_equal(F[:quads.n_triangles], quads.F) and F.shape[0] == 4 * quads.n_faces
    pentagon = mesh_from_polygons(np.array([[np.cos(a), np.sin(a), 0] for a in np.linspace(0, 6, 5)]),
                                  [[0, 1, 2, 3, 4]])
    assert {tuple(sorted(t)) for t in every_split(pentagon)} == {
        (a, b, c) for a in range(5) for b in range(a + 1, 5) for c in range(b + 1, 5)}
    tri = mesh_from_triangles(*icosphere(0))
    assert np.array_equal(every_split(tri), tri.F)


def test_self_contact_finds_where_a_body_crosses_itself():
    V1, F1 = icosphere(2)
    V2, F2 = icosphere(2, centre=(1.5, 0, 0))
    V, F = np.vstack([V1, V2]), np.vstack([F1, F2 + len(V1)])
    contact, pairs = self_contact(V, F, rings=0)
    assert pairs > 0 and contact.any()
    assert (V[contact, 0] > 0.3).all() and (V[contact, 0] < 1.2).all()     # only where the spheres overlap
    apart, none = self_contact(np.vstack([V1, V2 + [1.5, 0, 0]]), F, rings=2)
    assert none == 0 and not apart.any()


def test_self_contact_takes_parts_pressed_together_only_if_apart_at_rest():
    # Two spheres of radius 1 whose surfaces come within 0.04 of each other (no crossing): contact where they were
    # farther apart at rest than three gaps, not where they were as close already.
    V1, F1 = icosphere(2)
    V2, F2 = icosphere(2, centre=(2.04, 0, 0))
    V, F = np.vstack([V1, V2]), np.vstack([F1, F2 + len(V1)])
    gap = 0.1
    close = np.linalg.norm(V[:len(V1), None] - V[None, len(V1):], axis=2) < gap
    expected = np.zeros(len(V), bool)
    expected[np.flatnonzero(close.any(axis=1))] = True
    expected[len(V1) + np.flatnonzero(close.any(axis=0))] = True
    assert expected.any()
    far_rest = np.vstack([V1, V2 + [1.0, 0, 0]])
    contact, pairs = self_contact(V, F, rings=0, rest_V=far_rest, gap=gap)
    assert pairs == 0 and np.array_equal(contact, expected)
    as_now, _ = self_contact(V, F, rings=0, rest_V=V, gap=gap)
    assert not as_now.any()


def test_vertices_known_outside_are_not_counted_again():
    V, F = icosphere(2)
    body = mesh_from_triangles(V, F, "body")
    G = np.array([[0.0, 0.0, 0.5], [0.0, 0.0, 2.0], [0.0, 0.0, -0.5], [2.0, 0.0, 0.0]])
    contact = np.zeros(len(V), bool)
    garment_F = np.array([[0, 1, 3]])
    assert at_contact_and_inside(G, garment_F, body, F, contact) == (0, 2)
    # Told which vertices are outside (those a pass did not move since a count found none inside), it measures
    # the others only.
    assert at_contact_and_inside(G, garment_F, body, F, contact, outside=np.array([0, 1, 1, 1], bool)) == (0, 1)
    assert at_contact_and_inside(G, garment_F, body, F, contact, outside=np.ones(4, bool)) == (0, 0)


def test_posed_counts_count_the_garments_own_crossings_beyond_its_rest_shape_exactly():
    V, F = icosphere(1)
    body = mesh_from_triangles(V, F, "body")
    # Two triangles far from the body: apart at rest; in the pose the second one pierces the first, its two edges
    # from the vertex below through the first's inside (its own edges far from the second: 2 pairs in all).
    rest = np.array([[5.0, -1, 0], [7.0, -1, 0], [6.0, 1, 0], [6.0, 0, 1], [5.9, 0, 1.2], [6.1, 0, 1.2]])
    garment = mesh_from_triangles(rest, np.array([[0, 1, 2], [3, 4, 5]]), "garment")
    posed = rest.copy()
    posed[3:] = [[6.0, 0, -0.1], [5.9, 0, 0.1], [6.1, 0, 0.1]]
    counts = posed_counts(posed, garment, body, 0.01, rest_V=V, name="the pose")
    assert counts["self_intersections"] == counts["self_intersections_new"] == 2
    assert counts["crossings_outside_contact"] == counts["crossings_at_contact"] == counts["penetrating_vertices"] == 0
    assert counts["warnings"] == ["the garment crosses itself in the pose at 2 edge-triangle pairs it does not at "
                                  "rest (2 in all): look at the folds where the body bends"]
    # Pairs the rest shape has count in all, not as new; a caller counting them itself asks for the body's only.
    tangled = garment.with_vertices(posed)
    counts = posed_counts(posed, tangled, body, 0.01, rest_V=V)
    assert counts["self_intersections"] == 2 and counts["self_intersections_new"] == 0 and counts["warnings"] == []
    assert "self_intersections" not in posed_counts(posed, garment, body, 0.01, rest_V=V, own=False)


def sphere_body_and_garment():
    """A round body and a round garment over it: (V, body, G, garment)."""
    V, F = icosphere(3)
    G, GF = icosphere(2, radius=1.05)
    return V, mesh_from_triangles(V, F, "body"), G, mesh_from_triangles(G, GF, "garment")


def test_a_body_turned_as_a_whole_turns_the_garment_exactly():
    rng = np.random.default_rng(2)
    V, body, G, garment = sphere_body_and_garment()
    R = random_rotation(rng)
    result = fit_to_pose(body, V @ R.T + [0.3, 0, 0], garment, name="turned")
    assert np.allclose(result.V, G @ R.T + [0.3, 0, 0], atol=1e-9)
    info = result.info
    assert info["crossings_outside_contact"] == info["crossings_at_contact"] == info["body_self_crossings"] == 0
    assert info["warnings"] == [] and result.penetrating_vertices == 0
    # Nothing to untangle: the same fit.
    untangled = fit_to_pose(body, V @ R.T + [0.3, 0, 0], garment, name="turned", untangle=True)
    assert np.array_equal(untangled.V, result.V)
    assert untangled.info["untangle"] == {"self_intersections_new_before": 0, "self_intersections_new_after": 0,
                                          "kept": False, "restored_vertices": 0, "given_back": 0}


def test_poses_fitted_at_once_are_each_pose_fitted_alone_read_as_needed_and_stop_when_closed():
    rng = np.random.default_rng(5)
    V, body, _, garment = sphere_body_and_garment()
    # A bulge somewhere else in each pose, the body turned.
    poses = []
    for k in range(5):
        bulge = 1.0 + 0.12 * np.exp(-np.sum((V - V[k * 40]) ** 2, axis=1) / 0.05)
        poses.append((f"pose {k}", (V * bulge[:, None]) @ random_rotation(rng).T))
    prepared = prepare_garment(body, garment)
    alone = {name: fit_to_pose(body, P, garment, prepared=prepared, name=name) for name, P in poses}
    read = []

    def one_by_one():
        for name, P in poses:
            read.append(name)
            yield name, P

    given = fit_poses(body, one_by_one(), garment, prepared=prepared, workers=2)
    name, first = next(given)
    assert name == "pose 0" and np.array_equal(first.V, alone[name].V)
    assert read == ["pose 0", "pose 1", "pose 2"]                          # at most 2 poses ahead of what is given
    rest = list(given)
    assert [n for n, _ in rest] == [n for n, _ in poses[1:]]
    for n, result in rest:
        assert np.array_equal(result.V, alone[n].V) and result.info == alone[n].info
        assert result.obstacle is None and result.surface is None         # not 25 MB a pose kept
        assert result.contact is not None and alone[n].surface is not None
    read.clear()
    given = fit_poses(body, one_by_one(), garment, prepared=prepared, workers=2)
    next(given)
    given.close()                                                          # cancelled: nothing more is read
    assert read == ["pose 0", "pose 1", "pose 2"]


def makehuman_suit():
    root = require_makehuman()
    body = read_obj(root / "bodies" / "female_pear.obj")
    source = read_obj(root / "bodies" / "female_average.obj")
    garment = read_obj(root / "garments" / "female_sportsuit01" / "female_average.obj")
    rest = garment.with_vertices(transfer_garment(source, body, garment).V)
    skeleton = read_skeleton(root / "rig" / "skeleton.json")
    rig = Rig(skeleton, read_joints(root / "rig" / "joints" / "female_pear.json"),
              read_weights(root / "rig" / "weights.json", body.n_vertices))
    T = rig.transforms(bvh_rotations(read_bvh(root / "poses" / "standing01.bvh"), skeleton))
    return body, rest, rig, T


def test_a_makehuman_suit_fitted_to_a_pose_is_clean_and_keeps_its_design_better_than_skinning():
    body, rest, rig, T = makehuman_suit()
    posed = rig.pose(body.V, T)
    result = fit_to_pose(body, posed, rest, prepared=prepare_garment(body, rest), name="standing01")
    # Away from where the posed body crosses itself, no crossing under any split of either mesh's quads.
    contact, own = self_contact(posed, body.F)
    body_F = every_split(body)
    free = body_F[~contact[body_F].any(axis=1)]
    assert own > 0 and sum(crossing_counts(result.V, every_split(rest), posed, free)) == 0
    assert result.info["crossings_outside_contact"] == 0
    # The vertices inside the posed body, counted by the fit from what its pass moved, are those a full search
    # finds on the result.
    assert result.info["inside_after"] == 0
    inside = TriangleSurface(posed, body.F).signed_distance(result.V)[0] < 0
    assert result.penetrating_vertices == int(inside.sum())
    weights, _ = inpainted_weights(body.V, body.F, rig.weights, rest.V, rest.F)
    skinned = rig.pose(rest.V, T, weights)
    assert mdc(rest.V, result.V, rest.F) < mdc(rest.V, skinned, rest.F)


def test_an_untangled_fit_crosses_itself_less_and_the_body_no_more(caplog, monkeypatch):
    body, rest, rig, T = makehuman_suit()
    posed = rig.pose(body.V, T)
    prepared = prepare_garment(body, rest)
    caplog.set_level(logging.WARNING)
    # Every crossing pass says something, as a pass that leaves crossings does.
    real = clearance.separate

    def saying(*args, **kwargs):
        logging.getLogger(clearance.__name__).warning("a pass's own warning")
        return real(*args, **kwargs)

    monkeypatch.setattr(clearance, "separate", saying)
    fit = fit_to_pose(body, posed, rest, prepared=prepared, name="standing01")
    said = [r.getMessage() for r in caplog.records]
    caplog.clear()
    untangled = fit_to_pose(body, posed, rest, prepared=prepared, name="standing01", untangle=True)
    # The untangling's own pass says nothing (what is kept is counted on the result): the same warnings as the fit.
    assert [r.getMessage() for r in caplog.records] == said
    monkeypatch.setattr(clearance, "separate", real)
    figures = untangled.info["untangle"]
    # Counted afresh on both results, against the pose as given.
    posed_body = body.with_vertices(posed)
    offset = fit.info["offset"]
    before, after = (posed_counts(r.V, rest, posed_body, offset, rest_V=body.V) for r in (fit, untangled))
    assert figures["kept"] and figures["self_intersections_new_before"] == before["self_intersections_new"] > 0
    assert figures["self_intersections_new_after"] == after["self_intersections_new"] < before["self_intersections_new"]
    assert after["crossings_outside_contact"] == untangled.info["crossings_outside_contact"] == 0
    assert after["crossings_at_contact"] == untangled.info["crossings_at_contact"] <= before["crossings_at_contact"]
    assert after["penetrating_vertices"] == untangled.penetrating_vertices <= before["penetrating_vertices"]
    # The design kept better than skinning keeps it, as the fit does (measured: MDC 0.030 untangled, 0.028 the fit).
    weights, _ = inpainted_weights(body.V, body.F, rig.weights, rest.V, rest.F)
    assert mdc(rest.V, untangled.V, rest.F) < mdc(rest.V, rig.pose(rest.V, T, weights), rest.F)


def test_shapes_with_poses_writes_every_pose_and_its_counts(tmp_path):
    body, rest, rig, T = makehuman_suit()
    paths = {"rest": tmp_path / "rest.obj", "garment": tmp_path / "suit.obj", "pose": tmp_path / "standing01.obj"}
    write_obj(paths["rest"], body)
    write_obj(paths["garment"], rest)
    write_obj(paths["pose"], body, rig.pose(body.V, T))
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "garment_transfer", "shapes", "--poses", "--source-body",
                        paths["rest"], "--target-body", paths["pose"], "--garment", paths["garment"], "--out", out,
                        "--cache", tmp_path / "suit.pc2", "--json"], cwd=ROOT, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    row, = data["shapes"]
    assert row["crossings_outside_contact"] == 0 and isinstance(data["warnings"], list)
    written = read_obj(row["out"])
    # The point cache: the file as written, one sample per pose from frame 1.
    cache, start, _ = read_pc2(tmp_path / "suit.pc2")
    assert data["cache"] == str(tmp_path / "suit.pc2") and start == 1.0
    assert np.array_equal(cache, written.V[None].astype(np.float32))
    assert np.array_equal(written.face_vertices, rest.face_vertices)      # the garment's own faces
    # The figures are those of the file as written, against the pose file as given, under every split.
    # The pose is the rest body's mesh posed: its own crossings are counted on the rest body's triangles (the
    # pose file, read alone, may split a quad the other way).
    rest_body = read_obj(paths["rest"])
    posed = rest_body.with_vertices(read_obj(paths["pose"]).V)
    offset = row["offset"]
    contact, own = self_contact(posed.V, posed.F, CONTACT_RINGS, rest_body.V, CONTACT_GAP * offset)
    B, G = every_split(posed), every_split(written)
    free, at = B[~contact[B].any(axis=1)], B[contact[B].any(axis=1)]
    assert row["crossings_outside_contact"] == sum(crossing_counts(written.V, G, posed.V, free))
    assert row["crossings_at_contact"] == sum(crossing_counts(written.V, G, posed.V, at))
    assert row["body_self_crossings"] == own
    inside = TriangleSurface(posed.V, posed.F).signed_distance(written.V)[0] < 0
    assert row["penetrating_vertices"] == int(inside.sum())
    # The garment's own crossings as written, every split, beyond those of the garment as given.
    G = readings_of(written)
    pairs = self_intersections(written.V, G)[0]
    assert row["self_intersections"] == pairs and row["self_intersections_new"] > 0
    assert row["self_intersections_new"] == beyond_source(pairs_in_full(written.V, G), G, rest.V,
                                                          pairs_in_full(rest.V, G)).shape[0]
    assert any("crosses itself" in w for w in data["warnings"]) and data["untangle"] is False
    assert "1 of 1 poses fold the cloth through itself where it is not at rest (first: standing01): untangling " \
           "(--untangle) undoes it" in data["warnings"][-1]
    assert json.loads((out / "poses.json").read_text())["shapes"] == [row]
    # One pose at a time writes the same file; --workers without --poses is a usage error.
    alone = tmp_path / "alone"
    p = subprocess.run([sys.executable, "-m", "garment_transfer", "shapes", "--poses", "--workers", "1",
                        "--source-body", paths["rest"], "--target-body", paths["pose"], "--garment", paths["garment"],
                        "--out", alone], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert (alone / "suit_on_standing01.obj").read_bytes() == Path(row["out"]).read_bytes()
    p = subprocess.run([sys.executable, "-m", "garment_transfer", "shapes", "--workers", "2", "--source-body",
                        paths["rest"], "--target-body", paths["pose"], "--garment", paths["garment"], "--out",
                        tmp_path / "never"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "--workers is for --poses" in p.stderr and not (tmp_path / "never").exists()
    p = subprocess.run([sys.executable, "-m", "garment_transfer", "shapes", "--cache", tmp_path / "never.pc2",
                        "--source-body", paths["rest"], "--target-body", paths["pose"], "--garment", paths["garment"],
                        "--out", tmp_path / "never"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "--cache is for --poses" in p.stderr and not (tmp_path / "never.pc2").exists()
    p = subprocess.run([sys.executable, "-m", "garment_transfer", "shapes", "--untangle", "--source-body",
                        paths["rest"], "--target-body", paths["pose"], "--garment", paths["garment"], "--out",
                        tmp_path / "never"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "--untangle is for --poses" in p.stderr and not (tmp_path / "never").exists()


def test_shapes_fits_a_body_animation_given_as_a_point_cache(tmp_path):
    # A character's animation as a pipeline exports it: a PC2 point cache of the body's mesh, here a pose and the
    # rest position, from frame 10 every second frame.
    body, rest, rig, T = makehuman_suit()
    paths = {"rest": tmp_path / "rest.obj", "garment": tmp_path / "suit.obj"}
    write_obj(paths["rest"], body)
    write_obj(paths["garment"], rest)
    samples = np.stack([rig.pose(body.V, T), body.V])
    write_pc2(tmp_path / "walk.pc2", samples, start_frame=10.0, sample_rate=2.0)
    out, cache = tmp_path / "out", tmp_path / "suit.pc2"
    p = subprocess.run([sys.executable, "-m", "garment_transfer", "shapes", "--source-body", paths["rest"],
                        "--target-cache", tmp_path / "walk.pc2", "--garment", paths["garment"], "--out", out,
                        "--cache", cache, "--json"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    data = json.loads(p.stdout)
    assert [(r["target"], r["sample"], r["frame"], r["out"]) for r in data["shapes"]] == \
        [("frame 10", 0, 10.0, str(cache)), ("frame 12", 1, 12.0, str(cache))]
    assert (data["body_cache"], data["start_frame"], data["sample_rate"]) == (str(tmp_path / "walk.pc2"), 10.0, 2.0)
    assert sorted(q.name for q in out.iterdir()) == ["poses.json"]      # no file a frame beside the cache
    # The garment's cache plays in step with the body's (its start and rate), and holds each sample's fit.
    written, start, rate = read_pc2(cache)
    assert (written.shape, start, rate) == ((2, rest.n_vertices, 3), 10.0, 2.0)
    rest_body, garment = read_obj(paths["rest"]), read_obj(paths["garment"])
    read_samples = read_pc2(tmp_path / "walk.pc2")[0].astype(np.float64)
    prepared = prepare_garment(rest_body, garment)
    for k, V in enumerate(read_samples):
        fit = fit_to_pose(rest_body, V, garment, prepared=prepared, name=f"sample {k}")
        assert np.array_equal(written[k], fit.V.astype(np.float32))
    # The figures are the cache's as written, against the body's cache as given, under every split.
    posed = rest_body.with_vertices(read_samples[0])
    W = written[0].astype(np.float64)
    row = data["shapes"][0]
    contact, own = self_contact(posed.V, posed.F, CONTACT_RINGS, rest_body.V, CONTACT_GAP * row["offset"])
    B = every_split(posed)
    free = B[~contact[B].any(axis=1)]
    assert row["crossings_outside_contact"] == sum(crossing_counts(W, every_split(garment), posed.V, free)) == 0
    assert row["body_self_crossings"] == own > 0
    assert row["penetrating_vertices"] == int((TriangleSurface(posed.V, posed.F).signed_distance(W)[0] < 0).sum())
    # The same animation as an MDD file (its times in seconds): the same fits, written as MDD at those times.
    write_mdd(tmp_path / "walk.mdd", samples, [10 / 24, 12 / 24])
    summary = poses_to_files(paths["rest"], [], paths["garment"], tmp_path / "mdd", body_cache=tmp_path / "walk.mdd",
                             cache=tmp_path / "suit.mdd")
    positions, times = read_mdd(tmp_path / "suit.mdd")
    assert np.array_equal(positions, written) and np.array_equal(times, np.float32([10 / 24, 12 / 24]))
    assert [(r["target"], r["sample"], r["time"]) for r in summary["shapes"]] == \
        [(f"time {np.float32(10 / 24):.6g} s", 0, float(np.float32(10 / 24))),
         (f"time {np.float32(12 / 24):.6g} s", 1, float(np.float32(12 / 24)))]
    assert [r["crossings_outside_contact"] for r in summary["shapes"]] == \
        [r["crossings_outside_contact"] for r in data["shapes"]]


def test_a_body_cache_that_is_not_the_bodys_animation_is_refused_naming_it(tmp_path, capsys):
    from test_careless_inputs import one_clean_line, run_cli

    body = mesh_from_triangles(*icosphere(3))
    cloth = mesh_from_triangles(*icosphere(2, radius=1.05))
    write_obj(tmp_path / "rest.obj", body)
    write_obj(tmp_path / "cloth.obj", cloth)
    bad = {"other_mesh.pc2": (body.V[None, :-1], "holds 641 points a sample, but the rest body"),
           "centimetres.pc2": (100 * body.V[None], "at 100 times its size"),
           "nan.pc2": (np.stack([body.V, np.where(np.arange(642)[:, None] == 5, np.nan, body.V)]),
                       "sample 1 (frame 1) has coordinates that are not numbers")}
    for name, (P, message) in bad.items():
        if np.isfinite(P).all():
            write_pc2(tmp_path / name, P)
        else:   # written as a tool that does not check would write it
            data = bytearray(pc2_bytes(np.nan_to_num(P)))
            data[32 + 12 * (642 + 5):32 + 12 * (642 + 6)] = np.full(3, np.nan, "<f4").tobytes()
            (tmp_path / name).write_bytes(bytes(data))
        code, _, err = run_cli(capsys, "shapes", "--source-body", tmp_path / "rest.obj", "--target-cache",
                               tmp_path / name, "--garment", tmp_path / "cloth.obj", "--out", tmp_path / "out",
                               "--cache", tmp_path / "cloth.pc2")
        assert code == 1, err
        one_clean_line(err, str(tmp_path / name), message)
        assert not (tmp_path / "out").exists() and not (tmp_path / "cloth.pc2").exists()
    # Usage: a cache and pose files at once, a cache without one to write, a pose fit with the shapes' options.
    write_pc2(tmp_path / "walk.pc2", body.V[None])
    common = ["shapes", "--source-body", tmp_path / "rest.obj", "--garment", tmp_path / "cloth.obj",
              "--out", tmp_path / "out"]
    for extra, message in (
            (["--target-cache", tmp_path / "walk.pc2", "--target-body", tmp_path / "rest.obj", "--cache",
              tmp_path / "c.pc2"], "--target-cache gives every pose: no --target-body files beside it"),
            (["--target-cache", tmp_path / "walk.pc2"], "--target-cache needs --cache FILE.pc2"),
            (["--target-cache", tmp_path / "walk.pc2", "--cache", tmp_path / "c.pc2", "--no-fix"],
             "--margin and --no-fix are for target shapes"),
            (["--poses", "--target-body", tmp_path / "rest.obj", "--margin", "0.1"],
             "--margin and --no-fix are for target shapes"),
            ([], "give the target shapes as --target-body files")):
        code, _, err = run_cli(capsys, *common, *extra)
        assert code == 2 and message in err, err
        assert not (tmp_path / "out").exists() and not (tmp_path / "c.pc2").exists()
    # The garment's cache is written in the body cache's format: a name that says otherwise is refused, as is a
    # file of neither format.
    write_mdd(tmp_path / "walk.mdd", body.V[None], [0.0])
    (tmp_path / "walk.cache").write_bytes(b"not a cache")
    for given, out, message in ((tmp_path / "walk.mdd", tmp_path / "c.pc2", "format of the body's, MDD"),
                                (tmp_path / "walk.pc2", tmp_path / "c.mdd", "format of the body's, PC2"),
                                (tmp_path / "walk.cache", tmp_path / "c.pc2", "is neither a PC2 point cache")):
        code, _, err = run_cli(capsys, *common, "--target-cache", given, "--cache", out)
        assert code == 1
        one_clean_line(err, message)
        assert not out.exists()
    code, _, err = run_cli(capsys, *common, "--poses", "--target-body", tmp_path / "rest.obj", "--cache",
                           tmp_path / "c.mdd")
    assert code == 1
    one_clean_line(err, "written as one PC2 point cache")
    # A pose file in other units than the rest body is refused the same way.
    write_obj(tmp_path / "pose_cm.obj", body, 100 * body.V)
    code, _, err = run_cli(capsys, *common, "--poses", "--target-body", tmp_path / "pose_cm.obj")
    assert code == 1
    one_clean_line(err, str(tmp_path / "pose_cm.obj"), "at 100 times its size")


def test_a_pose_turned_and_moved_as_an_exporter_writes_it_is_fitted_turned_and_moved():
    # A point cache exported Y up for a rest body written Z up (or in world space): the whole body turned a quarter
    # about X and moved. The fit follows it: the same fit, turned and moved.
    body, rest, rig, T = makehuman_suit()
    posed = rig.pose(body.V, T)
    prepared = prepare_garment(body, rest)
    plain = fit_to_pose(body, posed, rest, prepared=prepared)
    R, t = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]]), np.array([3.0, -2.0, 5.0])
    turned = fit_to_pose(body, posed @ R.T + t, rest, prepared=prepared)
    d = np.linalg.norm((turned.V - t) @ R - plain.V, axis=1)
    # Measured: 0.003 mm on average, 0.5 mm at most (the pass's rounding), on a body 17 dm tall.
    assert d.mean() < 1e-4 and d.max() < 0.02
    assert turned.info["crossings_outside_contact"] == plain.info["crossings_outside_contact"] == 0
