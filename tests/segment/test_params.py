"""SegmentParams built from the attributes of CLI arguments or API requests."""

from argparse import Namespace

from neural_shdf.segment.params import DEFAULT_MIN_PART_FRACTION, SegmentParams


def test_from_attributes_takes_known_names_and_keeps_other_defaults():
    source = Namespace(partitioner="metis", parts=4, clusters=None, seed=7, method="exact")
    params = SegmentParams.from_attributes(source)
    assert params == SegmentParams(partitioner="metis", parts=4, seed=7)
    assert params.min_part_fraction == DEFAULT_MIN_PART_FRACTION
