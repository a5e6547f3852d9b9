"""Reciprocal pairs add coherently (issue 39 item 3): O-A-G-O and O-G-A-O have one length, so
where both arrive in one beam their amplitudes add, ``|a + a|^2 = 4 |a|^2``: four times one
path's intensity, against two independent paths' 2x (``separate``) and the paper's 1x."""

from __future__ import annotations

import numpy as np
import pytest

import sonarsim
from tests.conftest import sonar_dict


def ball_over_mirror(double_beam: str, roll_deg: float = 0.0, **render) -> dict:
    """A small ball straight ahead of a sonar 1 m above a perfect mirror floor: the ball and its
    image in one azimuth (one beam) unless the sonar rolls."""
    return {
        "sonar": sonar_dict(n_beams=64, elevation_fov_deg=40.0, n_range_bins=800, range_max_m=6.0,
                            pose={"position_m": [0.0, 0.0, 1.0], "rpy_deg": [roll_deg, 10.0, 0.0]}),
        "ground": {"height_m": 0.0, "albedo": 0.0, "specular": 1.0},
        "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 0.08, "pose": {"position_m": [3.0, 0.0, 0.5]}}],
        "render": {"elevation_samples": 400, "max_order": 2, "double_beam": double_beam, **render},
    }


@pytest.mark.parametrize("kernels", ["compiled", "numpy"])
def test_a_pair_in_one_beam_returns_four_times_one_path(kernels):
    double = {m: sonarsim.Simulator(ball_over_mirror(m), kernels=kernels).render().components["double"].astype(float)
              for m in ("paper", "separate", "coherent")}
    via_floor = double["paper"].sum()  # the paper records each pair once, from the leg via the floor
    direct = double["separate"].sum() - via_floor  # separate adds each partner from its own receive rays
    assert via_floor > 0
    # Each path is estimated from its own receive rays: the ball subtends the solid angle of its
    # distance from the sonar (|OA|) for the direct leg, from the sonar's image (|O'A|) via the
    # floor; their ratio is (|O'A| / |OA|)^2 (a closed form, within the rays' sampling).
    oa, o_a = np.hypot(3.0, 0.5), np.hypot(3.0, 1.5)
    assert direct / via_floor == pytest.approx((o_a / oa) ** 2, rel=0.02)
    # Coherent: the pair's amplitudes add, four times one path (the mean of the two estimates).
    assert double["coherent"].sum() == pytest.approx(4 * (via_floor + direct) / 2, rel=1e-6)
    # Path by path: coherent is separate doubled where the partner arrives in the same beam (here: all).
    np.testing.assert_allclose(double["coherent"], 2 * double["separate"], rtol=1e-6, atol=1e-9 * via_floor)
    # The single echoes are untouched.
    a = sonarsim.render(ball_over_mirror("coherent")).components
    b = sonarsim.render(ball_over_mirror("paper")).components
    np.testing.assert_array_equal(a["single"], b["single"])


def test_a_pair_in_two_beams_is_two_independent_paths():
    # Rolled, the ball and its image fall in different beams: each beam receives one path.
    roll = 25.0
    coherent = sonarsim.render(ball_over_mirror("coherent", roll)).components["double"]
    separate = sonarsim.render(ball_over_mirror("separate", roll)).components["double"]
    assert separate.sum() > 0
    beams = np.flatnonzero(separate.sum(axis=0) > 1e-3 * separate.sum(axis=0).max())
    assert beams.max() - beams.min() > 2  # two groups of beams apart
    np.testing.assert_allclose(coherent, separate, rtol=1e-6, atol=1e-12)


def test_the_default_is_coherent_and_the_papers_method_keeps_its_own():
    assert sonarsim.load_scene({"sonar": sonar_dict()}).render.double_beam == "coherent"
    assert sonarsim.load_scene({"sonar": sonar_dict(), "render": {"method": "paper"}}).render.double_beam == "paper"
    with pytest.raises(sonarsim.ConfigError, match="not a convention of Algorithm 2"):
        sonarsim.load_scene({"sonar": sonar_dict(), "render": {"method": "paper", "double_beam": "coherent"}})
