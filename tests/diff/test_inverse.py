"""Inverse problems by gradient (issue 24, item 5): the pose of a synthetic recording."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jnp = pytest.importorskip("jax.numpy")

from sonarsim.config.examples import demo_scene_dict  # noqa: E402
from sonarsim.errors import ConfigError  # noqa: E402
from sonarsim.renderer.simulator import Simulator  # noqa: E402

import sonarsim.diff as sd  # noqa: E402
from sonarsim.diff.inverse import blur, fit  # noqa: E402
from sonarsim.core.extras import install_command


@pytest.fixture(scope="module")
def demo_target():
    doc = demo_scene_dict()
    with Simulator(doc) as sim:
        return doc, sim.render(speckle=False).polar


def test_fit_recovers_a_synthetic_pose_from_10_cm_and_5_degrees_off(demo_target):
    doc, target = demo_target
    truth = {"x": 0.0, "y": 0.0, "z": 1.0, "pitch": 20.0, "yaw": 0.0}
    start = {"x": 0.1, "y": -0.1, "z": 1.1, "pitch": 25.0, "yaw": -5.0}
    r = sd.Renderer(doc, attach="surfaces")
    result = fit(r, target, free=("x", "y", "z", "pitch", "yaw"), starts=[start])
    for k in ("x", "y", "z"):
        assert abs(result.values[k] - truth[k]) < 0.01, result.values
    for k in ("pitch", "yaw"):
        assert abs(result.values[k] - truth[k]) < 0.3, result.values
    assert result.loss < 1e-4
    (only,) = result.starts
    assert only.start == start and only.values == result.values
    # The renderer's search is left at the fit.
    assert np.allclose(np.asarray(r.paths(result.params)["distance"]), r.search.distance[: r.search.n_paths], atol=2e-6)


def test_fit_refuses_unknown_parameters_and_a_target_of_another_shape(demo_target):
    doc, target = demo_target
    r = sd.Renderer(doc)
    with pytest.raises(ConfigError, match="free: unknown free parameter 'heave'"):
        fit(r, target, free=("heave",))
    with pytest.raises(ConfigError, match="target: has shape"):
        fit(r, target[:10], free=("z",))


def test_the_blur_is_a_gaussian_of_unit_mass_inside_and_zero_outside():
    x = np.zeros((101, 61))
    x[50, 30] = 1.0
    y = np.asarray(blur(jnp.asarray(x), (4.0, 2.0)))
    assert y.sum() == pytest.approx(1.0, rel=1e-9)
    r = np.arange(101) - 50
    np.testing.assert_allclose(y[:, 30] / y[50, 30], np.exp(-0.5 * (r / 4.0) ** 2), atol=1e-9)
    # Zero outside: an impulse at the edge loses the half that falls outside.
    x[:] = 0.0
    x[0, 30] = 1.0
    assert np.asarray(blur(jnp.asarray(x), (4.0, 2.0))).sum() == pytest.approx(0.5 + 0.5 * 0.0997, rel=0.05)


def test_calibration_by_gradient_on_a_real_oculus_ping_holds_on_the_others(shared_data):
    """From a generic sonar (12 degrees of elevation, the calibration's generic sensor) far
    from the floor band's pose, calibrated on ping 0 and scored on pings 1 and 2 (the full
    table of starts: benchmarks/bench_calibrate.py)."""
    import sonarsim
    from sonarsim.analysis.baselines import baseline_images, held_out_scores
    from sonarsim.diff.inverse import calibrate_recording
    from sonarsim.io.readers import read_frames

    pings = list(read_frames(shared_data / "real" / "oculus" / "three_pings_8bit.raw"))
    scene = sonarsim.load_scene({
        "sonar": {"preset": "oculus-m1200d-hf", "elevation_fov_deg": 12.0,
                  "pose": {"position_m": [0, 0, 0.7], "rpy_deg": [0, 40, 0]}},
        "render": {"bounces": [1]}, "ground": {"height_m": 0, "albedo": 0.8}})
    res = calibrate_recording(pings[0], scene, free=("z", "pitch", "roll"))
    held = [p.polar for p in pings[1:]]
    scores = held_out_scores({"model": res.expected.polar, **baseline_images(pings[0].polar)}, held)
    # Measured: 19.35 dB (the search calibration with channels, texture and range law: 19.30-19.33).
    assert scores["model"]["psnr"] >= 19.25
    # The start is the closed-form one, the levels' grid included (17.3 dB on the frame).
    assert res.psnr_db > res.psnr_start_db + 1.0
    assert res.law["compression"] == "gamma" and res.law["spreading"] in (0.0, 20.0, 30.0, 40.0)
    # The scene written renders what was scored (the compiled engine's expected output).
    with sonarsim.Simulator(res.scene) as sim:
        np.testing.assert_array_equal(sim.render(speckle=False).polar, res.expected.polar)
    assert set(res.baselines) == {"range profile", "separable", "ceiling"}
    assert scores["model"]["margin_db"] > -1.0  # beside the trivial baselines (reported in the note)


SMALL_SENSOR = {"sonar": {"n_beams": 32, "azimuth_fov_deg": 40.0, "elevation_fov_deg": 20.0, "range_min_m": 0.3,
                          "range_max_m": 3.0, "n_range_bins": 300,
                          "pose": {"position_m": [0, 0, 0.5], "rpy_deg": [0, 25, 0]}},
                "render": {"bounces": [1]}, "ground": {"albedo": 0.8},
                "sensor": {"source_level_db": 180.0, "tvg": {"spreading": 20.0},
                           "elevation_pattern": {"shape": "gaussian"}, "noise": {"level_db": 40.0},
                           "speckle": {"model": "rayleigh"},
                           "output": {"compression": "gamma", "gamma": 0.3, "ceiling_db": 160.0, "dtype": "uint8"}}}


def test_the_level_start_finds_a_gain_tens_of_db_off():
    """The generic sensor's gain can start 60 dB off a device's; the coordinate search over the
    sensor stage alone puts it within a grid step (6 dB) of the truth."""
    from sonarsim.diff.inverse import level_start

    doc = {**SMALL_SENSOR, "sensor": {**SMALL_SENSOR["sensor"], "gain_db": -40.0}}
    r = sd.Renderer(doc)
    truth = dict(r.params())
    truth["sensor.gain_db"] = jnp.asarray(20.0)
    target = np.asarray(r.render(truth))
    assert np.ptp(np.asarray(r.render())) < 0.05 * np.ptp(target)  # at the start: (nearly) nothing to see
    start = level_start(r, {}, target)
    assert abs(start["sensor.gain_db"] - 20.0) <= 6.0
    assert set(start) == {"sensor.gain_db", "sensor.noise_db"}  # the scene has no noise after the TVG


def test_the_channels_gains_in_closed_form():
    """Stripes of +-2 dB across the beams and a 1 dB offset: recovered to 0.02 dB, the mean in
    the gain (the channels' own mean is zero)."""
    from sonarsim.diff.inverse import fit_beam_gains

    r = sd.Renderer(SMALL_SENSOR)
    p = dict(r.params())
    stripes = np.random.default_rng(7).uniform(-2.0, 2.0, p["sensor.beam_gain_db"].shape)
    stripes -= stripes.mean()
    truth = {**p, "sensor.beam_gain_db": jnp.asarray(stripes), "sensor.gain_db": p["sensor.gain_db"] + 1.0}
    target = np.asarray(r.render(truth))
    got = fit_beam_gains(r, p, target)
    np.testing.assert_allclose(np.asarray(got["sensor.beam_gain_db"]), stripes, atol=0.02)
    assert float(got["sensor.gain_db"]) == pytest.approx(float(p["sensor.gain_db"]) + 1.0, abs=0.02)


def test_the_sensor_stages_jacobian_columns_are_the_full_forward_modes(monkeypatch):
    """The fit takes the Jacobian columns of the sensor stage's parameters on the echo formed
    once: one Levenberg-Marquardt step with them is the step with every column through the
    whole forward."""
    from sonarsim.diff import inverse

    r = sd.Renderer(SMALL_SENSOR)
    truth = dict(r.params())
    truth["sonar.position_m"] = truth["sonar.position_m"].at[2].set(0.52)
    target = np.asarray(r.render(truth))
    steps = {}
    for stage in (inverse.SENSOR_STAGE, frozenset()):
        monkeypatch.setattr(inverse, "SENSOR_STAGE", stage)
        for free in (("z", "sensor.gain_db"),):
            steps[stage, free] = fit(r, target, free=free, blurs=((2.0, 1.0),), iterations=1, linear=True,
                                     scale=255.0).values
    for (stage, free), values in steps.items():
        for name in free:
            assert values[name] == pytest.approx(steps[frozenset(), free][name], rel=1e-9, abs=1e-12)
    split = steps[next(iter(steps))[0], ("z", "sensor.gain_db")]
    assert split["z"] > 0.505  # it stepped towards 0.52


def test_calibration_by_gradient_on_the_aris_sample_holds_on_its_other_frames(shared_data):
    """A sea bed lit across the whole window: the band tells neither height nor tilt, so the
    pose is held at a window start (the pitch that centres the window's depression angles, at
    the one of a few heights that fits the frame best); the sensor and the channels are fitted
    on frame 0 and scored on frames 1-5 (the table of starts: benchmarks/bench_calibrate.py)."""
    import math

    import sonarsim
    from sonarsim.analysis.baselines import baseline_images, held_out_scores
    from sonarsim.diff.inverse import calibrate_recording, window_start
    from sonarsim.io.readers import read_frames

    frames = list(read_frames(shared_data / "real" / "aris" / "sample.aris"))
    scene = sonarsim.load_scene({
        "sonar": {"preset": "aris1200-48-telephoto", "elevation_fov_deg": 12.0,
                  "pose": {"position_m": [0, 0, 0.5], "rpy_deg": [0, 30, 0]}},
        "render": {"bounces": [1]}, "ground": {"height_m": 0, "albedo": 0.5}})
    start = window_start(frames[0], scene)
    r0, r1 = float(frames[0].range_m[0]), float(frames[0].range_m[-1])
    near, far = math.degrees(math.asin(0.5 / r0)), math.degrees(math.asin(0.5 / r1))
    assert start["pitch"] == pytest.approx((near + far) / 2, rel=1e-3)
    res = calibrate_recording(frames[0], scene, free=("z", "pitch", "roll"), refuse_degenerate=False)
    assert any("not identified" in w for w in res.warnings)
    # Held at a window start: one of the candidate heights, with its pitch.
    z = res.scene.sonar_pose.position_m[2]
    assert res.scene.sonar_pose.rpy_deg[1] == pytest.approx(window_start(frames[0], scene, z)["pitch"], abs=1e-6)
    held = [f.polar for f in frames[1:]]
    scores = held_out_scores({"model": res.expected.polar, **baseline_images(frames[0].polar)}, held)
    # Measured: 25.27 dB; the range profile copied across the beams 24.79, the separable image
    # 25.55, the ceiling 25.75.
    assert scores["model"]["psnr"] >= scores["range profile"]["psnr"] + 0.3
    assert scores["model"]["psnr"] >= scores["separable"]["psnr"] - 0.5


def test_the_window_start_needs_a_recording_lit_across_its_window(shared_data):
    import sonarsim
    from sonarsim.diff.inverse import window_start
    from sonarsim.io.readers import read_frames

    ping = next(iter(read_frames(shared_data / "real" / "oculus" / "one_ping_8bit.raw")))
    scene = sonarsim.load_scene({"sonar": {"preset": "oculus-m1200d-hf"}, "ground": {}})
    assert window_start(ping, scene) is None  # a floor band with edges


def test_calibrate_by_gradient_without_jax_names_the_extra(tmp_path, capsys, monkeypatch):
    import importlib.util

    import sonarsim
    from sonarsim.cli.main import main

    doc = {"sonar": {"preset": "oculus-m1200d-hf", "pose": {"position_m": [0, 0, 0.4], "rpy_deg": [0, 28, 0]}},
           "ground": {}, "render": {"bounces": [1]}}
    sonarsim.render(sonarsim.load_scene(doc)).save_npz(tmp_path / "real.npz")
    (tmp_path / "s.yaml").write_text(__import__("yaml").safe_dump(doc))
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "jax" else find_spec(name, *a))
    try:
        status = main(["calibrate", str(tmp_path / "real.npz"), "--scene", str(tmp_path / "s.yaml"), "--method",
                       "gradient", "--out", str(tmp_path / "c.yaml")])
    except SystemExit as exc:
        status = exc.code
    err = capsys.readouterr().err
    assert status == 2 and install_command("diff") in err and "Traceback" not in err
    assert not (tmp_path / "c.yaml").exists()


def _seabed_case(n_views: int):
    from dataclasses import replace

    from sonarsim.config.loader import load_scene
    from sonarsim.config.scene import ObjectSpec
    from sonarsim.core.transforms import Pose
    from sonarsim.diff.reconstruct import grid_mesh

    amp, extent = 0.1, (1.0, 3.0, -0.8, 0.8)
    base = load_scene({"sonar": {"preset": "aris3000-128", "range_min_m": 0.7, "range_max_m": 3.5, "n_range_bins": 600},
                       "render": {"bounces": [1], "max_order": 1}, "ground": {"albedo": 0.6}})

    def heights(x, y):  # a bump of 10 cm on a slope of 3 %
        gx, gy = np.meshgrid(x, y)
        return amp * np.exp(-((gx - 2.0) ** 2 + (gy - 0.1) ** 2) / (2 * 0.25 ** 2)) + 0.03 * (gx - 2.0)

    _, xt, yt = grid_mesh(extent, 0.02)
    truth_mesh, _, _ = grid_mesh(extent, 0.02, heights(xt, yt))
    truth = replace(base, ground=None, objects=(ObjectSpec(name="seabed", mesh=truth_mesh, albedo=0.6),))
    poses = [Pose((0.0, y, 1.0), (0.0, 25.0, yaw)) for y, yaw in ((0.0, 0.0), (-0.5, 12.0), (0.5, -12.0))][:n_views]
    with Simulator(truth) as sim:
        images = [sim.render(pose=p, speckle=False).polar for p in poses]
    return base, images, poses, extent, heights, amp


@pytest.mark.parametrize("n_views, bound", [(1, 0.08), (3, 0.03)])
def test_a_seabeds_heights_from_known_poses(n_views, bound):
    """A bump of 10 cm on a slope, meshed at 2 cm, seen from known poses, reconstructed on a
    10 cm grid from a flat start. Measured RMS over the seen vertices: 5.6 mm from one view,
    1.5 mm from four (a flat floor is 31-33 mm off)."""
    from sonarsim.diff.reconstruct import reconstruct_heights

    base, images, poses, extent, heights, amp = _seabed_case(n_views)
    out = reconstruct_heights(base, images, poses, extent, 0.1)
    truth = heights(out.x_m, out.y_m)
    seen = out.seen
    assert seen.sum() > 0.5 * seen.size
    error = float(np.sqrt(np.mean((out.heights_m - truth)[seen] ** 2)))
    flat = float(np.sqrt(np.mean(truth[seen] ** 2)))
    assert error < bound * amp and error < 0.3 * flat, (error, flat)
    assert out.loss[-1] < out.loss[0]


def test_a_brighter_patch_of_a_flat_floor_is_found_as_reflectivity():
    """A flat floor whose reflectivity is 3 in a disc of 0.3 m (rendered by the differentiable
    forward, the scene format having no such field), reconstructed with ``reflectivity``: the
    disc comes out brighter than the rest, which stays near 1, and the heights near flat.
    Measured from one view on a 10 cm grid: 1.73 in the disc (the smoothness and the grid
    blunt the step), 1.01 outside; heights 14.7 mm RMS (part of the brightness taken as
    relief)."""
    from dataclasses import replace

    from sonarsim.config.loader import load_scene
    from sonarsim.config.scene import ObjectSpec
    from sonarsim.core.transforms import Pose
    from sonarsim.diff.reconstruct import grid_mesh, reconstruct_heights

    extent = (1.0, 3.0, -0.8, 0.8)
    base = load_scene({"sonar": {"preset": "aris3000-128", "range_min_m": 0.7, "range_max_m": 3.5, "n_range_bins": 600},
                       "render": {"bounces": [1], "max_order": 1}, "ground": {"albedo": 0.6}})
    mesh, xt, yt = grid_mesh(extent, 0.05)
    gx, gy = np.meshgrid(xt, yt)
    disc = (gx - 2.2) ** 2 + (gy + 0.2) ** 2 < 0.3 ** 2
    pose = Pose((0.0, 0.0, 1.0), (0.0, 25.0, 0.0))
    truth = sd.Renderer(replace(base, ground=None, sonar_pose=pose,
                                objects=(ObjectSpec(name="seabed", mesh=mesh, albedo=0.6),)), reflectivity=("seabed",))
    image = np.asarray(truth.render({"objects.seabed.reflectivity": jnp.asarray(np.where(disc, 3.0, 1.0).ravel())}))
    out = reconstruct_heights(base, [image], [pose], extent, 0.1, reflectivity=True, rounds=2)
    gx, gy = np.meshgrid(out.x_m, out.y_m)
    d2 = (gx - 2.2) ** 2 + (gy + 0.2) ** 2
    inside, outside = out.seen & (d2 < 0.15 ** 2), out.seen & (d2 > 0.5 ** 2)
    assert inside.sum() >= 3 and outside.sum() > 50
    assert np.median(out.reflectivity[inside]) > 1.5 * np.median(out.reflectivity[outside])
    assert 0.8 < np.median(out.reflectivity[outside]) < 1.25
    assert float(np.sqrt(np.mean(out.heights_m[out.seen] ** 2))) < 0.02
