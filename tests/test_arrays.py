import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from neural_shdf.arrays import json_array, json_list, unique_rows


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


@pytest.mark.parametrize(
    "values",
    [
        np.arange(0),
        np.arange(-5, 70_000, dtype=np.int64),
        np.array([0.1, 1e-300, 2.5e30, -0.0, 3.0]),
        np.random.default_rng(0).random(40_000),
    ],
)
def test_json_array_is_the_text_json_dumps_writes(values):
    expected = json.dumps(values.tolist(), separators=(",", ":"))
    assert json_array(values) == expected


def test_json_array_writes_nan_as_null_when_asked():
    values = np.array([1.5, np.nan, 2.0] * 20_000)
    assert json.loads(json_array(values, nan_as_null=True))[:3] == [1.5, None, 2.0]
    assert json_array(values).startswith("[1.5,NaN,2.0")


@pytest.mark.parametrize("count", [0, 1, 5, 4097])
def test_json_list_is_the_text_json_dumps_writes(count):
    items = [{"label": i, "color": f"#{i:06x}", "area": i / 7} for i in range(count)]
    assert json_list(items, chunk=2048) == json.dumps(items, separators=(",", ":"))
