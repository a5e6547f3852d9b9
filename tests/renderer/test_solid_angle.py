"""A ray's weight is the solid angle of its cell, ``cos(phi) dphi dtheta`` (issue 37).

A flat floor seen through a wide elevation aperture: each range bin's level against the closed
form of paper Eq. 3 over solid angle. Without the ``cos(phi)`` (what sonarsim did before issue
37) the bins seen at 30 degrees of elevation read 0.6 dB high.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.core.rays import make_ray_fan
from tests.conftest import sonar_dict

HEIGHT_M, PITCH_DEG, APERTURE_DEG, ALBEDO = 1.0, 35.0, 60.0, 0.5


def floor_scene(method: str = "fast") -> dict:
    """A level floor 1 m below a sonar pitched 35 degrees down, seen over +-30 degrees of
    elevation (from 1.10 m at the aperture's bottom to 11.5 m at its top); three narrow beams,
    one ray across each, TVG on (l(r) = 1), single bounce."""
    sonar = sonar_dict(n_beams=3, azimuth_fov_deg=3.0, elevation_fov_deg=APERTURE_DEG, range_min_m=1.0,
                       range_max_m=12.0, n_range_bins=550,
                       pose={"position_m": [0.0, 0.0, HEIGHT_M], "rpy_deg": [0.0, PITCH_DEG, 0.0]})
    return {"sonar": sonar, "ground": {"height_m": 0.0, "albedo": ALBEDO, "specular": 0.0},
            "render": {"elevation_samples": 8192, "bounces": [1], "tvg": True, "method": method}}


def floor_bins(edges_m: np.ndarray, with_cos: bool = True) -> np.ndarray:
    """The centre beam's level in each range bin ``[edges[i], edges[i + 1])``, closed form.

    Along the beam's axis a ray at elevation phi meets the floor at ``r = z / sin(p - phi)``
    with ``cos(alpha) = sin(p - phi)``; the paper's law gives ``rho cos(alpha)`` per unit of
    the measure, so a bin holds ``rho * integral of sin(p - phi) cos(phi) dphi`` over the
    elevations whose range falls in it, whose antiderivative is
    ``phi sin(p) / 2 + cos(p - 2 phi) / 4``. ``with_cos=False``: the measure ``dphi`` alone
    (antiderivative ``cos(p - phi)``), the old weight.
    """
    p, a = math.radians(PITCH_DEG), math.radians(APERTURE_DEG) / 2

    def antiderivative(phi):
        return phi * math.sin(p) / 2 + np.cos(p - 2 * phi) / 4 if with_cos else np.cos(p - phi)

    phi = p - np.arcsin(HEIGHT_M / edges_m)  # ascending with range
    phi = np.clip(phi, -a, a)
    return ALBEDO * np.diff(antiderivative(phi))


@pytest.mark.parametrize("kernels,method", [("compiled", "fast"), ("numpy", "fast"), ("compiled", "paper")])
def test_a_flat_floor_per_range_bin_is_the_integral_over_solid_angle(kernels, method):
    image = sonarsim.Simulator(floor_scene(method), kernels=kernels).render(speckle=False)
    level = image.polar[:, 1].astype(float)  # the centre beam: its one ray column at azimuth 0
    edges = 1.0 + np.arange(len(level) + 1) * (12.0 - 1.0) / len(level)  # (sonar.range_*_m)
    expected = floor_bins(edges)
    seen = expected > 0
    assert seen.sum() > 500  # the floor fills the window from 1.10 m on
    np.testing.assert_allclose(level[seen], expected[seen], rtol=3e-3)
    assert not level[~seen].any()
    # Against the old measure the far bins (near +30 degrees) read 10 log10(1 / cos 30) high.
    old = floor_bins(edges, with_cos=False)
    far = np.flatnonzero(seen)[-20:]
    assert 10 * np.log10(old[far] / level[far]).mean() == pytest.approx(-10 * math.log10(math.cos(math.radians(29.5))),
                                                                      abs=0.05)


def test_the_fan_weight_is_the_solid_angle_of_its_cell():
    """Summed over a beam's rays, the weights are the aperture's solid angle per radian of
    beam width: ``2 sin(E / 2)`` (not ``E``)."""
    scene = sonarsim.load_scene(floor_scene())
    fan = make_ray_fan(scene.sonar, scene.render)
    assert fan.weight[1].sum() == pytest.approx(2 * math.sin(math.radians(APERTURE_DEG) / 2), rel=1e-6)
    np.testing.assert_allclose(fan.weight[1, 0], np.cos(fan.elevation_rad) * math.radians(APERTURE_DEG) / 8192,
                               rtol=1e-12)
