"""Figures made of several images, e.g. the paper's Fig. 9 comparison of bounce variants."""

from __future__ import annotations

import numpy as np

from .output import to_uint8

# (title, components summed) of the paper's Fig. 9 panels (b)-(d).
BOUNCE_VARIANTS = (
    ("single", ("single",)),
    ("single + triple", ("single", "triple")),
    ("all bounces", ("single", "double", "triple")),
)


def bounce_comparison(image, pixel_size_m: float | None = None, mapping: str = "db",
                      gain_db: float = 0.0, dynamic_range_db: float = 40.0, gap_px: int = 8) -> np.ndarray:
    """Fan views of single, single + triple and all bounces side by side (paper Fig. 9).

    All panels share one intensity reference (the maximum of the all-bounce image), so their
    brightness compares directly.

    Parameters
    ----------
    image : SonarImage
        A render with its ``components``.

    Returns
    -------
    (H, 3 W + 2 gap_px) uint8 ndarray
    """
    from ..image.fan import FanMapper

    s = image.sonar
    mapper = FanMapper(s.n_range_bins, s.range_min_m, s.range_max_m, image.azimuth_deg, pixel_size_m)
    panels = [mapper(sum(image.components[k].astype(np.float64) for k in keys)) for _, keys in BOUNCE_VARIANTS]
    ref = float(panels[-1].image.max()) or None
    tiles = [to_uint8(p.image, mapping, gain_db, dynamic_range_db, reference=ref, mask=p.mask) for p in panels]
    gap = np.full((tiles[0].shape[0], gap_px), 255, dtype=np.uint8)
    return np.concatenate([tiles[0], gap, tiles[1], gap, tiles[2]], axis=1)
