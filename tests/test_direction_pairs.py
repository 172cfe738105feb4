"""ctfit/_model/direction_pairs.py: a measurement's distinct direction pairs, as NumPy's own
``np.unique(axis=0, return_inverse=True)`` gives them, whatever the data's layout."""

import numpy as np
import pytest

from ctfit._model.direction_pairs import unique_direction_pairs


def _layouts():
    rng = np.random.default_rng(3)
    scattered = rng.uniform(0, 90, (5000, 4))  # no two θ_i alike: one sort
    grid = rng.integers(0, 4, (5000, 4)).astype(float)  # every value repeated: the lexsort
    tied_first = np.column_stack([np.repeat([10.0, 20.0], 2500), rng.uniform(0, 90, (5000, 3))])  # θ_i alike, the rest not
    bands = np.repeat(rng.uniform(0, 90, (1000, 4)), 5, axis=0)  # each pair's bands in consecutive rows
    one_tie = scattered.copy()
    one_tie[7, 0] = one_tie[8, 0]  # a single shared θ_i
    return dict(scattered=scattered, grid=grid, tied_first=tied_first, bands=bands, one_tie=one_tie)


@pytest.mark.parametrize("layout", list(_layouts()))
def test_the_pairs_and_each_sample_s_index_are_numpy_s_unique(layout):
    a = _layouts()[layout]
    pairs, index = unique_direction_pairs(*a.T)
    want, inverse = np.unique(a, axis=0, return_inverse=True)
    np.testing.assert_array_equal(pairs, want)
    np.testing.assert_array_equal(index, inverse.ravel())
    assert not pairs.flags.writeable and not index.flags.writeable
