"""The next discovered part's index (``discover.next_index``): past the largest in the model."""

from __future__ import annotations

import pytest

from hhra_phys.diagnosis.discovery import next_index
from hhra_phys.models.hhra import HHRAModel
from hhra_phys.terms import DiscoveredMode, DiscoveredTerm

VARS = ("omega", "theta", "u")


def _term(index: int, target: str = "rate:omega") -> DiscoveredTerm:
    return DiscoveredTerm(target=target, index=index, terms=("lin(omega)",), variables=VARS,
                          scales=(3.0, 0.7, 5.0), start=(0.1,), bound=(100.0,), knots=(0.0,),
                          knot_max=(10.0,), unit="rad/s^2", var_units=("rad/s", "rad", "mA"))


def test_the_next_term_index_is_past_the_largest_not_the_count():
    base = HHRAModel()
    assert next_index(base, DiscoveredTerm) == 1
    # the backward step removed term 1 and kept term 2: a count would give 2 again
    kept = base.with_parts(_term(2, "output"))
    assert next_index(kept, DiscoveredTerm) == 3
    assert next_index(kept, DiscoveredMode) == 1
    both = kept.with_parts(_term(3))
    assert next_index(both, DiscoveredTerm) == 4
    # the new term's parameters then never clash with those in the model
    new = _term(next_index(kept, DiscoveredTerm))
    assert not set(p.name for p in new.parameters) & set(kept.params.names)
    with pytest.raises(Exception, match="duplicate"):
        kept.with_parts(_term(2))
