"""Gradients of the differentiable engine (issue 24, items 2 and 3): against central finite
differences of the compiled engine (rebuilt at each step, the search verified unchanged) for
every parameter family, of the held forward on the demo, against closed forms, and mutations
of the gradient that the checks must catch."""

from __future__ import annotations

import math

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jnp = pytest.importorskip("jax.numpy")

from sonarsim.config.examples import demo_scene_dict  # noqa: E402

import sonarsim.diff as sd  # noqa: E402
from sonarsim.diff import check  # noqa: E402

SONAR = {"n_beams": 48, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5, "range_max_m": 4.0,
         "n_range_bins": 350}
# Two nearly parallel planes (a channel): multipath through chains of planes, image sources,
# and no corner or silhouette that a step could move a ray across.
CHANNEL = {"sonar": {**SONAR, "elevation_fov_deg": 30.0, "range_max_m": 8.0, "n_range_bins": 600,
                     "pose": {"position_m": [0.0, 0.0, 0.5], "rpy_deg": [2.0, 1.0, 3.0]}},
           # (paper: a coherent pair's factor 2, held where its legs share a beam, jumps as a step
           # moves a leg across a beam's edge: a finite difference sees the jump, the gradient not)
           "render": {"max_order": 3, "elevation_samples": 96, "double_beam": "paper"},
           "planes": [{"name": "bed", "point_m": [0, 0, 0.0], "normal": [0.03, -0.02, 1.0], "albedo": 0.5, "specular": 0.6},
                      {"name": "surface", "point_m": [0, 0, 1.0], "normal": [0.02, 0.01, -1.0],
                       "material": {"law": "lambert", "mu": 0.1}, "specular": 0.9}]}
OCULUS = {"sonar": {"preset": "oculus-m1200d-hf", "pose": {"position_m": [0, 0, 0.433], "rpy_deg": [1.42, 29.06, 0]}},
          "ground": {}, "sensor": {"preset": "oculus-m1200d-hf"}}


def sheet_scene(tmp_path) -> dict:
    """One large triangle, tilted in its own frame, filling the fan: no edge in view."""
    path = tmp_path / "sheet.obj"
    path.write_text("v 0.1 -3 -1.5\nv 0.3 3 -1.5\nv -0.2 0.3 3\nf 1 2 3\n")
    return {"sonar": {**SONAR, "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [2.0, 0.0, 3.0]}},
            "render": {"max_order": 1, "elevation_samples": 96},
            "objects": [{"name": "sheet", "mesh": str(path), "pose": {"position_m": [2.5, 0.2, 1.0], "rpy_deg": [3.0, 10.0, 25.0]},
                         "material": {"law": "rough", "albedo": 0.4, "specular_strength": 0.5, "roughness": 0.3}}]}


def assert_checked(rows, families, tolerance=0.02):
    bad = check.failures(rows, tolerance)
    assert not bad, "\n" + check.report([r for r, _ in bad])
    for family in families:
        seen = [r for r in rows if r.key.startswith(family)]
        assert any(r.finite_difference != 0.0 for r in seen), f"{family}: nothing to check"


def test_sonar_pose_and_planes_against_the_compiled_engine():
    rows = check.check_gradients(sd.Renderer(CHANNEL))
    assert_checked(rows, ["sonar.position_m", "sonar.rpy_deg", "planes.bed.offset_m", "planes.bed.normal",
                          "planes.bed.specular", "planes.bed.albedo", "planes.surface.offset_m",
                          "planes.surface.normal", "planes.surface.mu"])
    assert all(r.reference == "compiled" for r in rows)
    # Multipath is part of what was checked: the bed mirrors some of the paths.
    assert abs(next(r for r in rows if r.key == "planes.bed.specular").gradient) > 0


def test_object_pose_scale_vertices_and_material_against_the_compiled_engine(tmp_path):
    rows = check.check_gradients(sd.Renderer(sheet_scene(tmp_path)))
    assert_checked(rows, ["objects.sheet.position_m", "objects.sheet.rpy_deg", "objects.sheet.scale",
                          "objects.sheet.vertices_m", "objects.sheet.albedo", "objects.sheet.specular_strength",
                          "objects.sheet.roughness"])


def test_the_sensor_against_the_compiled_engine():
    r = sd.Renderer(OCULUS)
    keys = [k for k in r.names if k.startswith("sensor.")]
    rows = check.check_gradients(r, keys)
    assert_checked(rows, keys)
    # The TVG law's coefficient takes 0, 20, 30 or 40 in a scene file: its difference is the
    # held forward's (and the closed form below checks it against the gain's).
    assert {r.key for r in rows if r.reference == "held"} == {"sensor.tvg_spreading"}


def test_every_family_of_the_demo_against_the_held_forward():
    doc = demo_scene_dict()
    doc["render"]["double_beam"] = "paper"  # (as CHANNEL: the coherent factor is held, not differentiated)
    r = sd.Renderer(doc)
    rows = check.check_gradients(r, reference="held")
    assert_checked(rows, ["sonar.", "objects.concrete_block.position_m", "objects.buoy.vertices_m", "objects.pipe.scale",
                          "objects.plastic_drum.rpy_deg", "planes.ground.normal", "planes.ground.offset_m"])


def test_the_floor_onset_range_against_height_and_pitch_in_closed_form():
    """The nearest floor echo of each beam comes from its lowest ray: r = z / sin(depression),
    with the depression of that ray from the sonar's pitch, its elevation and its azimuth."""
    scene = {"sonar": {**SONAR, "pose": {"position_m": [0.0, 0.0, 0.8], "rpy_deg": [0.0, 25.0, 0.0]}},
             "render": {"max_order": 1, "elevation_samples": 64}, "ground": {"albedo": 0.5}}
    r = sd.Renderer(scene)
    p = r.params()
    fan = r._fan
    n_el = fan.shape[2]
    phi = fan.elevation_rad[0]  # the lowest ray of every beam
    theta = fan.azimuth_rad[:, 0]

    def onset(q):
        paths = r.paths(q)
        return jax.ops.segment_min(paths["distance"], jnp.asarray(paths["beam"]), num_segments=fan.shape[0])

    z, pitch = 0.8, math.radians(25.0)
    down = math.sin(pitch) * math.cos(phi) * np.cos(theta) - math.cos(pitch) * math.sin(phi)
    np.testing.assert_allclose(np.asarray(onset(p)), z / down, rtol=1e-9)
    jac = jax.jacobian(onset)(p)
    d_down = math.cos(pitch) * math.cos(phi) * np.cos(theta) + math.sin(pitch) * math.sin(phi)
    np.testing.assert_allclose(np.asarray(jac["sonar.position_m"])[:, 2], 1.0 / down, rtol=1e-9)
    np.testing.assert_allclose(np.asarray(jac["sonar.rpy_deg"])[:, 1], -z * d_down / down**2 * math.pi / 180.0, rtol=1e-9)
    # The floor's own height moves it the other way.
    np.testing.assert_allclose(np.asarray(jac["planes.ground.offset_m"]), -1.0 / down, rtol=1e-9)
    assert n_el == 64


def test_a_level_floor_is_the_same_seen_from_anywhere_over_it():
    r = sd.Renderer({"sonar": {**SONAR, "pose": {"position_m": [0.3, -0.2, 0.8], "rpy_deg": [1.0, 25.0, 40.0]}},
                     "render": {"max_order": 1, "elevation_samples": 64}, "ground": {"albedo": 0.5}})
    g = jax.grad(lambda q: jnp.sum(r.render(q) ** 2))(r.params())
    assert np.abs(np.asarray(g["sonar.position_m"])[:2]).max() < 1e-12 * np.abs(np.asarray(g["sonar.position_m"])[2])
    assert abs(float(g["sonar.rpy_deg"][2])) < 1e-12 * abs(float(g["sonar.rpy_deg"][1]))


def test_the_tvg_coefficient_acts_as_a_gain_of_log10_r():
    """``tvg_db = spreading log10 r + gain_db``: per pixel, d out / d spreading is log10(r)
    times d out / d gain_db."""
    r = sd.Renderer(OCULUS)
    p = r.params()

    def along(key):
        return jax.jvp(r.render, (p,), ({k: jnp.zeros_like(v) for k, v in p.items()} | {key: jnp.ones(())},))[1]

    log_r = np.log10(np.maximum(r.scene.sonar.range_m, 1e-3))[:, None]
    a, b = np.asarray(along("sensor.tvg_spreading")), np.asarray(along("sensor.gain_db"))
    np.testing.assert_allclose(a, log_r * b, rtol=1e-9, atol=1e-12 * np.abs(b).max())


def test_an_albedo_scales_its_surfaces_paths_only():
    r = sd.Renderer(demo_scene_dict())
    p = r.params()
    c = r.components(p)
    g = jax.jacfwd(lambda a: r.components({**p, "objects.buoy.albedo": a})["total"])(p["objects.buoy.albedo"])
    # The buoy's share of the image over its albedo: the image without it subtracted.
    without = r.components({**p, "objects.buoy.albedo": jnp.asarray(0.0)})["total"]
    np.testing.assert_allclose(np.asarray(g), (np.asarray(c["total"]) - np.asarray(without)) / float(p["objects.buoy.albedo"]),
                               rtol=1e-9, atol=1e-12 * float(np.abs(np.asarray(g)).max()))


# Mutations the checks must catch -------------------------------------------------------------


@pytest.fixture(autouse=True)
def _fresh_traces():
    """Traces are cached by function: a mutated forward must not outlive its test."""
    yield
    jax.clear_caches()


def test_a_sign_flipped_in_the_pose_jacobian_fails_the_check(monkeypatch):
    from sonarsim.diff import forward

    honest = forward.rpy_matrix

    @jax.custom_jvp
    def flipped(rpy):
        return honest(rpy)

    @flipped.defjvp
    def _(primals, tangents):
        value, tangent = jax.jvp(honest, primals, tangents)
        return value, -tangent

    monkeypatch.setattr(forward, "rpy_matrix", flipped)
    jax.clear_caches()  # the forward traced before the mutation would be reused
    rows = check.check_gradients(sd.Renderer(CHANNEL), ["sonar.rpy_deg"])
    assert check.failures(rows), check.report(rows)


def test_a_dropped_beam_width_gradient_fails_the_check(monkeypatch):
    from sonarsim.diff import sensor

    honest = sensor.pattern_gain
    monkeypatch.setattr(sensor, "pattern_gain", lambda a, shape, window, width, ways: honest(
        a, shape, window, jax.lax.stop_gradient(width), ways))
    jax.clear_caches()
    r = sd.Renderer(OCULUS)
    rows = check.check_gradients(r, ["sensor.elevation_width_deg", "sensor.azimuth_width_deg"], reference="held")
    assert {row.key for row, _ in check.failures(rows)} == {"sensor.elevation_width_deg", "sensor.azimuth_width_deg"}


def test_scatterers_held_on_their_triangles_see_the_objects_move_across_the_beams():
    """Turning the sonar moves an object's echo across the beams: a held ray cannot see it (it
    stays on its triangle's plane, in its beam), a ray turned to follow its scatterer on its
    triangle (``attach='surfaces'``) can. Against the compiled engine's central difference
    over 0.2 degrees and 1 cm (its search refreshed: the silhouettes move), of a smooth
    functional of the blurred image, for a ball in open water."""
    from sonarsim.diff.inverse import blur
    from sonarsim.diff.params import scene_with
    from sonarsim.renderer.simulator import Simulator

    doc = {"sonar": demo_scene_dict()["sonar"], "render": {"max_order": 1},
           "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 0.2, "pose": {"position_m": [2.5, 0.3, 0.2]}}]}
    errors, signs = {}, {}
    for attach in ("surfaces", "rays"):
        r = sd.Renderer(doc, attach=attach)
        p = r.params()
        image = np.asarray(r.render(p))
        w = jnp.asarray(check.smooth_weights(image.shape))
        scale = float(np.median(image[image > 0]))

        def functional(image, scale=scale, w=w):
            return jnp.sum(w * jnp.log1p(jnp.maximum(blur(image, (6.0, 3.0)), 0.0) / scale))

        g = jax.grad(lambda q: functional(r.render(q)))(p)
        for key, index, h in (("sonar.rpy_deg", 2, 0.2), ("sonar.position_m", 1, 0.01)):
            values = []
            for sign in (1.0, -1.0):
                v = np.asarray(p[key], float).copy()
                v[index] += sign * h
                with Simulator(scene_with(r.scene, {key: v})) as sim:
                    values.append(float(functional(jnp.asarray(sim.render(speckle=False).polar, jnp.float64))))
            fd = (values[0] - values[1]) / (2 * h)
            errors[attach, key] = abs(float(g[key][index]) - fd) / abs(fd)
            signs[attach, key] = float(g[key][index]) * fd > 0
    assert errors["surfaces", "sonar.rpy_deg"] < 0.15 and errors["surfaces", "sonar.position_m"] < 0.15, errors
    assert not signs["rays", "sonar.rpy_deg"] and not signs["rays", "sonar.position_m"], errors


def test_transmit_legs_over_two_planes_follow_the_image_sources_in_order():
    """Paths whose transmit leg meets two planes (not the receive leg reversed): the image
    sources' order matters there (found missing by a mutation that walked the chain forwards)."""
    import copy

    from sonarsim.renderer.simulator import Simulator

    doc = copy.deepcopy(CHANNEL)
    doc["render"].update(max_order=5, double_beam="separate")
    doc["sonar"]["elevation_fov_deg"] = 60.0
    doc["objects"] = [{"name": "ball", "primitive": "sphere", "radius_m": 0.3, "pose": {"position_m": [3.0, 0.0, 0.5]}}]
    r = sd.Renderer(doc)
    n = r.search.n_paths
    two = (r.search.tx_planes[:n] >= 0).sum(axis=1) >= 2
    assert two.sum() > 100 and not r.search.same[:n][two].any()
    np.testing.assert_allclose(np.asarray(r.paths()["distance"]), r.search.distance[:n], rtol=0, atol=2e-6)
    with Simulator(doc) as sim:
        ref = sim.render(speckle=False).polar
    image = np.asarray(r.render())
    assert np.abs(image - ref).sum() / np.abs(ref).sum() < 1e-4


def test_the_leakage_kernel_is_the_compiled_models_and_sums_to_one():
    """(Scaling the kernel cancels in the blur's edge normalisation: only a direct test sees it.)"""
    from sonarsim.diff import sensor

    r = sd.Renderer(OCULUS)
    k = np.asarray(sensor.leakage_kernel(r.params(), r.data, r.static.sensor))
    assert k.sum() == pytest.approx(1.0, abs=1e-12)
    np.testing.assert_allclose(k, r._sensor.model.beam_leakage, rtol=1e-9, atol=1e-15)


def test_the_column_factor_follows_the_azimuth_width_as_the_compiled_models_does():
    """The beam's cell times the pattern's equivalent width: at the scene's width the compiled
    model's, and at another width the compiled model built with that width."""
    from dataclasses import replace

    from sonarsim.diff import sensor
    from sonarsim.sensor.model import SensorModel

    r = sd.Renderer(OCULUS)
    params = r.params()
    np.testing.assert_allclose(np.asarray(sensor.column_factor(params, r.data, r.static.sensor)),
                               r._sensor.model.column_factor, rtol=1e-6)
    model = r._sensor.model
    wide = float(params["sensor.azimuth_width_deg"]) * 1.5
    reach = (len(model.beam_leakage) - 1) // 2  # the differentiable kernel keeps the scene's reach
    spec = replace(model.spec, azimuth_pattern=replace(model.spec.azimuth_pattern, width_deg=wide,
                                                       leakage_beams=reach))
    other = SensorModel(spec, model.sonar, fields=False)
    moved = sensor.column_factor({**params, "sensor.azimuth_width_deg": wide}, r.data, r.static.sensor)
    np.testing.assert_allclose(np.asarray(moved), other.column_factor, rtol=1e-4)
    assert other.column_factor[0] > model.column_factor[0] * 1.3  # a wider beam hears more of a floor
