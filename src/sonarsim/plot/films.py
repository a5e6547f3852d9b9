"""Figures of the films of side-scans, multibeams and echo sounders, as surveyors look at them.

* :func:`waterfall_figure`: the waterfall (port on the left far to near, starboard near to far,
  the first ping at the top) in dB, with the logged altitude drawn on both sides (the first
  bottom return follows it) and a second panel of altitude, depth, roll and pitch per ping.
* :func:`soundings_figure`: the swath, the soundings of the pings across track (level frame,
  depth down) and their depth per ping and beam.
* :func:`envelope_figure`: the echogram of the pings with the bottom track.

Builders return a :class:`matplotlib.figure.Figure` made without pyplot.
"""

from __future__ import annotations

import numpy as np

from ..io.output import to_uint8

__all__ = ["waterfall_figure", "soundings_figure", "envelope_figure"]


def _figure(figsize):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained")


def waterfall_figure(waterfall, dynamic_range_db: float = 40.0, gain_db: float = 0.0, title: str = ""):
    """The waterfall and its pings' geometry.

    Parameters
    ----------
    waterfall : Waterfall
    dynamic_range_db, gain_db : float
        The dB window below the waterfall's maximum (saturated samples excluded from it).
    """
    samples = np.asarray(waterfall.samples, np.float64)
    clean = np.where(samples >= 32767, np.nan, samples)  # a recording's saturated bang
    ref = np.nanmax(clean) if np.isfinite(clean).any() else None
    # saturated samples shown at full scale (white), not left out (black)
    shown = np.where(samples >= 32767, ref if ref is not None else 0.0, samples)
    image = to_uint8(np.nan_to_num(waterfall.display(shown)), "db", gain_db, dynamic_range_db, reference=ref)
    r_max, n = waterfall.range_max_m, waterfall.n_pings
    fig = _figure((9, 6))
    ax, geo = fig.subplots(1, 2, width_ratios=[4, 1], sharey=True)
    ax.imshow(image, cmap="gray", aspect="auto", extent=(-r_max, r_max, n - 0.5, -0.5), interpolation="nearest")
    h = waterfall.geometry.altitude_m
    pings = np.arange(n)
    for sign in (-1, 1):
        ax.plot(sign * h, pings, color="tab:orange", lw=1, label="altitude" if sign > 0 else None)
    ax.set_xlabel("slant range, m (port < 0 < starboard)")
    ax.set_ylabel("ping")
    ax.legend(loc="lower right", fontsize="small")
    ax.set_title(title or f"{waterfall.source}: {n} pings x 2 x {waterfall.n_samples} samples\n"
                 f"{waterfall.unit.label}, {dynamic_range_db:g} dB below the maximum", fontsize="medium")
    g = waterfall.geometry
    for values, label in ((g.altitude_m, "altitude m"), (g.depth_m, "depth m"), (g.roll_deg, "roll deg"),
                          (g.pitch_deg, "pitch deg")):
        if np.isfinite(values).any():
            geo.plot(values, pings, lw=1, label=label)
    geo.set_xlabel("geometry")
    geo.legend(fontsize="x-small")
    return fig


def soundings_figure(soundings, title: str = ""):
    """Soundings across track (the level frame: roll and pitch applied) and depth per ping and beam."""
    pts = soundings.level_points()
    fig = _figure((9, 6))
    across, grid = fig.subplots(2, 1, height_ratios=[1, 1.3])
    step = max(1, soundings.n_pings // 20)
    for p in range(0, soundings.n_pings, step):
        across.plot(-pts[p, :, 1], pts[p, :, 2], ".", ms=1.5)
    across.set_xlabel("across track, m (starboard > 0)")
    across.set_ylabel("z, m (up)")
    across.set_title(title or f"{soundings.source}: {soundings.n_pings} pings x {soundings.n_beams} beams")
    im = grid.imshow(-pts[..., 2], aspect="auto", cmap="viridis", interpolation="nearest")
    grid.set_xlabel("beam (0: port-most)")
    grid.set_ylabel("ping")
    fig.colorbar(im, ax=grid, label="depth below the head, m")
    return fig


def envelope_figure(envelope, dynamic_range_db: float = 40.0, title: str = ""):
    """The echogram (pings across, range down) with the bottom track."""
    image = to_uint8(np.asarray(envelope.samples, np.float64).T, "db", 0.0, dynamic_range_db)
    fig = _figure((9, 4))
    ax = fig.subplots()
    ax.imshow(image, cmap="gray", aspect="auto", interpolation="nearest",
              extent=(-0.5, envelope.n_pings - 0.5, envelope.range_max_m, envelope.range_min_m))
    ax.plot(np.arange(envelope.n_pings), envelope.bottom_range_m, color="tab:orange", lw=1, label="bottom")
    ax.set_xlabel("ping")
    ax.set_ylabel("range, m")
    ax.legend(loc="lower right", fontsize="small")
    ax.set_title(title or f"{envelope.source}: {envelope.n_pings} pings; {envelope.unit.label}, "
                 f"{dynamic_range_db:g} dB below the maximum", fontsize="medium")
    return fig
