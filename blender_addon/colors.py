"""Part colours as Blender wants them. No bpy here (tested outside Blender).

The palette is the service's (``neural_shdf.palette.part_colors``), defined there once, in sRGB:
each part of an answer carries it as ``color`` ("#rrggbb"). Blender's material colours and
FLOAT_COLOR attributes are linear, so the colours are converted with the sRGB transfer function.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

#: The service's colour of polygons without a part (``neural_shdf.palette.UNLABELED_COLOR``).
UNLABELED_HEX = "#404040"


def srgb_to_linear(component: float) -> float:
    """An sRGB component in [0, 1] in linear light."""
    if component <= 0.04045:
        return component / 12.92
    return ((component + 0.055) / 1.055) ** 2.4


def hex_to_linear(color: str) -> tuple[float, float, float, float]:
    """``#rrggbb`` (sRGB) to linear RGBA, opaque."""
    text = color.lstrip("#")
    if len(text) != 6:
        raise ValueError(f"not an #rrggbb colour: {color!r}")
    red, green, blue = (srgb_to_linear(int(text[i : i + 2], 16) / 255.0) for i in (0, 2, 4))
    return (red, green, blue, 1.0)


def part_colors(parts: Iterable[Mapping[str, Any]]) -> list[tuple[float, float, float, float]]:
    """Linear RGBA of each part of an answer (its ``color``), in label order."""
    ordered = sorted(parts, key=lambda part: part["label"])
    return [hex_to_linear(part["color"]) for part in ordered]


UNLABELED_LINEAR = hex_to_linear(UNLABELED_HEX)
