"""What fit and calibration refuse, and what they write (issue 37): a frame without echo, free
parameters no recording determines, a model no better than the frame's mean level, values at
their bounds, and the family of equally good poses written by its middle, never an edge."""

from __future__ import annotations

import numpy as np
import pytest

import sonarsim
from sonarsim.analysis.calibration import (bound_report, family_middle, frame_problems, gamma_for_contrast,
                                           model_problems)
from sonarsim.analysis.fitting import (MIN_ECHO_PIXELS, echo_problems, unidentified_parameters,
                                       unidentified_problem)

from ..conftest import sonar_dict


def floor(**pose) -> dict:
    p = {"position_m": [0, 0, 0.5], "rpy_deg": [0, 25, 0], **pose}
    return {"sonar": sonar_dict(n_beams=32, n_range_bins=200, range_min_m=0.2, range_max_m=3.0, pose=p),
            "ground": {"height_m": 0.0, "albedo": 0.8}, "render": {"bounces": [1]}}


@pytest.fixture(scope="module")
def floor_image():
    return np.asarray(sonarsim.render(sonarsim.load_scene(floor()), speckle=False).polar, float)


def test_a_floor_band_is_an_echo(floor_image):
    assert echo_problems(floor_image) == ()
    assert echo_problems(floor_image * 255 / floor_image.max()) == ()


@pytest.mark.parametrize("value", [0.0, 255.0])
def test_a_frame_of_one_value_is_no_echo(value):
    assert echo_problems(np.full((100, 40), value)) == (
        f"every pixel of the frame is {value:g} (a silent or saturated ping): no echo",)


def test_pixel_noise_is_no_echo():
    """Independent pixels: a 15 x 9 local mean explains 1/135 of their variance (0.74 %)."""
    noise = np.random.default_rng(3).integers(0, 256, (400, 128)).astype(float)
    (problem,) = echo_problems(noise)
    assert problem.startswith("the frame shows no echo structure: its 15 x 9 local mean explains 0.")


def test_one_bright_pixel_is_no_echo():
    x = np.zeros((300, 64))
    x[150, 32] = 255.0
    problems = echo_problems(x)
    assert problems[0] == f"the frame's lit region holds 0 pixels (at least {MIN_ECHO_PIXELS} are an echo)"


def test_a_saturated_frame_is_no_echo(floor_image):
    x = 255 * floor_image / floor_image.max()
    x[: int(0.99 * x.shape[0])] = 255.0  # 99 % of the pixels at the top value
    assert any(p.startswith("99 % of the frame's pixels are at its largest value 255 (saturated; at most 98 %")
               for p in echo_problems(x))
    x = 255 * floor_image / floor_image.max()
    x[: int(0.9 * x.shape[0])] = 255.0  # 90 %: what is left still calibrates
    assert not any("saturated" in p for p in echo_problems(x))


def test_the_structure_is_judged_on_frames_of_two_windows():
    """Over 8 beams a 15 x 9 window is no local mean: noise there is not judged by it."""
    noise = np.random.default_rng(4).integers(0, 256, (400, 8)).astype(float)
    assert echo_problems(noise) == ()
    assert len(echo_problems(np.random.default_rng(4).integers(0, 256, (400, 18)).astype(float))) == 1


def test_a_smooth_band_has_no_speckle_to_calibrate_on():
    """The search's contrast check, now one home for both methods (exit 3 through
    CalibrationFailed): a band without speckle is an echo, but not a device's frame."""
    rows = np.arange(200, dtype=float)[:, None]
    band = 200.0 * np.exp(-(((rows - 100.0) / 30.0) ** 2)) * np.ones((1, 32))
    assert echo_problems(band) == ()
    (problem,) = frame_problems(band)
    assert problem.startswith("the frame's speckle contrast in its bright band is 0.0")
    assert "not a noise-free render" in problem


def test_gamma_for_a_contrast_no_gamma_gives_says_so():
    """A saturated region's contrast is 0: scipy's "f(a) and f(b) must have different signs"
    reached the user before."""
    with pytest.raises(ValueError, match="speckle contrast of the region is 0; a gamma output"):
        gamma_for_contrast(0.0)
    assert gamma_for_contrast(1.0) == pytest.approx(1.0, rel=1e-6)  # exponential speckle itself


def test_x_y_and_yaw_do_not_change_a_flat_floor():
    scene = sonarsim.load_scene(floor(rpy_deg=[2, 25, 10]))
    assert unidentified_parameters(scene, ("x", "y", "z", "roll", "pitch", "yaw")) == ("x", "y", "yaw")
    assert unidentified_problem(("x",)).startswith("x does not change the render (a step of x 0.05 m")


def test_an_object_off_the_axis_identifies_x_and_yaw():
    doc = floor()
    doc["objects"] = [{"primitive": "sphere", "radius_m": 0.15, "pose": {"position_m": [1.5, 0.2, 0.15]}}]
    assert unidentified_parameters(sonarsim.load_scene(doc), ("x", "y", "yaw")) == ()


def test_a_model_no_better_than_the_mean_level_is_refused(floor_image):
    target = 255 * floor_image / floor_image.max()
    (problem,) = model_problems(target, np.full_like(target, target.mean()))
    assert problem.startswith("the calibrated model explains 0.0 % of the frame's variance")
    assert model_problems(target, target) == []
    # Half the variance explained: the target with half its departure from the mean.
    assert model_problems(target, target.mean() + (target - target.mean()) * (1 - 0.5 ** 0.5)) == []


def test_values_beyond_and_at_their_bounds():
    bounds = {"noise_db": (0.0, 160.0), "gain_db": (-40.0, 120.0), "elevation_width_deg": (1.0, 60.0),
              "bang_length_m": (0.001, 0.5)}
    beyond, at = bound_report({"noise_db": 0.0, "gain_db": 35.0, "elevation_width_deg": 70.0,
                               "bang_length_m": 0.001}, bounds)
    assert beyond == ["elevation_width_deg 70 (bounds 1 to 60)"]
    assert at == ["noise_db 0 (bounds 0 to 160)"]  # bang_length_m's lower bound is a natural limit


def test_the_family_is_written_by_its_middle_not_its_best_edge():
    """The README's Oculus recipe wrote the scan's narrowest width (2 degrees) because it fitted
    0.01 dB better than the rest of the family: within the tolerance every member is as good."""
    members = [{"elevation_width_deg": w, "psnr_db": p} for w, p in
               [(4.67, 19.31), (2.0, 19.32), (3.0, 19.31), (4.5, 19.30), (6.0, 19.29), (8.0, 19.25), (10.5, 19.14),
                (14.0, 18.9)]]
    # Within 0.2 dB of 19.32: widths 2-10.5 (seven members); their middle is 4.67.
    assert members[family_middle(members)]["elevation_width_deg"] == 4.67
    assert members[family_middle(members, within_db=0.015)]["elevation_width_deg"] == 3.0  # 2, 3, 4.67
