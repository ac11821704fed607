"""Render the demo results (``python -m garment_transfer demo``) with Blender: a .blend and Cycles figures.

With the bpy module:
    .venv/bin/python -m lab render --results DIR [--samples 24] [--resolution-percent 100]
In Blender:
    blender --background --python-exit-code 1 --python lab/blender/render_demo.py -- --results DIR

DIR is the folder the demo writes: ``results.json`` (source, targets, test_garments) and ``meshes/``
(``body__<body>.obj``, ``<garment>__<source>__source.obj``, ``<garment>__<target>__<method>.obj``,
``<garment>__<target>__ours_change.npy``). This writes

- ``DIR/demo.blend``: one collection per test garment (rows behind each other along +Y), with columns
  side by side along X: the source garment on the source body, then for each target body our transfer
  (with its per-vertex ``ours_change`` attribute) and the simulated garment on it; the scene camera
  frames the first garment on the source and the first target, the only collections set to render;
  ``--first-target-only`` leaves the other targets out;
- ``DIR/renders/fig7_<garment>.png`` (like the paper's figures 7 and 8): source | ours on the first
  target | simulation on the first target;
- ``DIR/renders/fig11_<garment>.png`` (figure 11): the first test garment on the source body (blue),
  then transferred to every target body (yellow);
- ``DIR/renders/fig3_<garment>_on_<target>.png`` (figure 3): our result on the first target, front and
  back, coloured by how far each vertex moved from the source garment (blue: little, red: most).

Renders use Cycles on the CPU: under the bpy module Workbench and EEVEE need an EGL driver and abort
the process without one. Exit status 0 when everything was written; 1, with one line on stderr naming
the file, when the results folder is missing or malformed or a render fails; 2 for bad arguments.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
# Under a Blender binary the checkout is not installed: import it from here.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# Linear RGB. The paper draws the source garment blue, transferred ones yellow; the simulation, the
# reference, is green here so that it is not mistaken for either.
COLOURS = {
    "body": (0.55, 0.55, 0.55),
    "source": (0.06, 0.22, 0.75),
    "ours": (0.90, 0.62, 0.06),
    "simulation": (0.16, 0.48, 0.20),
    "label": (0.02, 0.02, 0.02),
}
# Heat map stops, cold to hot (position, linear RGB).
RAMP = [(0.0, (0.02, 0.05, 0.70)), (0.25, (0.0, 0.45, 0.90)), (0.5, (0.10, 0.75, 0.15)),
        (0.75, (0.95, 0.80, 0.0)), (1.0, (0.85, 0.03, 0.01))]

SIZES = {"fig7": (960, 540), "fig11": (1200, 400), "fig3": (720, 540)}
LABEL_SIZE = 0.09  # metres: label text height next to 1.7 m bodies
BACKGROUND = 1.0


class ResultsError(Exception):
    """The results folder is missing or malformed; the message names the file."""


def log(msg):
    print(f"render_demo: {msg}", flush=True)


def parse_args(argv):
    parser = argparse.ArgumentParser(prog="render_demo.py",
                                     description="Render the Garment Transfer demo results with Cycles "
                                                 "(CPU).")
    parser.add_argument("--results", type=Path, required=True, help="results folder written by the demo")
    parser.add_argument("--samples", type=int, default=16,
                        help="Cycles samples per pixel (default 16; denoised, that is enough)")
    parser.add_argument("--resolution-percent", type=int, default=100,
                        help="scale of the image sizes (100: fig7 960x540, fig11 1200x400, fig3 720x540)")
    parser.add_argument("--no-denoise", action="store_true",
                        help="do not denoise (by default OpenImageDenoise is used where Cycles has it)")
    parser.add_argument("--first-target-only", action="store_true",
                        help="put only the first target's results in demo.blend (default: every target)")
    args = parser.parse_args(argv)
    if args.samples < 1:
        parser.error("--samples must be at least 1")
    if not 1 <= args.resolution_percent <= 100:
        parser.error("--resolution-percent must be between 1 and 100")
    return args


def script_argv(argv):
    """The script's own arguments: after ``--`` under Blender, else everything after the script."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


# --------------------------------------------------------------------------------------------------
# Results folder


class Results:
    """What the demo wrote, checked up front so that a bad folder fails before any rendering."""

    def __init__(self, folder: Path, first_target_only=False):
        from garment_transfer.errors import MeshError
        from garment_transfer.geometry.obj import read_obj

        self._read_obj = read_obj
        self._mesh_error = MeshError
        self.folder = folder
        if not folder.is_dir():
            raise ResultsError(f"results folder {folder} does not exist (run the demo first)")
        path = folder / "results.json"
        try:
            summary = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ResultsError(f"{path} not found: not a demo results folder") from None
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ResultsError(f"{path} cannot be read as JSON ({exc})") from None
        if not isinstance(summary, dict):
            raise ResultsError(f"{path}: expected a JSON object, found {type(summary).__name__}")
        self.source = summary.get("source")
        if not isinstance(self.source, str) or not self.source:
            raise ResultsError(f"{path}: 'source' must be the source body's name")
        for key in ("targets", "test_garments"):
            value = summary.get(key)
            if not isinstance(value, list) or not value or not all(isinstance(v, str) and v for v in value):
                raise ResultsError(f"{path}: '{key}' must be a non-empty list of names")
        self.targets = list(summary["targets"])
        self.garments = list(summary["test_garments"])
        self.blend_targets = self.targets[:1] if first_target_only else self.targets
        self._meshes = {}
        for name in self.needed_files():
            if not (folder / "meshes" / name).is_file():
                raise ResultsError(f"{folder / 'meshes' / name} not found (named by {path})")

    def needed_files(self):
        first = self.targets[0]
        names = [f"body__{b}.obj" for b in [self.source] + self.targets]
        for g in self.garments:
            names.append(f"{g}__{self.source}__source.obj")
            names += [f"{g}__{t}__{m}.obj" for t in self.blend_targets for m in ("ours", "simulation")]
            names.append(f"{g}__{first}__ours_change.npy")
        names += [f"{self.garments[0]}__{t}__ours.obj" for t in self.targets]
        return list(dict.fromkeys(names))

    def mesh(self, name):
        """The mesh ``meshes/<name>.obj``, read once."""
        if name not in self._meshes:
            path = self.folder / "meshes" / f"{name}.obj"
            try:
                self._meshes[name] = self._read_obj(path)
            except self._mesh_error as exc:
                raise ResultsError(str(exc)) from None
        return self._meshes[name]

    def body(self, body):
        return self.mesh(f"body__{body}")

    def garment(self, garment, body, method):
        mesh = self.mesh(f"{garment}__{body}__{method}")
        source = self.mesh(f"{garment}__{self.source}__source")
        if mesh.n_vertices != source.n_vertices:
            path = self.folder / "meshes" / f"{garment}__{body}__{method}.obj"
            raise ResultsError(f"{path}: "
                               f"{mesh.n_vertices} vertices, the source garment has {source.n_vertices}")
        return mesh

    def change(self, garment, target):
        path = self.folder / "meshes" / f"{garment}__{target}__ours_change.npy"
        try:
            change = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise ResultsError(f"{path} cannot be read ({exc})") from None
        n = self.garment(garment, target, "ours").n_vertices
        if change.shape != (n,) or not np.all(np.isfinite(change)):
            raise ResultsError(f"{path}: expected {n} finite values (one per garment vertex), "
                               f"found shape {change.shape}")
        return change.astype(np.float32)

    def check_meshes(self):
        """Read every mesh the renders and the .blend use (a malformed OBJ fails here, named)."""
        for b in [self.source] + self.targets:
            self.body(b)
        for g in self.garments:
            for t in self.blend_targets:
                self.garment(g, t, "ours")
                self.garment(g, t, "simulation")
            self.change(g, self.targets[0])
        for t in self.targets:
            self.garment(self.garments[0], t, "ours")


# --------------------------------------------------------------------------------------------------
# Scene building


def new_mesh_object(name, mesh, offset=(0.0, 0.0, 0.0), collection=None, data=None):
    """A smooth-shaded object for a garment_transfer Mesh, built with foreach_set (fast for big meshes).

    ``data``: an existing Blender mesh to share instead (a body seen in several columns).
    """
    import bpy

    if data is None:
        data = bpy.data.meshes.new(name)
        V = np.ascontiguousarray(mesh.V, dtype=np.float32)
        data.vertices.add(V.shape[0])
        data.vertices.foreach_set("co", V.ravel())
        data.loops.add(len(mesh.face_vertices))
        data.loops.foreach_set("vertex_index", np.asarray(mesh.face_vertices, dtype=np.int32))
        data.polygons.add(mesh.n_faces)
        data.polygons.foreach_set("loop_start", np.asarray(mesh.face_start[:-1], dtype=np.int32))
        data.update(calc_edges=True)
        if data.validate(verbose=False):
            log(f"{name}: Blender corrected invalid geometry in the mesh")
        data.shade_smooth()
    obj = bpy.data.objects.new(name, data)
    obj.location = offset
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def principled(name, colour, roughness=0.6, sheen=0.0):
    import bpy

    mat = bpy.data.materials.get(name)
    if mat is not None:
        return mat
    mat = bpy.data.materials.new(name)
    mat.diffuse_color = (*colour, 1.0)  # what the viewport's solid mode shows
    nt = node_tree(mat)
    nt.nodes.clear()
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    if sheen:
        bsdf.inputs["Sheen Weight"].default_value = sheen
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def node_tree(datablock):
    """The node tree of a new material or world: Blender 4.x makes them without one until
    ``use_nodes`` is set; 5.0 always gives them one."""
    if datablock.node_tree is None:
        datablock.use_nodes = True
    return datablock.node_tree


def material(kind):
    if kind == "body":
        return principled("body_grey", COLOURS["body"], roughness=0.55)
    if kind == "label":
        return principled("label", COLOURS["label"], roughness=0.9)
    # Garments: a little sheen, as cloth has, keeps the folds readable in flat front light.
    return principled(f"garment_{kind}", COLOURS[kind], roughness=0.75, sheen=0.3)


def heat_material(attribute, vmax):
    """Colour from the point attribute ``attribute`` (metres), 0..vmax through the blue-to-red ramp."""
    import bpy

    mat = bpy.data.materials.new(f"heat_{attribute}")
    nt = node_tree(mat)
    nt.nodes.clear()
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = attribute
    rng = nt.nodes.new("ShaderNodeMapRange")
    rng.inputs["From Min"].default_value = 0.0
    rng.inputs["From Max"].default_value = vmax
    rng.clamp = True
    ramp = nt.nodes.new("ShaderNodeValToRGB")
    elements = ramp.color_ramp.elements
    while len(elements) < len(RAMP):
        elements.new(0.5)
    for el, (pos, col) in zip(elements, RAMP):
        el.position = pos
        el.color = (*col, 1.0)
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Roughness"].default_value = 0.7
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(attr.outputs["Fac"], rng.inputs["Value"])
    nt.links.new(rng.outputs["Result"], ramp.inputs["Fac"])
    nt.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    mat.diffuse_color = (*RAMP[2][1], 1.0)
    return mat


def set_material(obj, mat):
    obj.data.materials.clear()
    obj.data.materials.append(mat)


def add_point_attribute(obj, name, values):
    attr = obj.data.attributes.new(name, "FLOAT", "POINT")
    attr.data.foreach_set("value", np.asarray(values, dtype=np.float32))


def add_label(text, x, z_top, collection=None, name=None, y=0.0):
    """Dark text centred at ``x`` whose top is at height ``z_top``, facing the camera (-Y)."""
    import bpy

    curve = bpy.data.curves.new(name or f"label {text}", type="FONT")
    curve.body = text
    curve.align_x = "CENTER"
    curve.align_y = "TOP"
    curve.size = LABEL_SIZE
    obj = bpy.data.objects.new(name or f"label {text}", curve)
    obj.rotation_euler = (math.pi / 2, 0.0, 0.0)
    obj.location = (x, y - 0.3, z_top)
    (collection or bpy.context.scene.collection).objects.link(obj)
    set_material(obj, material("label"))
    return obj


def column_step(meshes, gap=0.06):
    """Spacing along X between columns: the widest of the meshes shown plus a gap."""
    width = max(float(np.ptp(m.V[:, 0])) for m in meshes)
    return width + gap


def world_points(objects):
    """World-space points that bound what is drawn: mesh vertices, text bounding boxes."""
    import bpy

    bpy.context.view_layer.update()
    pts = []
    for obj in objects:
        M = np.array(obj.matrix_world)
        if obj.type == "MESH":
            co = np.empty(3 * len(obj.data.vertices), dtype=np.float32)
            obj.data.vertices.foreach_get("co", co)
            local = co.reshape(-1, 3).astype(np.float64)
        else:
            local = np.array([tuple(c) for c in obj.bound_box], dtype=np.float64)
        pts.append(local @ M[:3, :3].T + M[:3, 3])
    return np.concatenate(pts)


def setup_scene(size, samples, percent, denoise):
    """Cycles on the CPU, a white backdrop that lights softly, a sun from the front left."""
    import bpy

    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = True
    scene.cycles.use_denoising = denoise
    if denoise:
        scene.cycles.denoiser = "OPENIMAGEDENOISE"
    scene.cycles.max_bounces = 4
    scene.cycles.caustics_reflective = False
    scene.cycles.caustics_refractive = False
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.render.resolution_percentage = percent
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"
    scene.render.film_transparent = False
    try:
        # Standard keeps the paper's saturated blue/yellow; AgX (the default) washes them out.
        scene.view_settings.view_transform = "Standard"
    except TypeError:
        pass

    # The camera sees plain white; everything else sees a dim grey sky (soft fill light).
    world = bpy.data.worlds.new("demo_world")
    scene.world = world
    nt = node_tree(world)
    nt.nodes.clear()
    seen = nt.nodes.new("ShaderNodeBackground")
    seen.inputs["Color"].default_value = (BACKGROUND, BACKGROUND, BACKGROUND, 1.0)
    fill = nt.nodes.new("ShaderNodeBackground")
    fill.inputs["Color"].default_value = (0.45, 0.47, 0.5, 1.0)
    path = nt.nodes.new("ShaderNodeLightPath")
    mix = nt.nodes.new("ShaderNodeMixShader")
    out = nt.nodes.new("ShaderNodeOutputWorld")
    nt.links.new(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
    nt.links.new(fill.outputs["Background"], mix.inputs[1])
    nt.links.new(seen.outputs["Background"], mix.inputs[2])
    nt.links.new(mix.outputs["Shader"], out.inputs["Surface"])

    sun_data = bpy.data.lights.new("sun", type="SUN")
    sun_data.energy = 3.0
    sun_data.angle = math.radians(8)
    sun = bpy.data.objects.new("sun", sun_data)
    # Light travels along the sun's -Z: tilted 50 degrees from straight down toward +Y (the bodies
    # face -Y, so it comes from the front and above), then turned to come from the viewer's left.
    sun.rotation_euler = (math.radians(50), 0.0, math.radians(-30))
    scene.collection.objects.link(sun)
    return scene


def frame_camera(scene, objects, margin=1.06):
    """An orthographic camera looking along +Y (at the bodies' fronts), framing ``objects`` exactly."""
    import bpy
    from mathutils import Euler

    cam_data = bpy.data.cameras.get("camera") or bpy.data.cameras.new("camera")
    cam_data.type = "ORTHO"
    cam_data.sensor_fit = "HORIZONTAL"
    cam = bpy.data.objects.get("camera") or bpy.data.objects.new("camera", cam_data)
    if cam.name not in scene.collection.objects:
        scene.collection.objects.link(cam)
    scene.camera = cam
    rot = Euler((math.radians(88), 0.0, 0.0))  # nearly level: a hint of the top, no distortion
    R = np.array(rot.to_matrix())
    right, up, forward = R[:, 0], R[:, 1], -R[:, 2]
    P = world_points(objects)
    u, v, w = P @ right, P @ up, P @ forward
    aspect = scene.render.resolution_x / scene.render.resolution_y
    cam_data.ortho_scale = margin * max(float(np.ptp(u)), float(np.ptp(v)) * aspect)
    centre = right * (u.min() + u.max()) / 2 + up * (v.min() + v.max()) / 2
    depth = float(np.ptp(w))
    cam.location = tuple(centre + forward * (w.min() - 1.0))
    cam.rotation_euler = rot
    cam_data.clip_start = 0.01
    cam_data.clip_end = depth + 10.0
    return cam


def render_to(scene, path):
    """Render the scene's camera view to ``path`` (PNG), through a temporary file and a rename."""
    import bpy

    tmp = path.with_name(f".tmp-{path.name}")
    scene.render.filepath = str(tmp)
    t, cpu = time.perf_counter(), time.process_time()
    bpy.ops.render.render(write_still=True)
    if not tmp.is_file():
        raise RuntimeError(f"Cycles wrote no image for {path.name}")
    os.replace(tmp, path)
    return time.perf_counter() - t, time.process_time() - cpu


def reset():
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)


# --------------------------------------------------------------------------------------------------
# Layouts


def place_columns(res, columns, collections=None, y=0.0, labels=True):
    """Put columns side by side along X, centred on x = 0, each labelled underneath.

    ``columns``: list of (name, body name or None, garment mesh, material kind, label);
    ``collections``: the collection of each column (default: the scene's).
    Returns the objects made, a list per column.
    """
    import bpy

    meshes = [res.body(b) for _, b, _, _, _ in columns if b] + [g for _, _, g, _, _ in columns]
    bottom = min(float(m.V[:, 2].min()) for m in meshes)
    collections = collections or [None] * len(columns)
    texts = [add_label(label, 0.0, bottom - 0.05, coll, name=f"{name}_label", y=y)
             if labels and label else None for (name, _, _, _, label), coll in zip(columns, collections)]
    bpy.context.view_layer.update()
    # Columns as wide as the widest mesh or label, so that neither runs into its neighbour.
    step = max(column_step(meshes), max([t.dimensions.x + 0.1 for t in texts if t] or [0.0]))
    made = []
    shared = {}
    for i, (name, body, garment, kind, _) in enumerate(columns):
        x = (i - (len(columns) - 1) / 2) * step
        column = []
        collection = collections[i]
        if body:
            obj = new_mesh_object(f"{name}_body", res.body(body), (x, y, 0.0), collection,
                                  data=shared.get(body))
            shared[body] = obj.data
            obj.data.name = f"body_{body}"
            set_material(obj, material("body"))
            column.append(obj)
        gobj = new_mesh_object(name, garment, (x, y, 0.0), collection)
        if kind in COLOURS:
            set_material(gobj, material(kind))
        column.append(gobj)
        if texts[i] is not None:
            texts[i].location.x = x
            column.append(texts[i])
        made.append(column)
    return made


def build_blend(res, path, samples, percent, denoise):
    """demo.blend: a collection per test garment, one row per garment along +Y (behind each other), with
    a child collection for the source and one per target body.

    Only the first garment's source and first target render (the others' camera icons are off, or the
    rows behind and the neighbouring columns would show at the edges and under the labels); the camera
    frames them, so F12 gives the first fig7 image.
    """
    import bpy

    reset()
    scene = setup_scene(SIZES["fig7"], samples, percent, denoise)
    first_row = None
    row_gap = 1.2
    for row, g in enumerate(res.garments):
        coll = bpy.data.collections.new(g)
        scene.collection.children.link(coll)
        coll.hide_render = row > 0
        subs = {}
        for i, key in enumerate([None] + res.blend_targets):
            sub = bpy.data.collections.new(f"{g} source" if key is None else f"{g} on {key}")
            coll.children.link(sub)
            sub.hide_render = i > 1
            subs[key] = sub
        cols = [(f"{g}_source", res.source, res.garment(g, res.source, "source"), "source",
                 f"source ({res.source})")]
        colls = [subs[None]]
        for t in res.blend_targets:
            cols.append((f"{g}_on_{t}_ours", t, res.garment(g, t, "ours"), "ours", f"ours on {t}"))
            cols.append((f"{g}_on_{t}_simulation", t, res.garment(g, t, "simulation"), "simulation",
                         f"simulation on {t}"))
            colls += [subs[t], subs[t]]
        made = place_columns(res, cols, colls, y=row * row_gap)
        if row == 0:
            first_row = [o for column in made[:3] for o in column]
        for t in res.blend_targets:
            # Per-vertex distance moved, kept on our results for a heat map in Blender.
            obj = bpy.data.objects[f"{g}_on_{t}_ours"]
            npy = res.folder / "meshes" / f"{g}__{t}__ours_change.npy"
            values = res.change(g, t) if npy.is_file() else None
            if values is not None:
                add_point_attribute(obj, "ours_change", values)
    frame_camera(scene, first_row)
    tmp = path.with_name(f".tmp-{path.name}")
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp), compress=True, check_existing=False)
    os.replace(tmp, path)
    return [o.name for o in bpy.data.objects]


def render_fig7(res, g, out, samples, percent, denoise):
    reset()
    scene = setup_scene(SIZES["fig7"], samples, percent, denoise)
    t = res.targets[0]
    made = place_columns(res, [
        (f"{g}_source", res.source, res.garment(g, res.source, "source"), "source", f"source ({res.source})"),
        (f"{g}_on_{t}_ours", t, res.garment(g, t, "ours"), "ours", f"ours on {t}"),
        (f"{g}_on_{t}_simulation", t, res.garment(g, t, "simulation"), "simulation", f"simulation on {t}"),
    ])
    frame_camera(scene, [o for column in made for o in column])
    return render_to(scene, out)


def render_fig11(res, g, out, samples, percent, denoise):
    reset()
    scene = setup_scene(SIZES["fig11"], samples, percent, denoise)
    cols = [(f"{g}_source", res.source, res.garment(g, res.source, "source"), "source", res.source)]
    cols += [(f"{g}_on_{t}_ours", t, res.garment(g, t, "ours"), "ours", t) for t in res.targets]
    made = place_columns(res, cols)
    frame_camera(scene, [o for column in made for o in column])
    return render_to(scene, out)


def render_fig3(res, g, t, out, samples, percent, denoise):
    """Front and back of our result on ``t``, coloured by the distance each vertex moved."""
    reset()
    scene = setup_scene(SIZES["fig3"], samples, percent, denoise)
    garment = res.garment(g, t, "ours")
    change = res.change(g, t)
    # The 99th percentile, not the maximum, sets the red end: one stray vertex would turn the rest blue.
    vmax = max(float(np.percentile(change, 99)), 1e-6)
    mat = heat_material("ours_change", vmax)
    step = column_step([garment], gap=0.12)
    centre = (garment.V.min(axis=0) + garment.V.max(axis=0)) / 2
    made = []
    for i, (view, turn) in enumerate((("front", 0.0), ("back", math.pi))):
        x = (i - 0.5) * step
        obj = new_mesh_object(f"{g}_on_{t}_ours_{view}", garment, collection=None)
        add_point_attribute(obj, "ours_change", change)
        set_material(obj, mat)
        # Turn about the garment's own vertical axis so that the back view faces the camera too.
        obj.rotation_euler = (0.0, 0.0, turn)
        c = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]]) @ centre[:2]
        obj.location = (x - c[0], centre[1] - c[1], 0.0)
        made.append(obj)
        made.append(add_label(view, x, float(garment.V[:, 2].min()) - 0.04))
    made += colour_bar(mat, vmax, x=step + 0.02, z0=float(garment.V[:, 2].min()),
                       z1=float(garment.V[:, 2].max()))
    frame_camera(scene, made)
    return (*render_to(scene, out), vmax)


def colour_bar(mat, vmax, x, z0, z1, width=0.05):
    """A vertical strip in the heat map's colours, labelled 0 at the bottom and vmax (mm) at the top."""
    from garment_transfer.geometry.mesh import mesh_from_polygons

    n = 32
    zs = np.linspace(z0, z1, n + 1)
    V = np.zeros((2 * (n + 1), 3))
    V[0::2, 0], V[1::2, 0] = x - width / 2, x + width / 2
    V[0::2, 2] = V[1::2, 2] = zs
    quads = np.array([[2 * i, 2 * i + 1, 2 * i + 3, 2 * i + 2] for i in range(n)])
    bar = new_mesh_object("colour_bar", mesh_from_polygons(V, quads, name="colour_bar"), (0.0, -0.25, 0.0))
    add_point_attribute(bar, "ours_change", np.repeat(np.linspace(0.0, vmax, n + 1), 2))
    set_material(bar, mat)
    lo = add_label("0 mm", x, z0 - 0.03, name="bar_low")
    mm = vmax * 1000
    hi = add_label(f"{mm:.0f} mm" if mm >= 10 else f"{mm:.2g} mm", x, z1 + 0.03 + LABEL_SIZE, name="bar_high")
    return [bar, lo, hi]


# --------------------------------------------------------------------------------------------------


def main(argv=None):
    args = parse_args(script_argv(sys.argv) if argv is None else argv)
    try:
        import bpy  # noqa: F401
    except ImportError:
        print("render_demo: error: needs Blender's bpy module (pip install bpy, or run inside Blender)",
              file=sys.stderr)
        return 1
    denoise = not args.no_denoise
    if denoise:
        try:
            import _cycles
            denoise = bool(getattr(_cycles, "with_openimagedenoise", False))
        except ImportError:
            denoise = False
    folder = args.results
    t_all = time.perf_counter()
    written = []
    try:
        res = Results(folder, first_target_only=args.first_target_only)
        res.check_meshes()
        log(f"source {res.source}, targets {', '.join(res.targets)}, "
            f"test garments {', '.join(res.garments)}; "
            f"Cycles CPU, {args.samples} samples, {args.resolution_percent}% size, "
            f"denoising {'on (OpenImageDenoise)' if denoise else 'off'}")
        renders = folder / "renders"
        renders.mkdir(exist_ok=True)
        t = time.perf_counter()
        blend = folder / "demo.blend"
        build_blend(res, blend, args.samples, args.resolution_percent, denoise)
        written.append(blend)
        log(f"wrote {blend} ({time.perf_counter() - t:.1f} s)")
        jobs = [(f"fig7_{g}.png", render_fig7, (g,)) for g in res.garments]
        jobs.append((f"fig11_{res.garments[0]}.png", render_fig11, (res.garments[0],)))
        first = res.targets[0]
        jobs += [(f"fig3_{g}_on_{first}.png", render_fig3, (g, first)) for g in res.garments]
        for i, (name, fn, extra) in enumerate(jobs, 1):
            out = renders / name
            seconds, cpu, *vmax = fn(res, *extra, out, args.samples, args.resolution_percent, denoise)
            note = f"; red = {vmax[0] * 1000:.1f} mm and more" if vmax else ""
            written.append(out)
            log(f"[{i}/{len(jobs)}] rendered {out} in {seconds:.1f} s ({cpu:.1f} s CPU){note}")
    except ResultsError as exc:
        print(f"render_demo: error: {exc}", file=sys.stderr)
        return 1
    except Exception as exc:
        # A render or save failing: the traceback, then one clear last line for the demo's message.
        traceback.print_exc()
        print(f"render_demo: error: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    log(f"done in {time.perf_counter() - t_all:.1f} s; wrote: {', '.join(str(p) for p in written)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
