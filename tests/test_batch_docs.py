"""docs/batch.md's examples, run as written: the catalogue (TOML, and its JSON form) on the MakeHuman
fixtures, every command line of the page through the real parser, the dataset-folder catalogue, and the
Python entry point of the Dask section."""

from __future__ import annotations

import inspect
import json
import shlex
import tomllib
from pathlib import Path

import pytest
from meshes import require_makehuman

import garment_transfer
from garment_transfer.cli import main
from garment_transfer.cli.commands import build_parser
from garment_transfer.pipeline.catalogue import CatalogueError, read_catalogue

DOC = Path(__file__).resolve().parents[1] / "docs" / "batch.md"


def blocks(language):
    """The page's fenced code blocks of ``language`` ("" for plain ones), in order."""
    found, current, kind = [], None, None
    for line in DOC.read_text(encoding="utf-8").splitlines(keepends=True):
        if line.startswith("```"):
            if current is None:
                current, kind = [], line[3:].strip()
            else:
                if kind == language:
                    found.append("".join(current))
                current = None
        elif current is not None:
            current.append(line)
    return found


@pytest.fixture
def fixtures_folder(tmp_path):
    """A folder laid out like the MakeHuman fixtures (links to them), to save the catalogue in."""
    makehuman = require_makehuman()
    folder = tmp_path / "makehuman"
    folder.mkdir()
    for part in ("bodies", "garments"):
        (folder / part).symlink_to(makehuman / part)
    return folder


def test_the_catalogue_example_runs_as_written(fixtures_folder, tmp_path, capsys):
    toml = blocks("toml")[0]
    catalogue = fixtures_folder / "catalogue.toml"
    catalogue.write_text(toml, encoding="utf-8")
    out = tmp_path / "results"
    code = main(["batch", str(catalogue), "--out", str(out), "--workers", "1", "--no-progress", "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert json.loads(captured.out)["counts"] == {"done": 4, "skipped": 0, "failed": 0, "not run": 0}
    records = {(g, t): json.loads((out / g / f"{t}.json").read_text()) for g, t in
               (("sportsuit", "female_pear"), ("sportsuit", "male_slim"), ("casual", "male_slim"),
                ("casual", "female_pear"))}
    # Both ways of giving a reference work; the garment's own offset wins over the defaults.
    assert records["casual", "female_pear"]["drape_reference"] == "reference"
    assert records["casual", "male_slim"]["drape_reference"] == "reference"
    assert records["sportsuit", "male_slim"]["drape_reference"] is None
    assert records["casual", "male_slim"]["settings"]["offset"] == 0.03
    assert records["sportsuit", "male_slim"]["settings"]["offset"] is None


def test_the_json_form_has_the_same_keys(fixtures_folder):
    toml = blocks("toml")[0]
    (fixtures_folder / "catalogue.toml").write_text(toml, encoding="utf-8")
    (fixtures_folder / "catalogue.json").write_text(json.dumps(tomllib.loads(toml)), encoding="utf-8")
    a, b = (read_catalogue(fixtures_folder / f"catalogue.{ext}") for ext in ("toml", "json"))
    assert a.jobs == b.jobs and a.pairs() == b.pairs()


def test_top_level_keys_written_after_bodies_are_named(fixtures_folder):
    # The mistake the example once made: in TOML, keys after [bodies] belong to it.
    toml = blocks("toml")[0]
    head, tables = toml.split("\n[settings]", 1)
    top = "\n".join(line for line in head.splitlines() if line.startswith(("source =", "targets =")))
    assert top.count("\n") == 1
    moved = "[settings]" + tables.replace('male_slim = "bodies/male_slim.obj"\n',
                                          f'male_slim = "bodies/male_slim.obj"\n{top}\n')
    (fixtures_folder / "late.toml").write_text(moved, encoding="utf-8")
    with pytest.raises(CatalogueError, match=r"bodies\.(source|targets).*top-level key.*above the first \[table\]"):
        read_catalogue(fixtures_folder / "late.toml")


def command_lines():
    """Every ``python -m garment_transfer batch ...`` line of the page (comments dropped)."""
    lines = []
    for block in blocks(""):
        for line in block.splitlines():
            if line.startswith("python -m garment_transfer batch"):
                lines.append(shlex.split(line.split("#")[0])[3:])
    return lines


def test_every_command_line_of_the_page_parses():
    lines = command_lines()
    assert len(lines) >= 6
    for argv in lines:
        args = build_parser().parse_args(argv)
        assert args.command == "batch" and args.out


def test_the_dataset_folder_example_is_a_catalogue():
    makehuman = require_makehuman()
    (argv,) = [a for a in command_lines() if "--source" in a]
    args = build_parser().parse_args(argv)
    cat = read_catalogue(makehuman, source=args.source)
    manifest = json.loads((makehuman / "manifest.json").read_text())
    assert len(cat.jobs) == len(manifest["garments"]) and cat.n_pairs == 4 * len(cat.jobs)
    assert all(t.reference is not None for j in cat.jobs for t in j.targets)


def test_the_python_entry_point_of_the_dask_section_exists():
    (python,) = [b for b in blocks("python") if "run_batch" in b]
    assert "from garment_transfer import read_catalogue, run_batch" in python
    assert {"read_catalogue", "run_batch"} <= set(garment_transfer.__all__)
    assert "client" in inspect.signature(garment_transfer.run_batch).parameters


def test_the_rig_example_reads_with_the_catalogue(fixtures_folder):
    # The rig table added to the example catalogue: its joints name the catalogue's bodies, each pair then has them.
    catalogue, rig = blocks("toml")
    (fixtures_folder / "rig").symlink_to(require_makehuman() / "rig")
    top, rest = catalogue.split("\n[", 1)
    (fixtures_folder / "catalogue.toml").write_text(top + "\n" + rig + "\n[" + rest, encoding="utf-8")
    cat = read_catalogue(fixtures_folder / "catalogue.toml")
    assert all(job.rig is not None and job.rig.source_joints.endswith("female_average.json") for job in cat.jobs)
    joints = {t.name: t.joints for job in cat.jobs for t in job.targets}
    assert joints["female_pear"].endswith("rig/joints/female_pear.json") and joints["male_slim"] is None
