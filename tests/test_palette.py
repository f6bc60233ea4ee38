"""The part palette: deterministic, sRGB, converted to linear where a format expects it."""

import colorsys

import numpy as np

from neural_shdf.palette import (
    linear_color_bytes,
    part_color_hex,
    part_colors,
    srgb_to_linear,
)


def test_palette_is_deterministic_distinct_and_opaque():
    colors = part_colors(60)
    assert colors.shape == (60, 4) and colors.dtype == np.uint8
    np.testing.assert_array_equal(colors, part_colors(60))
    np.testing.assert_array_equal(part_colors(5), colors[:5])
    assert len(np.unique(colors[:, :3], axis=0)) == 60
    assert (colors[:, 3] == 255).all()
    assert part_colors(0).shape == (0, 4)


def test_palette_beyond_the_base_colours_is_golden_angle_hsv():
    colors = part_colors(500)
    golden = (np.sqrt(5.0) - 1.0) / 2.0
    for i in (12, 13, 14, 100, 499):
        k = i - 12
        rgb = colorsys.hsv_to_rgb((0.13 + k * golden) % 1.0, (0.55, 0.8, 0.4)[k % 3],
                                  (0.9, 0.7, 0.8)[(k // 3) % 3])  # fmt: skip
        np.testing.assert_array_equal(colors[i, :3], np.round(np.array(rgb) * 255))


def test_srgb_to_linear_is_the_srgb_transfer_function():
    np.testing.assert_allclose(srgb_to_linear([0.0, 0.04045, 0.5, 1.0]),
                               [0.0, 0.04045 / 12.92, 0.214041, 1.0], atol=1e-6)  # fmt: skip
    # Orange #e69f00 (part 0): what a linear format must hold so that it shows as #e69f00.
    np.testing.assert_array_equal(linear_color_bytes([230, 159, 0, 255]), [202, 88, 0, 255])
    assert (np.diff(linear_color_bytes(np.arange(256, dtype=np.uint8))) >= 0).all()


def test_part_color_hex_spells_the_palette():
    hexes = part_color_hex(20)
    assert hexes[0] == "#e69f00"
    rgb = [[int(h[i : i + 2], 16) for i in (1, 3, 5)] for h in hexes]
    np.testing.assert_array_equal(rgb, part_colors(20)[:, :3])
