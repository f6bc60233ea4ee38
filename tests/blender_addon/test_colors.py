"""The add-on's part colours (no Blender needed): the service's palette, linear."""

from __future__ import annotations

import numpy as np

from blender_addon import colors
from neural_shdf.palette import UNLABELED_COLOR, part_color_hex, part_colors, srgb_to_linear


def test_hex_colours_become_the_services_palette_in_linear_light():
    hexes = part_color_hex(20)
    parts = [{"label": i, "color": c} for i, c in enumerate(hexes)]
    linear = np.array(colors.part_colors(reversed(parts)))  # by label, whatever the order
    expected = srgb_to_linear(part_colors(20)[:, :3] / 255.0)
    np.testing.assert_allclose(linear[:, :3], expected, atol=1e-12)
    assert (linear[:, 3] == 1.0).all()


def test_unlabeled_grey_is_the_services():
    assert "#{:02x}{:02x}{:02x}".format(*UNLABELED_COLOR[:3].tolist()) == colors.UNLABELED_HEX
    np.testing.assert_allclose(
        colors.UNLABELED_LINEAR[:3], srgb_to_linear(UNLABELED_COLOR[:3] / 255.0), atol=1e-12
    )
