"""The floor band's edges, differentiable (sonarsim.diff.bands): where they lie, how they move
with the pose (closed form), and the pose of a synthetic and a real floor fitted by them."""

from __future__ import annotations

import math

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jnp = pytest.importorskip("jax.numpy")

import sonarsim  # noqa: E402
import sonarsim.diff as sd  # noqa: E402
from sonarsim.analysis.fitting import band_edges as found_edges  # noqa: E402
from sonarsim.core.transforms import Pose  # noqa: E402
from sonarsim.diff.bands import band_edges, fit_band  # noqa: E402
from sonarsim.renderer.simulator import Simulator  # noqa: E402

Z, PITCH, FOV = 0.45, 28.0, 12.0
FLOOR = {"sonar": {"n_beams": 64, "azimuth_fov_deg": 60.0, "elevation_fov_deg": FOV, "range_min_m": 0.2,
                   "range_max_m": 2.0, "n_range_bins": 500,
                   "pose": {"position_m": [0, 0, Z], "rpy_deg": [0, PITCH, 0]}},
         "render": {"bounces": [1], "elevation_samples": 512}, "ground": {"albedo": 0.8}}


@pytest.fixture(scope="module")
def floor():
    with Simulator(FLOOR) as sim:
        image = sim.render(speckle=False)
    return sd.Renderer(FLOOR, attach="surfaces"), image


def test_the_edges_are_where_the_band_detector_finds_them(floor):
    r, image = floor
    near, far, near_ok, far_ok = (np.asarray(a) for a in band_edges(jnp.asarray(image.polar), image.range_m))
    # Beam by beam (the detector's median across beams is against speckle; on a noise-free
    # render it only pulls the fan's outer beams towards their neighbours): the same bin, the
    # differentiable edge placed within it.
    ref_near, ref_far = found_edges(image, median_beams=1)
    near, far = (np.asarray(a) for a in band_edges(jnp.asarray(image.polar), image.range_m, median_beams=1)[:2])
    bin_m = float(image.range_m[1] - image.range_m[0])
    both = np.isfinite(ref_near) & near_ok
    assert both.mean() > 0.9
    assert np.max(np.abs(near[both] - ref_near[both])) <= 0.55 * bin_m
    both = np.isfinite(ref_far) & far_ok
    assert both.mean() > 0.9
    assert np.max(np.abs(far[both] - ref_far[both])) <= 0.55 * bin_m
    # With the median across beams both take (the default): the same again.
    for got, ref in zip(band_edges(jnp.asarray(image.polar), image.range_m)[:2], found_edges(image)):
        both = np.isfinite(ref)
        assert both.mean() > 0.9
        assert np.max(np.abs(np.asarray(got)[both] - ref[both])) <= 0.55 * bin_m


def test_the_near_edge_moves_with_height_and_pitch_as_the_closed_form(floor):
    """On the axis the lowest ray meets the floor at r = z / sin(p + h), h the half-aperture:
    dr/dz = 1 / sin(p + h), dr/dp = -z cos(p + h) / sin(p + h)^2 (per radian). The held
    image's onset bin fills as the edge crosses it, and through the logarithm the derivative
    cycles with the edge's position in its bin: its mean over one bin's worth of heights is
    the closed form's (the smoothing moves the edge, not to first order its derivatives)."""
    r, image = floor
    fn, data = r.image_function(), r.data
    beams = np.argsort(np.abs(np.asarray(image.azimuth_deg)))[:2]  # the two beams nearest the axis
    a = math.radians(PITCH + FOV / 2.0)
    az = math.radians(float(np.mean(np.abs(np.asarray(image.azimuth_deg)[beams]))))
    # The beam's lowest ray, off the axis by the azimuth az: sin of its depression = sin(a) cos(az).
    s = math.sin(a) * math.cos(az)
    dz = 1.0 / s
    dp = -Z * math.cos(a) * math.cos(az) / s ** 2 * math.pi / 180.0
    p0 = r.params()

    def near_of(p):
        return jnp.mean(band_edges(fn(p, data), image.range_m)[0][beams])

    grad = jax.jit(jax.grad(near_of))
    bin_m = float(image.range_m[1] - image.range_m[0])
    shifts = np.arange(16) / 16 * bin_m / dz  # heights that move the edge across one bin
    grads = [grad({**p0, "sonar.position_m": p0["sonar.position_m"].at[2].add(h)}) for h in shifts]
    got_z = np.mean([float(g["sonar.position_m"][2]) for g in grads])
    got_p = np.mean([float(g["sonar.rpy_deg"][1]) for g in grads])
    assert got_z == pytest.approx(dz, rel=0.03)
    assert got_p == pytest.approx(dp, rel=0.03)


def test_a_synthetic_floors_pose_from_10_cm_and_5_degrees_off(floor):
    r, image = floor
    values, cost, per = fit_band(r, image, ("z", "pitch"), starts=[{"z": Z + 0.1, "pitch": PITCH - 5.0}])
    assert values["z"] == pytest.approx(Z, abs=0.01)
    assert values["pitch"] == pytest.approx(PITCH, abs=0.3)
    assert cost < 0.01 and per[0]["cost"] == cost


def test_the_band_fit_refuses_what_it_cannot_fit(floor):
    from sonarsim.errors import ConfigError

    r, image = floor
    with pytest.raises(ConfigError, match="albedo"):
        fit_band(r, image, ("z", "albedo"))


def test_the_real_oculus_floor_by_gradient_lands_where_the_band_search_does(shared_data):
    """From a start far off, `fit --method gradient` (the band's edges) ends within 1 cm and
    0.5 degrees of the band search's pose, its band-edge RMS no worse than the search's
    (measured from four starts, z 0.3-0.7 m and pitch 20-40 degrees: 0.412-0.417 m,
    28.56-28.83 degrees, 0.0641 m; the search 0.415 m, 28.76 degrees)."""
    from sonarsim.analysis.fitting import fit_pose
    from sonarsim.diff.inverse import fit_recording
    from sonarsim.io.readers import read_frames

    ping = next(iter(read_frames(shared_data / "real" / "oculus" / "one_ping_8bit.raw")))

    def scene(z, pitch):
        return sonarsim.load_scene({"sonar": {"preset": "oculus-m1200d-hf",
                                              "pose": {"position_m": [0, 0, z], "rpy_deg": [0, pitch, 0]}},
                                    "render": {"bounces": [1]}, "ground": {"height_m": 0, "albedo": 0.8}})

    search = fit_pose(ping, scene(0.62, 33.0), free=("z", "pitch"))
    for z, pitch in ((0.3, 20.0),):
        got = fit_recording(ping, scene(z, pitch), free=("z", "pitch"))
        assert got.domain == "band" and not got.problems
        assert got.values["z"] == pytest.approx(search.values["z"], abs=0.01)
        assert got.values["pitch"] == pytest.approx(search.values["pitch"], abs=0.5)
        assert got.cost <= search.cost + 0.005
        assert isinstance(got.pose, Pose)
