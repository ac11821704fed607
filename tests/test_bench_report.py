"""The benchmark report in its quick form: every file written, every section in the JSON.

Times are not asserted (the machine is shared); the figures of a quick run mean nothing.
"""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from lab.outfits import OUTFITS
from lab.paths import makehuman_folder
from lab.report import METHODS, PAPER_TABLE1, peak_rss_mb

ROOT = Path(__file__).resolve().parents[1]


def test_quick_report(tmp_path):
    out = tmp_path / "report"
    p = subprocess.run([sys.executable, "-m", "lab", "report", str(out), "--quick",
                        "--json"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    assert json.loads(p.stdout)["report"].endswith("report.md")
    for name in ("report.md", "report.json", "speed.png", "training.png"):
        assert (out / name).is_file(), name
    rep = json.loads((out / "report.json").read_text())
    assert {"date", "machine", "command", "settings", "paper", "quality", "outfits", "speed", "memory",
            "training", "seconds", "plots"} <= set(rep)
    assert rep["settings"]["quick"] is True
    assert {"cpu", "cores", "load_average_start", "load_average_end"} <= set(rep["machine"])
    assert rep["paper"]["table1"] == PAPER_TABLE1

    assert set(rep["quality"]) == {"demo", "makehuman"}
    ran = [res for res in rep["quality"].values() if "skipped" not in res]
    if makehuman_folder() is not None:
        assert "skipped" not in rep["quality"]["makehuman"]
    for res in ran:
        assert {"rows", "summary", "trainings", "worse_than_ours", "surface_deform", "folds"} <= set(res)
        methods = {r["method"] for r in res["rows"]}
        assert {"shared", "paper", "direct", res["reference"]} <= methods
        assert methods <= set(METHODS) | {res["reference"]}
        for m, s in res["summary"].items():
            assert {"pairs", "mdc", "penetration_ratio", "max_penetration_depth", "drape_error",
                    "drape_error_relative", "vertex_error_mean", "seconds"} <= set(s), m
        assert res["summary"]["shared"]["penetration_ratio"] == 0.0
        assert {t["variant"] for t in res["trainings"]} == {"shared", "paper"}
        assert all(t["curve"] for t in res["trainings"])
    if ran:
        assert (out / "quality.png").is_file()

    sizes = rep["speed"]["sizes"]
    assert len(sizes) == len(rep["settings"]["sizes"])
    for r in sizes:
        assert {"field", "bind", "factor", "solve", "fix", "wall"} <= set(r["cold"])
        assert "wall" in r["reused"]
        assert r["exact"] < 1e-12 and r["exact_sample"] == rep["settings"]["exact_sample"]
        assert set(r["solver"].values()) <= {"factor", "multigrid"}
    assert rep["speed"]["multi_target"]["per_target_seconds"]
    assert [m["triangles"] > 0 and m["peak_rss_mb"] >= m["rss_before_mb"] > 0 for m in rep["memory"]] == \
        [True] * len(rep["settings"]["memory_sizes"])
    tr = rep["training"]
    if "skipped" not in tr:
        assert tr["body_triangles"] == 37744 and tr["garments"] == 15
        assert len(tr["curve"]) == tr["epochs"] == rep["settings"]["scale_epochs"]
    md = (out / "report.md").read_text()
    if ran:
        assert "Intersections, checked exactly" in md
        shared = [r for res in ran for r in res["rows"] if r["method"] == "shared"]
        assert shared and all(r["garment_edges_through_body"] == r["body_edges_through_garment"] == 0 for r in shared)
    for heading in ("## Quality", "## Outfits of several layers", "## Speed and scale", "### Peak memory",
                    "## Training"):
        assert heading in md

    outfits = rep["outfits"]
    assert outfits["targets"] == outfits["targets"][:rep["settings"]["outfit_targets"]]
    assert len(outfits["rows"]) == 2 * len(OUTFITS) * len(outfits["targets"]) > 0
    for r in outfits["rows"]:
        assert r["garment_edge_body_pairs"] == r["body_edge_garment_pairs"] == r["layer_crossings"] == 0, r
    assert all(f["refused"] for f in outfits["refusals"]) and len(outfits["refusals"]) == len(OUTFITS)
    assert f"Crossings left: 0 of {len(outfits['rows'])} layers" in md

    # The speed section again, the others kept from the report in the folder.
    rep["measured"] = {k: "earlier" for k in ("quality", "outfits", "speed", "memory", "training")}
    (out / "report.json").write_text(json.dumps(rep))
    p = subprocess.run([sys.executable, "-m", "lab", "report", str(out), "--quick", "--only", "speed"],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    again = json.loads((out / "report.json").read_text())
    for key in ("quality", "outfits", "memory", "training"):
        assert again[key] == rep[key], key
        assert again["measured"][key] == "earlier"
    assert again["measured"]["speed"] == again["date"] != "earlier"
    assert again["speed"]["sizes"][0]["cold"]["wall"] != rep["speed"]["sizes"][0]["cold"]["wall"]
    assert "Sections measured at different times" in (out / "report.md").read_text()
    bad = subprocess.run([sys.executable, "-m", "lab", "report", str(tmp_path / "none"), "--only", "speed"],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "report.json" in bad.stderr and not (tmp_path / "none").exists()


def test_peak_rss_is_the_child_own():
    # A small process started from a big one reports its own peak, not its parent's size.
    big = np.ones(400 * 2 ** 20 // 8)
    assert peak_rss_mb() > 400
    code = "from lab.report import peak_rss_mb; print(peak_rss_mb())"
    p = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert p.returncode == 0, p.stderr
    assert 0 < float(p.stdout) < 300
    del big
