"""Scenarios: loading and its errors, frames as a pure function of (scenario, k) in any order
and any process, the per-frame seeds, and the renders they give."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim.dataset import FrameSpec, Scenario, load_scenario
from sonarsim.dataset.scenario import frame_seed
from sonarsim.errors import ConfigError, SonarsimError

SONAR = {"n_beams": 16, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 14.0, "range_min_m": 0.5,
         "range_max_m": 5.0, "n_range_bins": 120}
SCENE = {
    "sonar": {**SONAR, "pose": {"position_m": [0, 0, 1], "rpy_deg": [0, 20, 0]}},
    "render": {"elevation_samples": 8, "seed": 999},
    "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
    "objects": [{"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.3],
                 "pose": {"position_m": [2.5, 0, 0.15]}}],
}
VARIED = {
    "scene": SCENE,
    "seed": 11,
    "trajectory": {"generate": {"kind": "random", "frames": 12, "bounds_m": [[-1, -1, 0.8], [0, 1, 1.2]],
                                "look_at_bounds_m": [[2.3, -0.2, 0.0], [2.7, 0.2, 0.3]], "jitter_deg": [2, 4]}},
    "variation": {
        "objects": [{"name": "rock", "count": {"randint": [1, 3]},
                     "pool": [{"primitive": "sphere", "radius_m": {"uniform": [0.05, 0.15]}},
                              {"primitive": "box", "size_m": [0.2, 0.2, 0.1]}],
                     "pose": {"position_m": [{"uniform": [1.5, 3.5]}, {"uniform": [-0.8, 0.8]}, 0.1]},
                     "albedo": {"uniform": [0.3, 0.9]}}],
        "ground": {"albedo": {"uniform": [0.3, 0.6]}},
    },
}


def frame_json(f: FrameSpec) -> str:
    """Everything a frame holds, as text (exact floats), for comparing across processes."""
    return json.dumps({"index": f.index, "seed": f.seed, "time_s": f.time_s, "pose": f.pose.matrix().tolist(),
                       "scene": f.scene, "base_dir": f.base_dir}, sort_keys=True)


# Frames are pure functions of (scenario, k) -------------------------------------------

def test_frames_in_reverse_order_equal_frames_in_order():
    s = load_scenario(VARIED)
    forward = [s.frame(k) for k in range(s.n_frames)]
    backward = [s.frame(k) for k in reversed(range(s.n_frames))][::-1]
    assert forward == backward
    assert [frame_json(f) for f in forward] == [frame_json(f) for f in load_scenario(VARIED).frame_specs()]


def test_frames_in_a_fresh_process_are_the_same(tmp_path):
    path = tmp_path / "scenario.yaml"
    path.write_text(yaml.safe_dump(VARIED))
    s = load_scenario(path)
    picks = [7, 0, 11, 3]
    code = textwrap.dedent(f"""
        import json, sys
        sys.path.insert(0, {str(__import__('pathlib').Path(__file__).parent)!r})
        from test_scenario import frame_json
        from sonarsim.dataset import load_scenario
        s = load_scenario({str(path)!r})
        print(json.dumps([frame_json(s.frame(k)) for k in {picks!r}]))
    """)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert json.loads(out.stdout) == [frame_json(s.frame(k)) for k in picks]


def test_different_frames_and_seeds_differ():
    s = load_scenario(VARIED)
    frames = list(s.frame_specs())
    assert len({f.seed for f in frames}) == len(frames)
    assert len({f.pose for f in frames}) == len(frames)
    assert len({json.dumps(f.scene, sort_keys=True) for f in frames}) == len(frames)
    other = load_scenario({**VARIED, "seed": 12})
    assert all(other.frame(k).pose != frames[k].pose for k in range(len(frames)))


def test_frame_seed_is_seedsequence_of_seed_and_index():
    word = np.random.SeedSequence([11, 5]).generate_state(1, np.uint64)[0]
    assert frame_seed(11, 5) == int(word) & (2**63 - 1)
    f = load_scenario(VARIED).frame(5)
    assert f.seed == frame_seed(11, 5)
    # The frame's draws come from default_rng(seed): the random pose first.
    rng = np.random.default_rng(f.seed)
    position = rng.uniform([-1, -1, 0.8], [0, 1, 1.2])
    np.testing.assert_allclose(f.pose.position_m, position)


def test_the_scenario_seed_becomes_the_render_seed_and_static_frames_share_a_document():
    s = load_scenario({"scene": SCENE, "seed": 4, "trajectory": {"generate": {
        "kind": "orbit", "centre_m": [2.5, 0, 0.15], "radius_m": 2.0, "z_m": 1.0, "frames": 6}}})
    assert s.scene["render"]["seed"] == 4 and SCENE["render"]["seed"] == 999
    frames = list(s.frame_specs())
    assert len({f.scene_key for f in frames}) == 1
    assert len({f.pose for f in frames}) == 6
    assert frames[2].time_s == 2.0
    varied = load_scenario(VARIED)
    assert varied.frame(0).scene_key != varied.frame(1).scene_key


def test_capping_keeps_the_frames():
    s = load_scenario(VARIED)
    c = load_scenario(VARIED, frames=5)
    assert (s.n_frames, c.n_frames, len(c), s.capped(100).n_frames) == (12, 5, 5, 12)
    assert [c.frame(k) for k in range(5)] == [s.frame(k) for k in range(5)]
    with pytest.raises(IndexError):
        c.frame(5)
    with pytest.raises(IndexError):
        s.frame(-1)
    for bad in (0, -3, 2.5, True):
        with pytest.raises(ConfigError, match="frames"):
            s.capped(bad)


# Renders ----------------------------------------------------------------------------

def test_a_frame_renders_the_same_alone_or_after_others():
    """Speckle and noise come from (seed, k): rendering frames 0-3 in order or frame 3 alone in
    a fresh simulator gives the same image."""
    doc = {**SCENE, "render": {**SCENE["render"], "speckle": True}}
    s = load_scenario({"scene": doc, "seed": 21, "trajectory": {"generate": {
        "kind": "orbit", "centre_m": [2.5, 0, 0.15], "radius_m": 2.0, "z_m": 1.0, "frames": 4, "sweep_deg": 40,
        "start_deg": 160}}})
    frames = list(s.frame_specs())
    with sonarsim.Simulator(frames[0].load_scene()) as sim:
        in_order = [f.render(sim, keep_rays=False).polar for f in frames]
    with sonarsim.Simulator(frames[3].scene) as sim:
        alone = frames[3].render(sim, keep_rays=False).polar
    np.testing.assert_array_equal(alone, in_order[3])
    assert in_order[3].max() > 0
    assert not np.array_equal(in_order[2], in_order[3])


def test_a_frames_scene_holds_its_objects_and_pose():
    s = load_scenario(VARIED)
    f = s.frame(2)
    scene = f.load_scene()
    assert scene.sonar_pose == f.pose
    names = [o.name for o in scene.objects]
    assert names[0] == "block" and all(n.startswith("rock_") for n in names[1:]) and len(names) >= 2
    assert 0.3 <= scene.ground.albedo < 0.6
    with sonarsim.Simulator(scene) as sim:
        image = f.render(sim, keep_rays=True)
    # Rays hit the varied rocks (surface ids: ground plane 0, then the objects in order).
    ids = np.unique(image.rays.surface_id)
    assert set(range(2, len(names) + 1)) & set(ids.tolist())


# Files and paths ----------------------------------------------------------------------

def test_paths_are_relative_to_the_scenario_file(tmp_path):
    import trimesh

    (tmp_path / "scenes").mkdir()
    (tmp_path / "scenes" / "s.yaml").write_text(yaml.safe_dump(SCENE))
    (tmp_path / "meshes").mkdir()
    trimesh.creation.icosphere(subdivisions=1, radius=0.2).export(tmp_path / "meshes" / "rock.obj")
    (tmp_path / "track.csv").write_text("t,x,y,z,roll_deg,pitch_deg,yaw_deg\n0,0,0,1,0,20,0\n2,1,0,1,0,20,0\n")
    (tmp_path / "sc.yaml").write_text(yaml.safe_dump({
        "scene": "scenes/s.yaml", "seed": 0, "trajectory": {"file": "track.csv", "rate_hz": 2},
        "variation": {"objects": [{"pool": [{"mesh": "meshes/rock.obj"}],
                                   "pose": {"position_m": [2.0, 0.5, 0.2]}}]},
    }))
    s = load_scenario(tmp_path / "sc.yaml")
    assert s.n_frames == 5 and s.source == str(tmp_path / "sc.yaml")
    f = s.frame(1)
    np.testing.assert_allclose(f.pose.position_m, [0.25, 0, 1])
    assert f.scene["objects"][1]["mesh"] == str((tmp_path / "meshes" / "rock.obj").resolve())
    assert f.base_dir == str((tmp_path / "scenes").resolve())
    assert len(f.load_scene().objects) == 2


@pytest.mark.parametrize("doc, key", [
    ({**VARIED, "frames": 3}, "frames"),
    ({k: v for k, v in VARIED.items() if k != "seed"}, "seed"),
    ({k: v for k, v in VARIED.items() if k != "scene"}, "scene"),
    ({k: v for k, v in VARIED.items() if k != "trajectory"}, "trajectory"),
    ({**VARIED, "seed": -1}, "seed"),
    ({**VARIED, "seed": 1.5}, "seed"),
    ({**VARIED, "seed": True}, "seed"),
    ({**VARIED, "seed": 2**130}, "seed"),
    ({**VARIED, "trajectory": [1, 2]}, "trajectory"),
    ({**VARIED, "scene": 3}, "scene"),
    ({**VARIED, "scene": "missing.yaml"}, "scene"),
    ({**VARIED, "scene": {**SCENE, "ground": {"albedo": 2.0}}}, "scene.ground.albedo"),
    ({**VARIED, "scene": {**SCENE, "render": [1]}}, "scene.render"),
    ({**VARIED, "description": 5}, "description"),
    ({**VARIED, "start_time": "yesterday"}, "start_time"),
    ({**VARIED, "start_time": 0}, "start_time"),  # tf2's "latest", not a time
    ({**VARIED, "start_time": "2038-01-19T03:14:08Z"}, "start_time"),  # past int32 seconds
    ({**VARIED, "start_time": True}, "start_time"),
    ({**VARIED, "start_time": [2024, 5, 1]}, "start_time"),
    # Variations whose extremes make invalid scenes: the key in the scenario is named.
    ({**VARIED, "variation": {"ground": {"albedo": {"uniform": [0.5, 1.5]}}}}, "variation.ground.albedo"),
    ({**VARIED, "variation": {"objects": [{"pool": [{"primitive": "sphere", "radius_m": {"uniform": [-0.1, 0.1]}}]}]}},
     "variation.objects[0].pool[0].radius_m"),
    ({**VARIED, "variation": {"objects": [{"pool": [{"primitive": "sphere", "radius_m": 0.1},
                                                    {"primitive": "cone"}]}]}},
     "variation.objects[0].pool[1].primitive"),
    ({**VARIED, "variation": {"objects": [{"count": 1, "pool": [{"primitive": "sphere", "radius_m": 0.1},
                                                                {"primitive": "sphere", "radius_m": 0.1, "albedo": 7},
                                                                {"primitive": "sphere", "radius_m": 0.2}]}]}},
     "variation.objects[0].pool[1].albedo"),
    ({**VARIED, "variation": {"objects": [{"pool": [{"mesh": "nowhere.obj"}]}]}}, "variation.objects[0].pool[0].mesh"),
    ({**VARIED, "scene": {**SCENE, "objects": [{**SCENE["objects"][0], "name": "rock_0"}]},
      "variation": {"objects": [{"name": "rock", "pool": [{"primitive": "sphere", "radius_m": 0.1}]}]}},
     "variation.objects[0].name"),
])
def test_bad_scenarios_name_the_key(doc, key):
    with pytest.raises(ConfigError) as info:
        load_scenario(doc)
    assert info.value.key == key, str(info.value)


def test_errors_in_files_name_the_file(tmp_path):
    f = tmp_path / "sc.yaml"
    f.write_text(yaml.safe_dump({**VARIED, "seed": -1}))
    with pytest.raises(ConfigError, match=r"sc\.yaml: seed: must be") as info:
        load_scenario(f)
    assert info.value.source == str(f)
    f.write_text("")
    with pytest.raises(ConfigError, match="empty"):
        load_scenario(f)
    with pytest.raises(SonarsimError, match="is a directory"):
        load_scenario(tmp_path)
    f.write_text("seed: [1\n")
    with pytest.raises(SonarsimError, match="invalid YAML at line"):
        load_scenario(f)
    (tmp_path / "dir.csv").mkdir()
    f.write_text(yaml.safe_dump({"scene": SCENE, "seed": 0, "trajectory": {"file": "dir.csv"}}))
    with pytest.raises(ConfigError, match="is a directory") as info:
        load_scenario(f)
    assert info.value.key == "trajectory.file"


def test_start_time_key_in_every_form_a_scenario_file_may_hold_it(tmp_path):
    # ISO 8601 text (quoted), YAML's own timestamp (unquoted: a datetime), a date, seconds.
    noon = 1_714_564_800 * 10**9  # 2024-05-01T12:00:00Z
    for text, expected in (("'2024-05-01T12:00:00Z'", noon), ("2024-05-01T12:00:00Z", noon),
                           ("2024-05-01T14:00:00+02:00", noon), ("2024-05-01 12:00:00", noon),
                           ("2024-05-01", noon - 12 * 3600 * 10**9), ("1714564800.25", noon + 250_000_000)):
        f = tmp_path / "sc.yaml"
        f.write_text(yaml.safe_dump(VARIED) + f"start_time: {text}\n")
        assert load_scenario(f).start_time_ns == expected, text
    assert load_scenario(VARIED).start_time_ns is None  # the bag's default, not the clock
    f.write_text(yaml.safe_dump(VARIED) + "start_time: soon\n")
    with pytest.raises(ConfigError, match=r"sc\.yaml: start_time: must be an ISO 8601 time") as info:
        load_scenario(f)
    assert "\n" not in str(info.value) and "'soon'" in str(info.value)


def test_a_scenario_object_is_frozen():
    s = load_scenario(VARIED)
    assert isinstance(s, Scenario)
    with pytest.raises(AttributeError):
        s.seed = 3


def test_scenarios_and_frames_travel_to_workers():
    """Workers (processes, Ray) receive the scenario or its frames pickled; a frame's scene
    document is plain data (it survives YAML and JSON unchanged)."""
    import pickle

    for doc in (VARIED, {**VARIED, "trajectory": {"generate": {
            "kind": "orbit", "centre_m": [2.5, 0, 0.15], "radius_m": 2.0, "z_m": 1.0, "frames": 5}}}):
        s = load_scenario(doc)
        copy = pickle.loads(pickle.dumps(s))
        assert [copy.frame(k) for k in range(s.n_frames)] == list(s.frame_specs())
        f = s.frame(3)
        assert pickle.loads(pickle.dumps(f)) == f
        assert yaml.safe_load(yaml.safe_dump(f.scene)) == f.scene
        assert json.loads(json.dumps(f.scene)) == f.scene


def test_another_seed_changes_every_draw_and_the_renderers_seed():
    from tests.dataset.test_examples import EXAMPLES

    sc = load_scenario(EXAMPLES / "orbit_tank.yaml")
    other = sc.with_seed(sc.seed + 1)
    assert other.seed == sc.seed + 1 and other.scene["render"]["seed"] == sc.seed + 1
    assert sc.scene["render"]["seed"] == sc.seed  # the original is untouched
    assert other.frame(3).seed != sc.frame(3).seed
    assert other.frame(3).scene["ground"]["albedo"] != sc.frame(3).scene["ground"]["albedo"]
    for bad in (-1, 2**128, 1.5, True):
        with pytest.raises(ConfigError, match="seed"):
            sc.with_seed(bad)
