"""Where the lab's data lives: the one place that knows the repository's and the shared folders' layout."""

from __future__ import annotations

import os
from pathlib import Path

#: The repository root (the extension root).
ROOT = Path(__file__).resolve().parents[1]
#: The built-in demo dataset (``lab/blender/make_demo_data.py`` writes it).
DEMO_DATA = ROOT / "data" / "demo"
#: Blender-side scripts the lab runs in subprocesses.
BLENDER_SCRIPTS = ROOT / "lab" / "blender"
#: The MakeHuman fixtures' place beside a checkout (``../shared/data/makehuman``).
SHARED_MAKEHUMAN = ROOT.parent / "shared" / "data" / "makehuman"
MAKEHUMAN_SOURCE = "female_average"
MAKEHUMAN_TARGETS = ("female_pear", "female_slim_banana", "male_average", "male_slim")


def makehuman_folder():
    """The MakeHuman fixtures (``$GARMENT_TRANSFER_MAKEHUMAN``, else ``SHARED_MAKEHUMAN``), or None."""
    env = os.environ.get("GARMENT_TRANSFER_MAKEHUMAN")
    for c in ([Path(env)] if env else []) + [SHARED_MAKEHUMAN]:
        if (c / "bodies").is_dir():
            return c
    return None


def data_folders():
    """The datasets the lab's commands read (the demo data, the MakeHuman fixtures where present): its
    outputs must not land in them, nor be a folder that holds them (``files.check_outputs``)."""
    return [DEMO_DATA] + [f for f in [makehuman_folder()] if f is not None]


#: Millimetres per unit of a dataset's ``units`` (its manifest), for figures in millimetres.
MM_PER_UNIT = {"metres": 1000.0, "meters": 1000.0, "m": 1000.0, "decimetres": 100.0, "decimeters": 100.0,
               "dm": 100.0, "centimetres": 10.0, "centimeters": 10.0, "cm": 10.0, "millimetres": 1.0,
               "millimeters": 1.0, "mm": 1.0}


def mm_per_unit(units):
    """Millimetres per unit of a dataset's ``units`` name, or None for an unknown one."""
    return MM_PER_UNIT.get((units or "").strip().lower())
