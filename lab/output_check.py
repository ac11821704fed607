"""What the check of a batch's outputs against its inputs costs before a run (``python -m lab.output_check``).

A catalogue of G garments (each dressed on one of 20 bodies, sent to the 19 others, with a reference on each)
is laid out as empty files in a temporary folder, and ``check_batch_outputs`` is timed: once with the results
folder missing (a first run), once with it present (a re-run, when it must also hold no input). The cost per
pair is printed beside the cost of a pair's transfer measured in docs/batch.md (0.89 s), as a share of it.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from garment_transfer.pipeline.batch import check_batch_outputs
from garment_transfer.pipeline.catalogue import catalogue_from_dict

#: Core-seconds of one pair (transfer, penetration fix, metrics, writing) measured in docs/batch.md.
PAIR_SECONDS = 0.89
BODIES = 20


def catalogue(folder: Path, garments: int):
    """A catalogue of ``garments`` garments on ``BODIES`` bodies, its files made empty under ``folder``."""
    (folder / "bodies").mkdir(parents=True)
    for b in range(BODIES):
        (folder / "bodies" / f"b{b}.obj").touch()
    for g in range(garments):
        (folder / "garments" / f"g{g}").mkdir(parents=True)
        for b in range(BODIES):
            (folder / "garments" / f"g{g}" / f"b{b}.obj").touch()
    others = [[f"b{b}" for b in range(BODIES) if b != g % BODIES] for g in range(garments)]
    data = {"bodies": {f"b{b}": f"bodies/b{b}.obj" for b in range(BODIES)},
            "garments": [{"name": f"g{g}", "file": f"garments/g{g}/b{g % BODIES}.obj", "source": f"b{g % BODIES}",
                          "targets": others[g], "references": {t: f"garments/g{g}/{t}.obj" for t in others[g]}}
                         for g in range(garments)]}
    return catalogue_from_dict(data, base=folder, origin=str(folder))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--garments", type=int, nargs="+", default=[1000, 4000])
    args = ap.parse_args(argv)
    print("| garments | pairs | run | check s | per pair ms | share of a pair's transfer |")
    print("| ---: | ---: | --- | ---: | ---: | ---: |")
    for garments in args.garments:
        with tempfile.TemporaryDirectory() as tmp:
            cat = catalogue(Path(tmp) / "DS", garments)
            out = Path(tmp) / "results"
            for run in ("first", "re-run"):
                if run == "re-run":
                    out.mkdir()
                t = time.perf_counter()
                check_batch_outputs(cat, out)
                seconds = time.perf_counter() - t
                per = seconds / cat.n_pairs
                print(f"| {garments} | {cat.n_pairs} | {run} | {seconds:.2f} | {1000 * per:.3f} | "
                      f"{per / PAIR_SECONDS:.5f} |")


if __name__ == "__main__":
    main()
