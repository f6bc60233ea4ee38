"""The part colour palette every output shares (GLB, USD, the API's colours, the atlas
layout image): identical on every call."""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from neural_shdf.errors import ParameterError

#: First colours of the palette: distinct, colour-blind-friendly-ish, light enough to shade.
_BASE_PALETTE = np.array(
    [
        [230, 159, 0], [86, 180, 233], [0, 158, 115], [240, 228, 66], [0, 114, 178],
        [213, 94, 0], [204, 121, 167], [153, 153, 153], [117, 112, 179], [102, 166, 30],
        [166, 118, 29], [231, 41, 138],
    ],
    dtype=np.uint8,
)  # fmt: skip


def part_colors(n_parts: int) -> NDArray[np.uint8]:
    """(n_parts, 4) RGBA colours, identical on every call: fixed palette, then golden-angle hues."""
    if n_parts < 0:
        raise ParameterError(f"n_parts must be >= 0, got {n_parts}")
    colors = np.full((n_parts, 4), 255, dtype=np.uint8)
    base = min(n_parts, len(_BASE_PALETTE))
    colors[:base, :3] = _BASE_PALETTE[:base]
    golden = (np.sqrt(5.0) - 1.0) / 2.0
    k = np.arange(n_parts - base)
    hue = (0.13 + k * golden) % 1.0
    saturation = np.array([0.55, 0.8, 0.4])[k % 3]
    value = np.array([0.9, 0.7, 0.8])[(k // 3) % 3]
    colors[base:, :3] = np.round(_hsv_to_rgb(hue, saturation, value) * 255)
    return colors


def _hsv_to_rgb(
    hue: NDArray[Any], saturation: NDArray[Any], value: NDArray[Any]
) -> NDArray[np.float64]:
    """(N, 3) ``colorsys.hsv_to_rgb`` of each row, with the same arithmetic (so the same
    colours), in one pass instead of a Python call per part."""
    sector = (hue * 6.0).astype(np.int64)
    fraction = hue * 6.0 - sector
    p = value * (1.0 - saturation)
    q = value * (1.0 - saturation * fraction)
    t = value * (1.0 - saturation * (1.0 - fraction))
    table = np.stack(
        [
            np.stack([value, t, p], axis=1),
            np.stack([q, value, p], axis=1),
            np.stack([p, value, t], axis=1),
            np.stack([p, q, value], axis=1),
            np.stack([t, p, value], axis=1),
            np.stack([value, p, q], axis=1),
        ]
    )
    return table[sector % 6, np.arange(len(hue))]


#: Colour of triangles without a part (negative label).
UNLABELED_COLOR = np.array([64, 64, 64, 255], dtype=np.uint8)


def srgb_to_linear(srgb: NDArray[Any]) -> NDArray[np.float64]:
    """sRGB components in [0, 1] to linear light (the inverse sRGB transfer function):
    the palette is defined in sRGB, glTF's COLOR_0 and renderers' vertex colours are linear."""
    srgb = np.asarray(srgb, dtype=np.float64)
    return np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)


def linear_color_bytes(rgba: NDArray[Any]) -> NDArray[np.uint8]:
    """RGB(A) sRGB bytes to linear bytes (alpha is linear already and kept)."""
    out = np.array(rgba, dtype=np.uint8, copy=True)
    out[..., :3] = np.round(srgb_to_linear(out[..., :3] / 255.0) * 255.0)
    return out


def part_color_hex(n_parts: int) -> list[str]:
    """part_colors as ``#rrggbb`` strings (what the API returns with each part)."""
    return [f"#{r:02x}{g:02x}{b:02x}" for r, g, b, _ in part_colors(n_parts).tolist()]
