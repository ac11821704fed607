"""Nothing lost, in every command: every command of the command line (found in its parser, so a new one is
caught here), every one of its inputs, and its output pointed at that input, into an input folder, at a folder
that holds inputs, and through ``..``, symlink and hard-link spellings. Each is refused before any work (the
work functions fail if they are called), with exit code 1, one line naming the path as given, and every file
left byte for byte as it was. The same for the Blender batch script (exit 2: its bad arguments) and the lab's
commands that write into a folder.

One check does it (``files.check_outputs``); the commands only declare what they read and write
(``cli/paths.py``). Case folding is not exercised: this file system does not fold case; the check compares
what a path reaches (device and inode), which is what a folding file system folds to.
"""

from __future__ import annotations

import importlib.util
import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from meshes import icosphere
from test_careless_inputs import one_clean_line, run_cli, snapshot

from garment_transfer.cli import batch as cli_batch
from garment_transfer.cli import commands, paths
from garment_transfer.cli import weights as cli_weights
from garment_transfer.cli.commands import build_parser
from garment_transfer.geometry.mesh import mesh_from_triangles
from garment_transfer.geometry.obj import write_obj
from garment_transfer.geometry.pc2 import write_pc2

ROOT = Path(__file__).resolve().parents[1]


class WorkStarted(Exception):
    """Raised by every work function of the commands: the refusal came too late."""


#: Where each command's work starts (module, name): reading meshes, registering, transferring, training.
WORK = [(commands, name) for name in ("read_obj", "transfer_to_any_body", "transfer_outfit", "register",
                                      "shapes_to_files", "evaluate", "train_from_dataset",
                                      "train_garment_fit_from_dataset", "training_garments", "check_after_training")]
WORK += [(cli_batch, "run_batch"), (commands, "poses_to_files"), (cli_weights, "read_obj")]


@pytest.fixture
def no_work(monkeypatch):
    def work(*args, **kwargs):
        raise WorkStarted

    for module, name in WORK:
        monkeypatch.setattr(module, name, work)


# ----------------------------------------------------------------------------------------------
# A small world of inputs: loose files, a dataset folder, a catalogue naming files of the dataset.


def band(V, F, below=0.2):
    keep = V[F].mean(axis=1)[:, 2] < below
    used = np.unique(F[keep])
    remap = -np.ones(V.shape[0], np.int64)
    remap[used] = np.arange(used.size)
    return V[used], remap[F[keep]]


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    w = tmp_path_factory.mktemp("world")
    V, F = icosphere(1)
    GV, GF = band(V * 1.05, F)
    for name, shape in (("banana", 1.0), ("pear", np.array([1.2, 1.1, 1.0]))):
        (w / "DS" / "bodies").mkdir(parents=True, exist_ok=True)
        write_obj(w / "DS" / "bodies" / f"{name}.obj", mesh_from_triangles(V * shape, F))
        for g, scale in (("skirt", 1.0), ("top", 1.02)):
            (w / "DS" / "garments" / g).mkdir(parents=True, exist_ok=True)
            write_obj(w / "DS" / "garments" / g / f"{name}.obj", mesh_from_triangles(GV * scale * shape, GF))
    (w / "DS" / "manifest.json").write_text('{"source": "banana"}\n')
    write_obj(w / "source.obj", mesh_from_triangles(V, F))
    write_obj(w / "target.obj", mesh_from_triangles(V * 1.1, F))
    write_obj(w / "cage.obj", mesh_from_triangles(V * 1.1, F))
    write_pc2(w / "walk.pc2", np.stack([V, V * 1.01]))
    write_obj(w / "basis.obj", mesh_from_triangles(V * [1.0, 1.2, 1.0], F))
    (w / "clothes").mkdir()
    write_obj(w / "clothes" / "garment.obj", mesh_from_triangles(GV, GF))
    write_obj(w / "clothes" / "coat.obj", mesh_from_triangles(GV * 1.03, GF))
    write_obj(w / "result.obj", mesh_from_triangles(GV * 1.1, GF))
    write_obj(w / "reference.obj", mesh_from_triangles(GV * 1.1, GF))
    (w / "weights.json").write_text('{"weights": {"spine": [[0, 1.0]]}}\n')
    (w / "skeleton.json").write_text('{"bones": {"spine": {"parent": null, "head": "a", "tail": "b"}}}\n')
    (w / "joints.json").write_text('{"a": [0, 0, 0], "b": [0, 1, 0]}\n')
    (w / "target_joints.json").write_text('{"a": [0, 0, 0], "b": [0, 1.1, 0]}\n')
    np.savez(w / "model.npz", a=np.zeros(3))
    np.savez(w / "targets.npz", a=np.zeros(3))
    (w / "cat.toml").write_text(
        'source = "banana"\ntargets = ["pear"]\n\n[settings]\nmethod = "model"\nmodel = "model.npz"\n\n'
        '[bodies]\nbanana = "DS/bodies/banana.obj"\npear = "DS/bodies/pear.obj"\n\n'
        '[[garments]]\nname = "bodies"\nfile = "DS/garments/skirt/banana.obj"\n'
        'references = { pear = "DS/garments/skirt/pear.obj" }\n')
    # A shape file named as the output shapes would give it: the result must not replace it.
    (w / "shapes").mkdir()
    write_obj(w / "shapes" / "garment_on_target.obj", mesh_from_triangles(V * 1.3, F))
    (w / "elsewhere").mkdir()
    (w / "elsewhere" / "sub").mkdir()
    return w


# ----------------------------------------------------------------------------------------------
# Every command, its inputs, and its outputs.


@dataclass
class Command:
    """How to run a command with all its inputs given, and where its outputs go.

    ``inputs``: option -> file or folder names in the world (relative); ``outputs``: option -> "file" or
    "folder"; ``settings``: every other option of the command's parser; ``args(world, outputs)``: the command
    line, ``outputs`` giving each output option its value.
    """

    args: callable
    inputs: dict
    outputs: dict
    settings: set = field(default_factory=set)


def _transfer(w, out):
    return ["transfer", "--source-body", w / "source.obj", "--target-body", w / "target.obj", "--target-cage",
            w / "cage.obj", "--garment", w / "clothes" / "garment.obj", "--model", w / "model.npz", "--target", "pear",
            "--shape-basis",
            w / "basis.obj", "--body-model", w / "targets.npz", "--skeleton", w / "skeleton.json", "--source-joints",
            w / "joints.json", "--source-weights", w / "weights.json", "--target-joints", w / "target_joints.json",
            "--out", out["--out"]]


def _outfit(w, out):
    outs = out["--out"] if isinstance(out["--out"], list) else [out["--out"]]
    return ["transfer", "--source-body", w / "source.obj", "--target-body", w / "target.obj", "--garment",
            w / "clothes" / "garment.obj", "--garment", w / "clothes" / "coat.obj", "--model", w / "model.npz",
            "--target", "pear", *[a for o in outs for a in ("--out", o)]]


TRANSFER_SETTINGS = {"--method", "--target", "--field-share", "--no-placement", "--offset", "--no-fix",
                     "--no-crossing-pass", "--no-interpolate", "--no-cache", "--untangle", "--json"}

COMMANDS = {
    "transfer": Command(_transfer, {"--source-body": "source.obj", "--target-body": "target.obj",
                                    "--target-cage": "cage.obj",
                                    "--garment": "clothes/garment.obj", "--model": "model.npz",
                                    "--shape-basis": "basis.obj", "--body-model": "targets.npz",
                                    "--skeleton": "skeleton.json", "--source-joints": "joints.json",
                                    "--source-weights": "weights.json", "--target-joints": "target_joints.json"},
                        {"--out": "file"}, TRANSFER_SETTINGS),
    # With --poses and its point cache: every output of the command.
    "shapes": Command(lambda w, out: ["shapes", "--poses", "--source-body", w / "source.obj", "--target-body",
                                      w / "target.obj", "--target-body", w / "DS" / "bodies" / "pear.obj",
                                      "--garment", w / "clothes" / "garment.obj", "--out", out["--out"],
                                      "--cache", out["--cache"]],
                      {"--source-body": "source.obj", "--target-body": "target.obj",
                       "--garment": "clothes/garment.obj"},
                      {"--out": "folder", "--cache": "file"},
                      {"--offset", "--margin", "--no-fix", "--poses", "--workers", "--untangle", "--json"}),
    # A body's animation as a point cache in, the garment's out.
    "shapes --target-cache": Command(lambda w, out: ["shapes", "--source-body", w / "source.obj", "--target-cache",
                                                     w / "walk.pc2", "--garment", w / "clothes" / "garment.obj",
                                                     "--out", out["--out"], "--cache", out["--cache"]],
                                     {"--source-body": "source.obj", "--target-cache": "walk.pc2",
                                      "--garment": "clothes/garment.obj"},
                                     {"--out": "folder", "--cache": "file"}, set()),
    "weights": Command(lambda w, out: ["weights", "--body", w / "source.obj", "--weights", w / "weights.json",
                                       "--garment", w / "clothes" / "garment.obj", "--out", out["--out"]],
                       {"--body": "source.obj", "--weights": "weights.json", "--garment": "clothes/garment.obj"},
                       {"--out": "file"},
                       {"--rule", "--max-influences", "--match-distance", "--match-angle", "--json"}),
    "register": Command(lambda w, out: ["register", "--source-body", w / "source.obj", "--target-body",
                                        w / "target.obj", "--shape-basis", w / "basis.obj", "--body-model",
                                        w / "targets.npz", "--out", out["--out"]],
                        {"--source-body": "source.obj", "--target-body": "target.obj", "--shape-basis": "basis.obj",
                         "--body-model": "targets.npz"},
                        {"--out": "file"}, {"--no-cache", "--json"}),
    "evaluate": Command(lambda w, out: ["evaluate", "--source", w / "clothes" / "garment.obj", "--result",
                                        w / "result.obj", "--target-body", w / "target.obj", "--reference",
                                        w / "reference.obj", "--source-body", w / "source.obj"],
                        {"--source": "clothes/garment.obj", "--result": "result.obj", "--target-body": "target.obj",
                         "--reference": "reference.obj", "--source-body": "source.obj"},
                        {}, {"--json"}),
    "train": Command(lambda w, out: ["train", "--dataset", w / "DS", "--source", "banana", "--targets", "pear",
                                     "--out", out["--out"]],
                     {"--dataset": "DS"}, {"--out": "file"},
                     {"--kind", "--source", "--targets", "--garments", "--epochs", "--latent", "--seed", "--threads",
                      "--unmasked", "--placement-epochs", "--placement-members", "--no-placement",
                      "--placement-absolute", "--nearest-garments", "--hold-out", "--json"}),
    "batch": Command(lambda w, out: ["batch", w / "cat.toml", "--model", w / "model.npz", "--workers", "1",
                                     "--out", out["--out"], *(["--log", out["--log"]] if "--log" in out else [])],
                     {"catalogue": "cat.toml", "--model": "model.npz"}, {"--out": "folder", "--log": "file"},
                     {"--source", "--targets", "--garments", "--method", "--field-share", "--offset", "--no-fix",
                      "--no-interpolate", "--untangle", "--workers", "--dask", "--scheduler", "--no-progress",
                      "--json"}),
}

#: What an input of a command reads beyond its own path: the catalogue names files of the dataset; a
#: dataset folder is read through its bodies/, garments/ and manifest.json (those, not the folder itself:
#: the dataset's folder may hold a model file or results beside them).
READ_ALSO = {("batch", "catalogue"): ["cat.toml", "DS/bodies/banana.obj", "DS/bodies/pear.obj",
                                      "DS/garments/skirt/banana.obj", "DS/garments/skirt/pear.obj"],
             ("train", "--dataset"): ["DS/bodies", "DS/garments", "DS/manifest.json", "DS/bodies/pear.obj",
                                      "DS/garments/top/banana.obj"]}


def subcommands():
    parser = build_parser()
    action = next(a for a in parser._actions if a.dest == "command")
    return action.choices


def test_every_command_and_every_option_is_known_here_and_declared():
    subs = subcommands()
    # A key of COMMANDS is a command, or a command and the option that gives another way of running it.
    assert set(subs) == {key.split()[0] for key in COMMANDS}, "a command this test does not walk: add it to COMMANDS"
    assert set(paths.DECLARED) == set(subs), "a command without a declaration of what it reads and writes"
    for name, sub in subs.items():
        options = {a.option_strings[0] if a.option_strings else a.dest for a in sub._actions
                   if a.dest != "help"}
        known = set().union(*(set(c.inputs) | set(c.outputs) | c.settings
                              for key, c in COMMANDS.items() if key.split()[0] == name))
        assert options == known, (name, options ^ known)


def spellings(w, rel):
    """The ways an output can reach the input ``rel`` (a file or folder of the world): (label, path)."""
    target = w / rel
    out = [("as given", target), ("through ..", w / "elsewhere" / "sub" / ".." / ".." / rel)]
    link = w / "elsewhere" / f"link-{rel.replace('/', '-')}"
    if not os.path.lexists(link):
        os.symlink(target, link)
    out.append(("through a symlink", link))
    if target.is_file():
        hard = w / "elsewhere" / f"hard-{rel.replace('/', '-')}"
        if not hard.exists():
            os.link(target, hard)
        out.append(("through a hard link", hard))
    else:
        out += [("a new file inside", target / "new.out"), ("inside, through a linked folder", link / "new.out")]
    return out


def reached(name):
    """(option, input) pairs of a command: every input, or what it reads (``READ_ALSO``)."""
    return [(opt, rel) for opt, given in COMMANDS[name].inputs.items()
            for rel in READ_ALSO.get((name, opt), [given])]


def fresh_outputs(w, tmp_path, name):
    return {opt: str(tmp_path / ("results" if kind == "folder" else f"new{opt.strip('-')}.out"))
            for opt, kind in COMMANDS[name].outputs.items()}


def assert_refused(capsys, w, args, shown):
    before = snapshot(w)
    code, _, err = run_cli(capsys, *args)
    assert code == 1, (args, err)
    one_clean_line(err, str(shown))
    assert snapshot(w) == before


CASES = [(name, opt, rel) for name in COMMANDS for opt, rel in reached(name) if COMMANDS[name].outputs]


@pytest.mark.parametrize("name, option, rel", CASES, ids=[f"{n} {o} {r}" for n, o, r in CASES])
def test_an_output_pointed_at_an_input_is_refused_before_any_work(world, tmp_path, capsys, no_work, name, option,
                                                                  rel):
    command = COMMANDS[name]
    for out_option in command.outputs:
        for label, path in spellings(world, rel):
            outs = fresh_outputs(world, tmp_path, name)
            outs[out_option] = str(path)
            assert_refused(capsys, world, command.args(world, outs), path)


@pytest.mark.parametrize("name", [n for n in COMMANDS if COMMANDS[n].outputs])
def test_with_fresh_outputs_the_work_starts(world, tmp_path, capsys, no_work, name):
    # The command lines above are right but for the output: with new outputs, the command gets to its work.
    with pytest.raises(WorkStarted):
        run_cli(capsys, *COMMANDS[name].args(world, fresh_outputs(world, tmp_path, name)))


def test_the_model_may_be_written_beside_the_dataset_it_reads(world, capsys, no_work):
    # Training reads bodies/, garments/ and manifest.json; a model file next to them harms none of them.
    with pytest.raises(WorkStarted):
        run_cli(capsys, *COMMANDS["train"].args(world, {"--out": world / "DS" / "model.npz"}))


def test_evaluate_writes_nothing(world, capsys, no_work):
    assert not COMMANDS["evaluate"].outputs
    before = snapshot(world)
    with pytest.raises(WorkStarted):
        run_cli(capsys, *COMMANDS["evaluate"].args(world, {}))
    assert snapshot(world) == before


@pytest.mark.parametrize("holder", ["DS", "DS/garments", "DS/bodies", "DS/garments/skirt", ".",
                                    "elsewhere/sub/../../DS"])
def test_a_batch_results_folder_that_holds_an_input_is_refused(world, tmp_path, capsys, no_work, holder):
    # The catalogue names its garment "bodies": with --out DS its result would be DS/bodies/pear.obj.
    out = world / holder
    assert_refused(capsys, world, COMMANDS["batch"].args(world, {"--out": str(out)}), out)
    for dataset_out in (world / "DS", world / "DS" / "garments"):
        args = ["batch", world / "DS", "--targets", "pear", "--workers", "1", "--out", dataset_out]
        assert_refused(capsys, world, args, dataset_out)


def test_outfit_outputs_on_a_layer_or_in_the_garments_folder_are_refused_before_the_work(world, tmp_path, capsys,
                                                                                         no_work):
    garment = world / "clothes" / "garment.obj"
    for outs, shown in (([str(tmp_path / "a.obj"), str(garment)], garment),
                        ([str(world / "clothes")], world / "clothes" / "garment.obj"),
                        ([str(tmp_path / "a.obj"), str(world / "elsewhere" / "sub" / ".." / ".." / "target.obj")],
                         "target.obj")):
        assert_refused(capsys, world, _outfit(world, {"--out": outs}), shown)
    with pytest.raises(WorkStarted):
        run_cli(capsys, *_outfit(world, {"--out": [str(tmp_path / "a.obj"), str(tmp_path / "b.obj")]}))


def test_shapes_results_named_like_an_input_are_refused(world, capsys, no_work):
    shape = world / "shapes" / "garment_on_target.obj"
    args = ["shapes", "--source-body", shape, "--target-body", world / "target.obj", "--garment",
            world / "clothes" / "garment.obj", "--out", world / "shapes"]
    assert_refused(capsys, world, args, shape)


# ----------------------------------------------------------------------------------------------
# Path problems: one line naming the path, before any work, in every command.


@pytest.mark.parametrize("name", [n for n in COMMANDS if COMMANDS[n].outputs])
def test_missing_file_in_the_way_and_read_only_places_are_refused_before_any_work(world, tmp_path, capsys, no_work,
                                                                                 name):
    command = COMMANDS[name]
    afile = tmp_path / "afile"
    afile.write_text("mine\n")
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        for opt, kind in command.outputs.items():
            cases = [(tmp_path / "missing" / "deeper" / "x.out", "does not exist" if kind == "file" else ""),
                     (tmp_path / "missing" / ".." / "x.out", "does not exist" if kind == "file" else ""),
                     (afile / "x.out", "is a file"), (locked / "x.out", "not writable")]
            if kind == "folder":
                cases = [(afile, "is a file, not a folder"), (locked / "x", "not writable"),
                         (afile / "x", "is a file")]
            for path, problem in cases:
                if not problem:
                    continue
                outs = fresh_outputs(world, tmp_path, name)
                outs[opt] = str(path)
                before = snapshot(tmp_path)
                code, _, err = run_cli(capsys, *command.args(world, outs))
                assert code == 1, (name, opt, path, err)
                one_clean_line(err, str(path), problem)
                assert snapshot(tmp_path) == before
    finally:
        locked.chmod(0o755)


# ----------------------------------------------------------------------------------------------
# The Blender batch script and the lab's commands go through the same check.


def batch_script(monkeypatch):
    spec = importlib.util.spec_from_file_location("batch_transfer_script", ROOT / "scripts" / "batch_transfer.py")
    module = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, module)      # its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_the_blender_batch_script_refuses_outputs_on_its_inputs_before_blender_starts(world, tmp_path, capsys,
                                                                                      monkeypatch):
    script = batch_script(monkeypatch)

    def work(*args, **kwargs):
        raise WorkStarted

    monkeypatch.setattr(script, "run", work)
    plain = ["--source-body", world / "source.obj", "--target-body", world / "target.obj", "--garment",
             world / "clothes" / "garment.obj", "--model", world / "model.npz"]
    cases = [(plain + ["--out", world / "target.obj"], world / "target.obj"),
             (plain + ["--out", tmp_path / "o", "--blend", world / "source.obj"], world / "source.obj"),
             (plain + ["--out", world / "elsewhere" / "sub" / ".." / ".." / "model.npz"], "model.npz"),
             (["--catalogue", world / "cat.toml", "--out", world / "DS"], world / "DS"),
             (["--catalogue", world / "cat.toml", "--out", world / "DS" / "garments"], world / "DS" / "garments"),
             (["--catalogue", world / "DS", "--out", world / "DS" / "bodies" / "new"], world / "DS" / "bodies" / "new"),
             (["--catalogue", world / "cat.toml", "--out", tmp_path / "o", "--blend",
               world / "DS" / "garments" / "skirt" / "pear.obj"], world / "DS" / "garments" / "skirt" / "pear.obj")]
    for args, shown in cases:
        before = snapshot(world)
        code = script.main(["batch_transfer.py", *map(str, args)])
        err = capsys.readouterr().err
        assert code == 2, (args, err)
        one_clean_line(err, str(shown))
        assert snapshot(world) == before
    with pytest.raises(WorkStarted):
        script.main(["batch_transfer.py", "--catalogue", str(world / "cat.toml"), "--out", str(tmp_path / "o")])
    assert not (tmp_path / "o").exists()


def test_the_lab_writes_into_no_dataset_it_reads(capsys, monkeypatch, tmp_path):
    import lab.demo
    import lab.report
    from lab.__main__ import main as lab_main
    from lab.paths import DEMO_DATA

    def work(*args, **kwargs):
        raise WorkStarted

    monkeypatch.setattr(lab.demo, "run_demo", work)
    monkeypatch.setattr(lab.report, "run_report", work)
    for args, shown in ((("demo", "--out", DEMO_DATA / "results"), DEMO_DATA / "results"),
                        (("demo", "--out", DEMO_DATA.parent), DEMO_DATA.parent),
                        (("report", DEMO_DATA / "bodies"), DEMO_DATA / "bodies")):
        before = snapshot(DEMO_DATA)
        code, _, err = run_cli(capsys, *args, main=lab_main)
        assert code == 1
        one_clean_line(err, str(shown))
        assert snapshot(DEMO_DATA) == before
    with pytest.raises(WorkStarted):
        run_cli(capsys, "demo", "--out", tmp_path / "results", main=lab_main)
