"""SegmentParams built from the attributes of CLI arguments or API requests."""

from argparse import Namespace

import numpy as np
import pytest

from neural_shdf.errors import ParameterError
from neural_shdf.segment.params import (
    DEFAULT_MIN_PART_FRACTION,
    MAX_CLUSTERS,
    MAX_PARTS,
    MAX_SEED,
    MAX_SMOOTHING,
    SegmentParams,
    check_seed,
)


def test_from_attributes_takes_known_names_and_keeps_other_defaults():
    source = Namespace(partitioner="metis", parts=4, clusters=None, seed=7, method="exact")
    params = SegmentParams.from_attributes(source)
    assert params == SegmentParams(partitioner="metis", parts=4, seed=7)
    assert params.min_part_fraction == DEFAULT_MIN_PART_FRACTION


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"clusters": MAX_CLUSTERS + 1}, "clusters must be an integer in 1..32"),
        ({"smoothing": MAX_SMOOTHING * 2}, "smoothing must be a finite number in \\[0, 100\\]"),
        ({"smoothing": float("nan")}, "finite"),
        ({"partitioner": "metis", "parts": MAX_PARTS + 1}, "parts must be an integer in"),
        ({"seed": MAX_SEED + 1}, "seed must be an integer in 0..2147483647"),
        ({"seed": True}, "seed must be an integer"),
    ],
)
def test_every_bound_is_checked_when_the_parameters_are_built(changes, message):
    with pytest.raises(ParameterError, match=message):
        SegmentParams(**changes)


def test_largest_values_are_accepted():
    params = SegmentParams(
        partitioner="metis", clusters=MAX_CLUSTERS, smoothing=MAX_SMOOTHING, parts=MAX_PARTS,
        seed=MAX_SEED,
    )  # fmt: skip
    assert check_seed(np.int64(MAX_SEED)) == params.seed
