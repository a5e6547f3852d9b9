"""Image formation (paper Eq. 3-6 and Algorithm 1): per-ray intensities into a polar image.

The code lives in :mod:`sonarsim.core.splat` (NumPy only), below the path search
(:mod:`sonarsim.paths`), which splats the echoes it finds with it; every name is re-exported
here, where it was.
"""

from __future__ import annotations

from ..core.splat import (  # noqa: F401 - re-exported
    CONTINUITY_SINE,
    MIN_SPREAD_BINS,
    RayEnergy,
    _segments,
    accumulate,
    continuity,
    expand_cells,
    form_image,
    range_cells,
)
