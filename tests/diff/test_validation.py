"""The differentiable engine's parameters checked where they are concrete, degenerate geometry
harmless inside ``jit``, and a warning when the parameters leave the held search (issue 37).

One small scene (:mod:`tests.diff.small_scenes`) compiled once per module: a box and a rough
ball on a ground, with a sensor whose elevation and azimuth widths are parameters.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jnp = pytest.importorskip("jax.numpy")

import sonarsim.diff as sd  # noqa: E402
from sonarsim.config.materials import Material  # noqa: E402
from sonarsim.config.scene import ObjectSpec, PlaneSpec  # noqa: E402
from sonarsim.config.sensor import OutputSpec, PatternSpec  # noqa: E402
from sonarsim.diff.check import smooth_weights  # noqa: E402
from sonarsim.diff.params import check_value  # noqa: E402
from sonarsim.errors import ConfigError  # noqa: E402
from tests.diff.small_scenes import SCENES, SENSED  # noqa: E402

BEFORE = Path(__file__).parent / "data" / "before_issue37.npz"


@pytest.fixture(scope="module")
def sensed():
    """The scene with a sensor, its renderer, the image function (jitted: its values are
    abstract, nothing is checked) and the gradient of a smooth functional of it: the functions
    :meth:`~sonarsim.diff.Renderer.render` compiles (one compilation for the whole module)."""
    r = sd.Renderer(SENSED)
    image = r.image_function()
    w = jnp.asarray(smooth_weights(r.render().shape))
    grad = jax.grad(lambda p, d: jnp.sum(w * image(p, d)))
    return r, image, grad


def finite(tree) -> bool:
    return all(bool(np.all(np.isfinite(np.asarray(v)))) for v in jax.tree_util.tree_leaves(tree))


# Item 2: checked where concrete ------------------------------------------------------------

def test_a_nan_position_is_refused_by_name_directly_and_through_grad_jacfwd_and_vmap(sensed):
    r, _, _ = sensed
    p = r.params()
    bad = p["sonar.position_m"].at[1].set(jnp.nan)
    with pytest.raises(ConfigError, match=r"^sonar.position_m: must be finite, within \[-1e\+06, 1e\+06\] m"):
        r.render({**p, "sonar.position_m": bad})
    with pytest.raises(ConfigError, match=r"sonar.position_m: .* got nan \(at \[1\]\)"):
        jax.grad(lambda q: r.render({**p, "sonar.position_m": q}).sum())(bad)
    with pytest.raises(ConfigError, match="sonar.position_m: must be finite"):
        jax.jacfwd(lambda q: r.render({**p, "sonar.position_m": q}).sum())(bad)
    batch = jnp.stack([p["sonar.position_m"], bad])  # one bad member of a batch
    with pytest.raises(ConfigError, match="sonar.position_m: must be finite"):
        jax.vmap(lambda q: r.render({**p, "sonar.position_m": q}))(batch)
    with pytest.raises(ConfigError, match="sensor.gain_db: must be finite"):
        r.echo({**p, "sensor.gain_db": jnp.inf})


@pytest.mark.parametrize("key,value,allowed", [
    ("objects.box.albedo", -0.2, r"\[0, 1\]"),
    ("planes.ground.specular", 5.0, r"\[0, 1\]"),
    ("objects.box.scale", [0.0, 0.0, 0.0], r"\[1e-06, 10000\]"),
    ("objects.ball.roughness", 0.0, r"\[0.001, 0.5\]"),
    ("sensor.elevation_width_deg", 0.0, r"\[0.01, 180\) degrees"),
    ("planes.ground.normal", [0.0, 0.0, 0.0], "zero vector"),
])
def test_values_the_scene_format_refuses_are_refused_with_the_range(sensed, key, value, allowed):
    r, _, _ = sensed
    with pytest.raises(ConfigError, match=f"^{key}: .*{allowed}"):
        r.render({key: jnp.asarray(value)})
    # refresh takes what is finite (a fit's trial step beyond a bound fails, it does not stop
    # the fit); what is not finite it refuses too.
    if "normal" not in key and "scale" not in key:
        r.refresh({key: jnp.asarray(value)})
        r.refresh()
    with pytest.raises(ConfigError, match=key):
        r.refresh({key: jnp.full(np.shape(value), jnp.nan)})


@pytest.mark.parametrize("make,key,values", [
    (lambda v: ObjectSpec(name="o", primitive="box", size_m=(1, 1, 1), albedo=v), "objects.o.albedo",
     [-1e-9, 0.0, 0.5, 1.0, 1.0 + 1e-9]),
    (lambda v: ObjectSpec(name="o", primitive="box", size_m=(1, 1, 1), scale=v), "objects.o.scale",
     [0.0, 9e-7, 1e-6, 1e4, 1.0001e4]),
    (lambda v: PlaneSpec(name="p", specular=v), "planes.p.specular", [-0.1, 0.0, 1.0, 1.1]),
    (lambda v: Material(law="rough", albedo=0.5, specular_strength=1.0, roughness=v), "objects.o.roughness",
     [9e-4, 1e-3, 0.5, 0.51]),
    (lambda v: PatternSpec(shape="gaussian", width_deg=v), "sensor.elevation_width_deg", [0.0, 0.009, 0.01, 179.9, 180.0]),
    (lambda v: OutputSpec(compression="gamma", gamma=v), "sensor.gamma", [0.04, 0.05, 4.0, 4.1]),
])
def test_the_bounds_are_the_scene_formats_own(make, key, values):
    """What the scene format's own specs refuse, the parameter check refuses, at both sides
    of each bound (one home: the bounds are read from the specs' constants)."""
    for v in values:
        try:
            make(v)
            accepted = True
        except ConfigError:
            accepted = False
        try:
            check_value(key, np.asarray(v if "scale" not in key else [v] * 3, float))
            checked = True
        except ConfigError:
            checked = False
        assert accepted == checked, (key, v)


# Item 3: degenerate geometry inside jit ----------------------------------------------------

def test_a_normal_scene_renders_as_before_issue_37(sensed):
    """Images and gradients of the small scenes equal those the engine gave before the
    degenerate-geometry guards and the objects posed at once (``data/before_issue37.npz``,
    written by the earlier forward with the ray weight's cos(elevation) already in it:
    ``data/make_before_issue37.py``), to round-off."""
    before = np.load(BEFORE)
    for name, doc in SCENES.items():
        r = sensed[0] if name == "sensed" else sd.Renderer(doc)
        p = r.params()
        image = np.asarray(r.render(p))
        # Since then (issue 39 item 5) a beam with an azimuth pattern hears the pattern's
        # equivalent width of the floor, not the beam's spacing: the sensed scene's image (linear
        # output) is the earlier one times that ratio, the same for every beam here.
        factor = 1.0
        if name == "sensed":
            model = r._sensor.model
            ratio = model.column_factor / np.radians(model.sonar.effective_beam_width_deg())
            np.testing.assert_allclose(ratio, ratio[0], rtol=1e-6)
            factor = float(ratio[0])
            assert factor == pytest.approx(model.azimuth_gain, rel=1e-6) and factor > 1.1
        ref = before[f"{name}/image"] * factor
        assert image.any()
        np.testing.assert_allclose(image, ref, rtol=1e-6 if factor != 1.0 else 1e-12, atol=1e-13 * np.abs(ref).max())
        w = jnp.asarray(smooth_weights(image.shape))
        g = jax.grad(lambda q: jnp.sum(w * r.render(q)))(p)
        for k, v in g.items():
            if k == "sensor.azimuth_width_deg" and factor != 1.0:
                continue  # the column now grows with the width too (tests/diff/test_gradients.py)
            ref = before[f"{name}/grad/{k}"] * factor
            np.testing.assert_allclose(np.asarray(v), ref, rtol=1e-9 if factor == 1.0 else 1e-6,
                                       atol=1e-9 * max(np.abs(ref).max(), 1e-300), err_msg=f"{name}: {k}")


def test_collapsed_triangles_and_a_zero_scale_contribute_nothing_and_stay_finite(sensed):
    r, image, grad = sensed
    p = r.params()
    base = np.asarray(image(p, r.data))
    v = np.asarray(p["objects.box.vertices_m"])
    collapsed = {**p, "objects.box.vertices_m": jnp.broadcast_to(jnp.asarray(v[0]), v.shape)}  # every triangle
    zero_scale = {**p, "objects.box.scale": jnp.zeros(3)}
    no_box = {**p, "objects.box.albedo": jnp.zeros(())}  # the box's paths without energy
    without = np.asarray(image(no_box, r.data))
    assert np.abs(base - without).max() > 1e-3 * np.abs(base).max()  # the box shows
    for q in (collapsed, zero_scale):
        out = np.asarray(image(q, r.data))
        assert np.isfinite(out).all()
        np.testing.assert_allclose(out, without, rtol=1e-9, atol=1e-12 * np.abs(base).max())
        g = grad(q, r.data)
        assert finite(g)
        assert np.abs(np.asarray(g["objects.box.scale"])).max() == 0.0  # nothing of the box is left
        assert np.abs(np.asarray(g["sonar.position_m"])).max() > 0  # the rest still differentiates


def test_one_collapsed_triangle_leaves_its_paths_without_energy_and_the_rest_alone(sensed):
    """A triangle whose corners meet (a NaN column of the image before): its paths have no
    energy, every other path is as it was, image and gradients finite."""
    r, image, grad = sensed
    p = r.params()
    n_planes = len(r.static.planes)
    surface = np.asarray(r.data["surface"])[: r.search.n_paths]
    face_object = np.asarray(r.data["face_object"])
    rows = [k for k in np.unique(surface[surface >= n_planes] - n_planes) if face_object[k] == 0]
    row = rows[0]
    corners = np.asarray(r.data["faces"])[row]
    v = np.asarray(p["objects.box.vertices_m"]).copy()
    v[corners[1]] = v[corners[2]] = v[corners[0]]
    q = {**p, "objects.box.vertices_m": jnp.asarray(v)}
    before = r.paths(p)
    with pytest.warns(sd.StaleSearchWarning, match="object 'box' moved"):  # its corner moved 0.4 m
        after = r.paths(q)
    on = surface == n_planes + row
    e0, e1 = np.asarray(before["energy"]), np.asarray(after["energy"])
    assert on.any() and e0[on].max() > 0
    assert np.isfinite(e1).all() and np.isfinite(np.asarray(after["distance"])).all()
    assert (e1[on] == 0).all()
    # Triangles sharing a corner moved with it; the ground's paths are exactly as they were.
    ground = surface == 0
    np.testing.assert_array_equal(e1[ground], e0[ground])
    assert np.isfinite(np.asarray(image(q, r.data))).all()
    assert finite(grad(q, r.data))


def test_a_zero_width_receives_nothing_and_stays_finite(sensed):
    r, image, grad = sensed
    p = r.params()
    base = np.asarray(image(p, r.data))
    for key in ("sensor.elevation_width_deg", "sensor.azimuth_width_deg"):
        zero, tiny = {**p, key: jnp.zeros(())}, {**p, key: jnp.asarray(1e-6)}
        out = np.asarray(image(zero, r.data))
        assert np.isfinite(out).all(), key
        # The limit of a vanishing width: an elevation beam that receives nothing (its rays'
        # span, and so their weights, shrink with it), an azimuth beam that leaks into no other.
        np.testing.assert_allclose(out, np.asarray(image(tiny, r.data)), rtol=1e-12,
                                   atol=1e-6 * np.abs(base).max() if "elevation" in key else 0.0, err_msg=key)
        assert finite(grad(zero, r.data)), key
    zero = {**p, "sensor.elevation_width_deg": jnp.zeros(())}
    floor = {**p, "objects.box.albedo": jnp.zeros(()), "objects.ball.albedo": jnp.zeros(()),
             "objects.ball.specular_strength": jnp.zeros(()), "planes.ground.albedo": jnp.zeros(())}
    np.testing.assert_allclose(np.asarray(image(zero, r.data)), np.asarray(image(floor, r.data)), rtol=1e-12)


def test_nan_inside_jit_is_the_callers_and_is_documented(sensed):
    """Inside ``jit`` the values are abstract: a NaN given there is not refused (it cannot be
    seen), and the image shows it; the docstring of render says where values are checked."""
    r, image, _ = sensed
    p = r.params()
    out = np.asarray(image({**p, "sonar.position_m": p["sonar.position_m"].at[0].set(jnp.nan)}, r.data))
    assert np.isnan(out).any()
    assert "jit" in sd.Renderer.render.__doc__ and "concrete" in sd.Renderer.render.__doc__


# Item 4: far from the held search ----------------------------------------------------------

def test_a_sonar_moved_far_without_refresh_warns_how_far_and_what_refresh_does(sensed):
    r, _, _ = sensed
    p = r.params()
    r.refresh()
    near = {**p, "sonar.position_m": p["sonar.position_m"] + jnp.asarray([0.01, 0.0, 0.0])}
    with warnings.catch_warnings():
        warnings.simplefilter("error", sd.StaleSearchWarning)
        r.render(near)  # 1 cm: within 0.4 m (a tenth of the 4 m window)
    far = {**p, "sonar.position_m": p["sonar.position_m"] + jnp.asarray([500.0, 0.0, 0.0])}
    with pytest.warns(sd.StaleSearchWarning, match=r"the sonar moved 500 m .* beyond 0.4 m.*refresh\(params\)"):
        r.render(far)
    with warnings.catch_warnings():  # once per held search, not once per render of a loop
        warnings.simplefilter("error", sd.StaleSearchWarning)
        r.render(far)
    r.refresh(far)
    with warnings.catch_warnings():  # refreshed there: nothing stale
        warnings.simplefilter("error", sd.StaleSearchWarning)
        r.render(far)
    turned = {**p, "sonar.rpy_deg": p["sonar.rpy_deg"] + jnp.asarray([0.0, 0.0, 10.0])}
    r.refresh()
    with pytest.warns(sd.StaleSearchWarning, match=r"turned 10 degrees .* beyond .* 2 degrees"):
        r.render(turned)
    r.refresh()


def test_an_object_moved_beyond_half_its_size_warns(sensed):
    r, _, _ = sensed
    p = r.params()
    r.refresh()
    assert r.distance_from_search({"objects.ball.position_m": p["objects.ball.position_m"] + 0.05}) == ""
    moved = {"objects.ball.position_m": p["objects.ball.position_m"] + jnp.asarray([0.0, 0.3, 0.0])}
    assert "object 'ball' moved 0.3 m" in r.distance_from_search(moved)
    assert "object 'ball'" in r.distance_from_search({"objects.ball.scale": jnp.full(3, 3.0)})
    assert "plane 'ground'" in r.distance_from_search({"planes.ground.offset_m": jnp.asarray(-1.0)})
    with pytest.warns(sd.StaleSearchWarning, match="object 'ball'"):
        r.render(moved)
    r.refresh()
    # Inside jit nothing is concrete: nothing to say (and nothing raised).
    assert jax.jit(lambda q: jnp.asarray(len(r.distance_from_search(q))))(moved) == 0


def test_an_object_posed_beyond_the_scenes_extent_is_refused_as_the_scene_format_refuses_its_mesh(sensed):
    """Each coordinate within 1e6 m, yet the box's vertices, posed, reach beyond it: refused by
    the key that moved it (render and refresh), as the scene format refuses such a mesh."""
    r, _, _ = sensed
    edge = {"objects.box.position_m": jnp.asarray([1e6 - 0.1, 0.0, 0.0])}  # the box is 0.4 m wide
    with pytest.raises(ConfigError, match=r"^objects.box.position_m: the vertices of object 'box', scaled and "
                                          r"posed, reach 1e\+06 m .* within \[-1e\+06, 1e\+06\] m"):
        r.render(edge)
    with pytest.raises(ConfigError, match="objects.box.position_m: the vertices of object 'box'"):
        r.refresh(edge)
    assert r.distance_from_search({"objects.box.position_m": jnp.asarray([1e6 - 1.0, 0.0, 0.0])})  # within: far only


def test_check_params_refuses_what_render_refuses_without_rendering_or_warning(sensed):
    r, _, _ = sensed
    p = r.params()
    far = {**p, "sonar.position_m": p["sonar.position_m"] + jnp.asarray([500.0, 0.0, 0.0])}
    with warnings.catch_warnings():
        warnings.simplefilter("error", sd.StaleSearchWarning)
        r.check_params(far)  # a fit's start, before its first refresh: nothing to say
    with pytest.raises(ConfigError, match=r"^objects.box.albedo: must be finite, within \[0, 1\]"):
        r.check_params({"objects.box.albedo": jnp.asarray(2.0)})
