"""Segmentation from any per-face ShDF in [0, 1]: soft clustering, then a hard partition."""

from neural_shdf.segment.params import SegmentParams

__all__ = ["SegmentParams"]
