import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from neural_shdf.arrays import unique_rows


@settings(max_examples=200, deadline=None)
@given(
    hnp.arrays(
        dtype=st.sampled_from([np.int64, np.float64]),
        shape=st.tuples(st.integers(0, 60), st.integers(1, 5)),
        elements=st.integers(-3, 3),
    )
)
def test_unique_rows_is_numpys_unique_along_rows(rows):
    expected = np.unique(rows, axis=0, return_index=True, return_inverse=True, return_counts=True)
    got = unique_rows(rows, return_index=True, return_inverse=True, return_counts=True)
    for mine, numpys in zip(got, expected, strict=True):
        np.testing.assert_array_equal(mine, np.asarray(numpys).reshape(mine.shape))


def test_unique_rows_alone_and_in_lexicographic_order():
    rows = np.array([[2, 0], [1, 5], [2, 0], [1, -1]])
    np.testing.assert_array_equal(unique_rows(rows), [[1, -1], [1, 5], [2, 0]])


def test_unique_rows_refuses_other_shapes():
    with pytest.raises(ValueError, match="2-D"):
        unique_rows(np.arange(4))
