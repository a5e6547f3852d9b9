"""The differentiable engine on mesh mirrors (issue 25, item 5): its forward equals the compiled
engine's on scenes with mirroring objects, and its gradients with respect to a mirror's pose,
vertices and reflectance pass the finite-difference check against the compiled engine."""

from __future__ import annotations

import numpy as np
import pytest

jax = pytest.importorskip("jax")
jnp = pytest.importorskip("jax.numpy")

import sonarsim.diff as sd  # noqa: E402
from sonarsim.diff import check  # noqa: E402
from sonarsim.errors import ConfigError  # noqa: E402
from sonarsim.paths.engine import parse_path_name  # noqa: E402
from sonarsim.renderer.simulator import Simulator  # noqa: E402
from tests.diff.test_gradients import SONAR, assert_checked  # noqa: E402
from tests.paths.test_mesh_mirrors import mirror_tank, wall_scene  # noqa: E402


def rel_l1(a, b) -> float:
    a, b = np.asarray(a, float), np.asarray(b, float)
    return float(np.abs(a - b).sum() / np.abs(b).sum())


@pytest.mark.parametrize("name,doc", [("tank, paper", mirror_tank(3, "paper")),
                                      ("tank, separate", mirror_tank(3, "separate")),
                                      ("wall as a box", wall_scene(True, 3))])
def test_the_forward_equals_the_compiled_engine_with_mesh_mirrors(name, doc):
    r = sd.Renderer(doc)
    with Simulator(doc) as sim:
        ref = sim.render(speckle=False)
    assert rel_l1(r.render(), ref.polar) < 1e-4, name
    mine = r.components()
    via_mirror = 0
    for k in ref.components.signatures:
        image = np.asarray(ref.components[k])
        assert rel_l1(mine[k], image) < 1e-3, (name, k)
        via_mirror += any(m in k for m in ("block", "plate", "wall"))
    assert via_mirror >= 5


def roof_scene(tmp_path) -> dict:
    """A tilted floor and, above the sonar, one large mirroring triangle (a hull's flat bottom,
    no diffuse part) that fills the fan, which looks 15 degrees up: the floor is seen only in
    the mirror, along paths whose transmit leg is the receive leg reversed. No edge is in
    view, and no leg ends at an edge of the window or the aperture, where a path would come
    and go with a step (the held search's documented blind spot)."""
    return {"sonar": {**SONAR, "elevation_fov_deg": 30.0, "range_max_m": 8.0, "n_range_bins": 600,
                      "pose": {"position_m": [0.0, 0.0, 0.5], "rpy_deg": [2.0, -15.5, 3.0]}},
            "render": {"max_order": 3, "elevation_samples": 96},
            "planes": [{"name": "bed", "point_m": [0, 0, 0.0], "normal": [0.03, -0.02, 1.0], "albedo": 0.5,
                        "specular": 0.6}],
            "objects": [{"name": "roof", "mesh": _roof_mesh(tmp_path), "pose": {"position_m": [0.0, 0.0, 1.0],
                                                                                "rpy_deg": [0.5, 0.4, 2.0]},
                         "albedo": 0.0, "specular": 0.8}]}


def _roof_mesh(tmp_path) -> str:
    # One triangle, 45 m across.
    path = tmp_path / "roof.obj"
    path.write_text("v -5 -30 0\nv 40 0 0\nv -5 30 0\nf 1 2 3\n")
    return str(path)


def test_a_mirrors_pose_vertices_and_reflectance_against_the_compiled_engine(tmp_path):
    r = sd.Renderer(roof_scene(tmp_path))
    assert set(r.search.signatures) == {"O-roof-[bed]-roof-O"}
    keys = ["objects.roof.position_m", "objects.roof.rpy_deg", "objects.roof.vertices_m", "objects.roof.specular",
            "planes.bed.offset_m", "planes.bed.normal"]
    rows = check.check_gradients(r, keys)
    assert_checked(rows, keys)
    assert all(r.reference == "compiled" for r in rows)


def test_transmit_legs_across_mesh_mirrors_against_the_held_forward():
    """The image sources across a mirror's facets (transmit legs by other chains than the
    receive leg's), checked against the held forward's differences: the tank's block and
    plate, both mirrors, moved, turned and deformed."""
    doc = mirror_tank(3, "separate")
    doc["render"]["range_splat"] = True  # (the reference's scenes put each path in one bin: no derivative)
    r = sd.Renderer(doc)
    # Signatures whose transmit leg meets a mirror and is not the receive leg reversed.
    tx_mirrors = {m for k in r.search.signatures for m in ("block", "plate")
                  if m in parse_path_name(k)[0] and parse_path_name(k)[0] != parse_path_name(k)[2]}
    assert tx_mirrors == {"block", "plate"}
    keys = [f"objects.{m}.{p}" for m in ("block", "plate") for p in ("position_m", "rpy_deg", "specular")]
    rows = check.check_gradients(r, keys, reference="held")
    # The vertices along three random directions, each judged against the largest of the
    # three, as a vector's components are (one direction nearly across the gradient would be
    # judged by the isolated paths' straight-through derivative alone, which a difference of
    # the held forward does not see).
    vertices = [f"objects.{m}.vertices_m" for m in ("block", "plate")]
    for seed in range(3):
        rows += check.check_gradients(r, vertices, reference="held", seed=seed)
    assert_checked(rows, keys + vertices)


@pytest.mark.parametrize("edit,key", [({"render": {"glints": True}}, "render.glints"),
                                      ({"normals": "smooth"}, "objects[0].normals")])
def test_what_the_differentiable_engine_does_not_cover_is_refused_by_name(edit, key, tmp_path):
    doc = roof_scene(tmp_path)
    if "render" in edit:
        doc["render"].update(edit["render"])
    else:
        doc["objects"][0].update(edit)
    with pytest.raises(ConfigError) as err:
        sd.Renderer(doc)
    assert key in str(err.value)
