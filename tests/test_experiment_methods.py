import pytest

from lab.experiment import METHODS, method_of


def test_a_field_share_method_is_the_half_field_method_at_another_share():
    m = method_of("garment_share0.25_placed")
    half = METHODS["garment_half_placed"]
    assert m.field_share == 0.25 and half.field_share == 0.5
    assert (m.kind, m.variant, m.field, m.placement, m.anchoring) == (half.kind, half.variant, half.field,
                                                                      half.placement, half.anchoring)
    assert method_of("direct") is METHODS["direct"]
    with pytest.raises(KeyError, match="garment_share_placed"):
        method_of("garment_share_placed")
