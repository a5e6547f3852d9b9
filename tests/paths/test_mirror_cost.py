"""What mesh mirrors cost is estimated and checked against the budgets (issue 37): the mirror
tables' build, the legs of high orders before the frame, the path-signature images before
they are formed; a refusal is one line naming ``render.max_order`` (or ``objects``) with the
estimate, and nothing is written."""

from __future__ import annotations

import copy

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim.cli.main import main
from sonarsim.core import memory
from sonarsim.errors import ConfigError
from sonarsim.renderer.simulator import require_frame_memory
from sonarsim.scene.cost import BYTES_PER_LEG_RAY, LEGS_IN_RAY_BYTES, SECONDS_PER_MIRROR_TRIANGLE, leg_bytes, scene_cost


def mirror_boxes(n: int = 40, max_order: int = 4, glints: bool = True) -> dict:
    """``n`` small tilted mirror boxes (R 0.8) in front of a far wall, under a water surface,
    on a floor: each box a named mirror, so the paths' signatures multiply with the order."""
    rng = np.random.default_rng(1)
    objects = [{"name": f"box{k}", "primitive": "box", "size_m": [0.1, 0.1, 0.1],
                "pose": {"position_m": [2.0 + 1.5 * rng.random(), -0.8 + 1.6 * rng.random(), 0.2 + 0.8 * rng.random()],
                         "rpy_deg": (rng.random(3) * 90).tolist()}, "albedo": 0.3, "specular": 0.8} for k in range(n)]
    return {"sonar": {"n_beams": 32, "azimuth_fov_deg": 40.0, "elevation_fov_deg": 20.0, "range_min_m": 0.5,
                      "range_max_m": 5.0, "n_range_bins": 200, "pose": {"position_m": [0, 0, 0.6], "rpy_deg": [0, 5, 0]}},
            "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
            "planes": [{"name": "far_wall", "point_m": [4.5, 0, 0], "normal": [-1, 0, 0], "albedo": 0.5, "specular": 0.6},
                       {"name": "surface", "point_m": [0, 0, 1.5], "normal": [0, 0, -1], "albedo": 0.0, "specular": 0.9}],
            "render": {"max_order": max_order, "glints": glints, "elevation_samples": 64}, "objects": objects}


@pytest.fixture
def budget():
    yield memory.set_memory_budget
    memory.set_memory_budget(None)
    memory.set_time_budget(None)


def test_the_signature_images_are_checked_before_they_are_formed(budget):
    image = sonarsim.Simulator(mirror_boxes()).render(speckle=False)
    n = len(image.components.signatures)  # (formed within the default budget)
    assert n > 150
    budget(3 * 2**20)  # the frame fits; its 200 x 32 images of every signature (6 MB) do not
    image = sonarsim.Simulator(mirror_boxes()).render(speckle=False)
    with pytest.raises(ConfigError) as err:
        image.components.signatures
    assert err.value.key == "render.max_order"
    assert "path signatures (200 x 32; mirrors at max_order 4) would need" in str(err.value)


def test_render_refuses_the_signature_images_in_one_line_writing_nothing(tmp_path, capsys):
    scene = tmp_path / "boxes.yaml"
    scene.write_text(yaml.safe_dump(mirror_boxes()))
    out = tmp_path / "out"
    code = main(["--max-memory", "3M", "render", str(scene), "--out", str(out), "--components", "--no-figures",
                 "--pixel-size", "0.05"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and [line for line in err if "error" in line] == err[-1:], err
    assert "render.max_order" in err[-1] and "path signatures" in err[-1] and "--max-memory" in err[-1]
    assert not out.exists() or not [p for p in out.iterdir() if p.name != "sonarsim-run.json"]


def test_the_legs_of_high_orders_count_in_the_frame_estimate(budget):
    scene = sonarsim.load_scene(mirror_boxes(4, max_order=3, glints=False))
    deep = sonarsim.load_scene({**mirror_boxes(4), "render": {"max_order": 8, "glints": True, "elevation_samples": 1024}})
    n_rays = 32 * 1024
    assert leg_bytes(n_rays, 8, True) == n_rays * (9 - LEGS_IN_RAY_BYTES) * BYTES_PER_LEG_RAY
    assert leg_bytes(n_rays, 3, False) == 0.0
    budget(40 * 2**20)  # rays 20 MB, legs of 9 generations 29 MB: each fits, not together
    require_frame_memory(scene, scene.sonar)
    with pytest.raises(ConfigError) as err:
        require_frame_memory(deep, deep.sonar)
    assert err.value.key == "render.max_order" and "path legs (9 generations)" in str(err.value)


def test_mirror_triangles_cost_build_time(budget):
    doc = mirror_boxes(4)
    plain = copy.deepcopy(doc)
    for obj in plain["objects"]:
        obj["specular"] = 0.0
    a, b = scene_cost(sonarsim.load_scene(doc)), scene_cost(sonarsim.load_scene(plain))
    assert a.seconds - b.seconds == pytest.approx(48 * SECONDS_PER_MIRROR_TRIANGLE)
    assert a.bytes > b.bytes


@pytest.mark.parametrize("double_beam", ["paper", "separate"])
def test_the_smooth_mirrors_partners_are_those_of_the_definition(double_beam, monkeypatch):
    """The reciprocal pairs of a smooth mirror's chains come from an index of the flat chains by
    length (it scanned every chain per smooth chain: a sphere of 82k smooth facets took 8 s a
    frame, flat 0.2 s): each call during a frame gives the chains the definition names."""
    from sonarsim.paths import engine

    calls = []
    original = engine.partner_chains

    def recorded(table, g, tx, rank, beam):
        out = original(table, g, tx, rank, beam)
        calls.append((table, g, tx, np.array(rank), beam, out))
        return out

    monkeypatch.setattr(engine, "partner_chains", recorded)
    doc = mirror_boxes(6, max_order=3, glints=False)
    doc["render"]["double_beam"] = double_beam
    for obj in doc["objects"][:3]:
        obj["normals"] = "smooth"
    sonarsim.Simulator(doc).render(speckle=False)
    assert len(calls) > 10 and sum(len(c[-1]) for c in calls) > 10
    for table, g, tx, rank, beam, out in calls:
        expected = [c for c in range(len(table)) if c != tx and table.length(c) == g and table.flat(c)
                    and (beam == "separate" or rank[c] > rank[tx])]
        assert out == expected


def test_a_frame_of_many_transmit_options_lays_its_path_buffer_out_within_a_small_budget(budget):
    """Regression (mirror fuzz, seed 0, case 165: 20 objects, 16 of them mirrors, three planes,
    order 4, 672 rays): the path buffer was laid out for every candidate up to 64 MiB whatever
    the budget, and the frame peaked at 68 MiB under a 64 MiB budget; past an eighth of the
    budget the paths are counted first (2 MiB)."""
    import tracemalloc

    from tests.fuzz.mirrors import generate_mirror_cases

    case = list(generate_mirror_cases(166, 0))[165]
    budget(64 * 2**20)
    sim = sonarsim.Simulator(case.doc)
    tracemalloc.start()
    try:
        image = sim.render(speckle=False, keep_rays=False)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert image.components["order4"].any() and peak < 16 * 2**20


def test_the_paths_candidates_are_checked_against_the_time_budget(budget, monkeypatch):
    """Each live ray of a generation is a candidate of each of its transmit options: known once
    the frame's chains are, and checked before the paths are formed."""
    from sonarsim.renderer import compiled

    memory.set_time_budget(1.0)
    image = sonarsim.Simulator(mirror_boxes()).render(speckle=False)  # well within a second's estimate
    assert image.components["order4"].any()
    monkeypatch.setattr(compiled, "SECONDS_PER_CANDIDATE", 1.0)
    with pytest.raises(ConfigError) as err:
        sonarsim.Simulator(mirror_boxes()).render(speckle=False)
    assert err.value.key == "render.max_order"
    assert "forming the frame's paths (" in str(err.value) and "candidates of" in str(err.value)
    assert "--max-build-time" in str(err.value)
