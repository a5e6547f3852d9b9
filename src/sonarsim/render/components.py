"""Which bounces make which image: the components of a render and their assembly.

A render forms four images from its rays: ``object`` and ``ground`` (single bounce, O-A-O and
O-G-O), ``double`` (O-G-A-O / O-A-G-O, cases 2/3) and ``triple`` (O-G-A-G-O, case 4). From them
come ``single`` (= object + ground) and ``total``: the sum of the bounces selected by
``render.bounces`` (1 single, 2 double, 3 triple).
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from ..image.result import COMPONENTS

__all__ = ["BOUNCE_COMPONENTS", "COMPONENTS", "assemble"]

#: The image each bounce count of ``render.bounces`` adds to the total.
BOUNCE_COMPONENTS = {1: "single", 2: "double", 3: "triple"}


def assemble(images: Mapping[str, np.ndarray], bounces: tuple[int, ...]) -> dict[str, np.ndarray]:
    """float32 components from the object, ground, double and triple images."""
    # Already float32 and contiguous (compiled path): no copy.
    out = {k: np.ascontiguousarray(images[k], dtype=np.float32) for k in ("object", "ground", "double", "triple")}
    out["single"] = out["object"] + out["ground"]
    keys = [key for bounce, key in BOUNCE_COMPONENTS.items() if bounce in bounces]
    total = out[keys[0]].copy()
    for key in keys[1:]:
        np.add(total, out[key], out=total)
    out["total"] = total
    return out
