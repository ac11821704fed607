import pytest

from lab.experiment import METHODS, method_of


def test_a_field_share_method_is_the_half_field_method_at_another_share():
    m = method_of("garment_share0.25_placed")
    half = METHODS["garment_half_placed"]
    assert m.field_share == 0.25 and half.field_share == 0.5
    assert (m.kind, m.variant, m.field, m.placement, m.anchoring) == (half.kind, half.variant, half.field,
                                                                      half.placement, half.anchoring)
    mixed, half_mixed = method_of("garment_share1_mixed_placed"), METHODS["garment_half_mixed_placed"]
    assert mixed.field_share == 1.0 and (mixed.placement, mixed.field) == (half_mixed.placement, half_mixed.field)
    assert method_of("direct") is METHODS["direct"]
    with pytest.raises(KeyError, match="garment_share_placed"):
        method_of("garment_share_placed")


def test_only_the_paper_as_written_solves_with_the_papers_edge_energy():
    from garment_transfer.geometry.poisson import ENERGIES

    assert METHODS["paper"].energy == "edges"
    assert {m.energy for k, m in METHODS.items() if k != "paper"} == {"gradients"}
    assert {m.energy for m in METHODS.values()} <= set(ENERGIES)
