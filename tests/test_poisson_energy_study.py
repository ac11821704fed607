"""The lab's comparison of the Poisson solve's two energies (lab.poisson_energy) on a MakeHuman garment."""

import numpy as np
from meshes import require_makehuman

from lab import poisson_energy


def test_both_energies_with_and_without_the_own_placement_on_a_suit(capsys):
    root = require_makehuman()
    rows = poisson_energy.run(root, "female_average", ["female_casualsuit01"], ["female_pear"], progress=print)
    assert [(r["energy"], r["placed"]) for r in rows] == poisson_energy.RUNS
    by = {(r["energy"], r["placed"]): r for r in rows}
    # The garment's own placement (from its fit on the target) brings it closer to that fit, with either energy.
    for e in ("gradients", "edges"):
        assert by[e, True]["vertex_error_mean"] < by[e, False]["vertex_error_mean"]
    # The finite-element energy keeps the design better, direct transfer and placed alike.
    assert by["gradients", False]["mdc"] < by["edges", False]["mdc"]
    assert by["gradients", True]["mdc"] < by["edges", True]["mdc"]
    text = poisson_energy.summarise(rows, ["female_pear"], 100.0)
    assert "gradients + own placement" in text and "prepare_garment" in text
    assert np.isfinite([r["prepare_seconds"] for r in rows]).all()
    assert "female_casualsuit01 on female_pear" in capsys.readouterr().out
