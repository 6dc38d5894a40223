"""The per-process memo of host-side derivations (jaxlc.memo)."""

import dataclasses

import numpy as np
import pytest

from jaxlc.memo import identity_memo


@dataclasses.dataclass(frozen=True)
class Holder:  # unhashable (a frozen dataclass of arrays), like Facets
    x: np.ndarray


def test_identity_memo_keys_objects_by_identity_arrays_by_value_and_shares_frozen_results():
    calls = []

    @identity_memo(maxsize=2)
    def f(holder, ids, label):
        calls.append(label)
        return holder.x[ids] * 2.0

    a, b = Holder(np.arange(4.0)), Holder(np.arange(4.0))
    first = f(a, np.array([1, 2]), "s")
    assert f(a, np.array([1, 2]), "s") is first  # equal array, same object: remembered
    assert len(calls) == 1
    f(b, np.array([1, 2]), "s")  # an equal but distinct object is another key
    f(a, np.array([2, 1]), "s")  # other array contents: another key
    assert len(calls) == 3
    np.testing.assert_array_equal(first, [2.0, 4.0])
    with pytest.raises(ValueError):
        first[0] = 0.0  # shared between callers: read-only
    f(a, np.array([1, 2]), "s")  # evicted (first in, first out, 2 kept): computed again
    assert len(calls) == 4
    f.cache_clear()
    f(a, np.array([1, 2]), "s")
    assert len(calls) == 5
