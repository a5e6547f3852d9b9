"""The sediment law's curves (docs/seabed.md): backscattering strength against grazing angle for
sea beds from rock to clay at four frequencies, and the coherent reflectance ``|V|^2``.

Run from the repository root (about 5 s)::

    python docs/make_seabed_figure.py          # writes docs/images/seabed_backscatter.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sonarsim.core import seabed  # noqa: E402

OUT = Path(__file__).resolve().parent / "images" / "seabed_backscatter.png"
BEDS = ("rock", "sandy-gravel", "medium-sand", "fine-sand", "coarse-silt", "clay")
FREQUENCIES_HZ = (40e3, 100e3, 400e3, 1.8e6)


def main() -> int:
    grazing = np.radians(np.linspace(0.5, 90.0, 360))
    fig, axes = plt.subplots(1, len(FREQUENCIES_HZ) + 1, figsize=(19, 4.2), sharey=False)
    for ax, f in zip(axes, FREQUENCIES_HZ):
        for name in BEDS:
            s = seabed.sediment(name)
            ax.plot(np.degrees(grazing), 10 * np.log10(seabed.backscatter(grazing, s, f)), label=name)
        lo, hi = seabed.model_range()
        where = "fitted range" if lo <= f <= hi else "extrapolated"
        ax.set_title(f"{f / 1e3:g} kHz ({where})")
        ax.set_xlabel("grazing angle (degrees)")
        ax.set_ylim(-50, 5)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("backscattering strength 10 log10 sigma (dB)")
    axes[0].legend(fontsize=8)
    ax = axes[-1]
    for name in BEDS:
        ax.plot(np.degrees(grazing), np.abs(seabed.rayleigh_coefficient(grazing, seabed.sediment(name))) ** 2,
                label=name)
    ax.set_title("coherent reflectance |V|^2 (smooth bed)")
    ax.set_xlabel("grazing angle (degrees)")
    ax.grid(alpha=0.3)
    fig.suptitle("sonarsim sediment law (after APL-UW TR 9407): interface roughness (small-slope) + volume")
    fig.tight_layout()
    OUT.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(OUT, dpi=80)
    print(OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main())
