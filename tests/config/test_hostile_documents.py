"""Hostile scene documents (issue 11): each ends in one clear error naming the file or key."""

from __future__ import annotations

import numpy as np
import pytest

import sonarsim
from sonarsim.cli.main import main
from sonarsim.config.loader import MAX_SCENE_BYTES, read_document
from sonarsim.errors import ConfigError, SonarsimError


@pytest.mark.parametrize("name, content, message", [
    ("dup.yaml", "sonar: {n_beams: 4}\nground: {}\nsonar: {n_beams: 8}\n", "'sonar' is given twice"),
    ("dupinner.yaml", "sonar: {n_beams: 4, n_beams: 8}\n", "'n_beams' is given twice"),
    ("dup.json", '{"sonar": {}, "sonar": {}}', "'sonar' is given twice"),
    ("latin1.yaml", "sonar: {name: caf\xe9}\n".encode("latin-1"), "not UTF-8"),
    ("binary.yaml", bytes(range(256)), "not UTF-8"),
    ("deep.yaml", "a: " + "[" * 20000 + "]" * 20000 + "\n", "nested too deeply"),
    ("deep.json", '{"a": ' + "[" * 100000 + "]" * 100000 + "}", "nested too deeply"),
])
def test_malformed_documents_name_the_file_and_the_problem(tmp_path, name, content, message):
    p = tmp_path / name
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    with pytest.raises(SonarsimError, match=message) as e:
        read_document(p)
    assert str(p) in str(e.value)


def test_directories_devices_and_huge_files_are_not_scene_files(tmp_path):
    with pytest.raises(SonarsimError, match="is a directory"):
        read_document(tmp_path)
    with pytest.raises(SonarsimError, match="not a regular file"):
        read_document("/dev/zero")
    big = tmp_path / "big.yaml"
    with open(big, "wb") as f:
        f.truncate(MAX_SCENE_BYTES + 1)
    with pytest.raises(SonarsimError, match="is not a scene file"):
        read_document(big)


def test_the_cli_says_one_line_and_exits_2(tmp_path, capsys):
    p = tmp_path / "dup.yaml"
    p.write_text("sonar: {preset: aris3000-128}\nsonar: {preset: aris3000-64}\n")
    assert main(["render", str(p), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "given twice" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("value", [-5.0, 0.0, 1e9, float("inf")])
def test_impossible_frequencies_are_refused(value):
    with pytest.raises(ConfigError, match="sonar.frequency_khz"):
        sonarsim.load_scene({"sonar": {"preset": "aris3000-128", "frequency_khz": value}})


def test_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0 and capsys.readouterr().out.strip() == f"sonarsim {sonarsim.__version__}"


@pytest.mark.parametrize("where, value, key", [
    ("sonar_pose", {"position_m": [1e300, 0, 0]}, "sonar.pose.position_m"),
    ("sonar_pose", {"rpy_deg": [0, 1e300, 0]}, "sonar.pose.rpy_deg"),
    ("object", {"primitive": "sphere", "radius_m": 1e30}, "objects[0].radius_m"),
    ("object", {"primitive": "box", "size_m": [1, 1, 1e9]}, "objects[0].size_m"),
    ("object", {"primitive": "box", "size_m": [1, 1, 1], "scale": 1e12}, "objects[0].scale"),
    ("object", {"primitive": "box", "size_m": [1, 1, 1], "pose": {"position_m": [0, 0, 1e7]}},
     "objects[0].pose.position_m"),
])
def test_absurd_sizes_and_places_are_refused(where, value, key):
    doc = {"sonar": {"preset": "aris3000-128"}}
    if where == "sonar_pose":
        doc["sonar"]["pose"] = value
    else:
        doc["objects"] = [{"name": "o", **value}]
    with pytest.raises(ConfigError) as e:
        sonarsim.load_scene(doc)
    assert e.value.key == key


def test_mesh_files_that_are_not_meshes_say_so(tmp_path):
    import numpy as np
    from sonarsim.errors import MeshFileError
    from sonarsim.scene.meshes import load_mesh_file

    with pytest.raises(MeshFileError, match="is a directory"):
        load_mesh_file(tmp_path)
    with pytest.raises(MeshFileError, match="not a regular file"):
        load_mesh_file("/dev/zero")
    for suffix in (".stl", ".obj"):
        junk = tmp_path / f"junk{suffix}"
        junk.write_bytes(np.random.default_rng(0).bytes(4096))
        with pytest.raises(MeshFileError) as e:
            load_mesh_file(junk)
        assert str(junk) in str(e.value) and "charset" not in str(e.value)
    flat = tmp_path / "flat.obj"
    flat.write_text("v 1 1 1\nv 1 1 1\nv 1 1 1\nf 1 2 3\n")
    with pytest.raises(MeshFileError, match="degenerate"):
        load_mesh_file(flat)


@pytest.mark.parametrize("sonar, key", [
    ({"n_beams": 128, "azimuth_fov_deg": 30, "n_range_bins": 10**9}, "sonar.n_range_bins"),
    ({"n_beams": 128, "azimuth_fov_deg": 30, "range_resolution_m": 1e-9}, "sonar.n_range_bins"),
    ({"n_beams": 10**6, "azimuth_fov_deg": 30, "n_range_bins": 1000}, "sonar.n_range_bins"),
])
def test_sizes_beyond_the_memory_budget_are_refused_before_allocating(sonar, key):
    doc = {"sonar": {"elevation_fov_deg": 14, "range_min_m": 0.5, "range_max_m": 5.0, **sonar}}
    with pytest.raises(ConfigError, match="memory budget") as e:
        sonarsim.load_scene(doc)
    assert e.value.key == key


def test_ray_counts_and_fan_pixels_are_checked_against_the_budget():
    doc = {"sonar": {"preset": "aris3000-128"}, "render": {"elevation_samples": 10**9}}
    with pytest.raises(ConfigError, match="render.elevation_samples"):
        sonarsim.render(doc)
    img = sonarsim.render({"sonar": {"preset": "aris3000-128"}, "render": {"elevation_samples": 8}})
    with pytest.raises(ConfigError, match="pixel_size_m"):
        img.fan(pixel_size_m=1e-6)


def test_the_budget_can_be_raised_or_lowered(monkeypatch, capsys, tmp_path):
    from sonarsim.core import memory

    monkeypatch.setenv(memory.ENV_VAR, "2M")
    with pytest.raises(ConfigError, match="memory budget of"):
        sonarsim.load_scene({"sonar": {"preset": "aris3000-128"}})
    monkeypatch.delenv(memory.ENV_VAR)
    sonarsim.load_scene({"sonar": {"preset": "aris3000-128"}})
    scene = tmp_path / "s.yaml"
    scene.write_text("sonar: {preset: aris3000-128}\n")
    try:
        assert main(["--max-memory", "2M", "render", str(scene), "--out", str(tmp_path / "o")]) == 2
    finally:
        memory.set_memory_budget(None)
    assert "--max-memory" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["--max-memory", "lots", "presets"])


def test_beam_tables_that_are_devices_are_refused(tmp_path):
    with pytest.raises(ConfigError, match="directory or device"):
        sonarsim.load_scene({"sonar": {"n_beams": 4, "beam_angles_file": "/dev/zero", "elevation_fov_deg": 14,
                                       "range_min_m": 0.5, "range_max_m": 5, "n_range_bins": 100}})


def test_a_frames_images_rays_and_speckle_fields_must_fit_the_budget_together(monkeypatch):
    from sonarsim.core import memory

    doc = {"sonar": {"preset": "aris3000-128"}, "render": {"elevation_samples": 16, "azimuth_samples": 1},
           "sensor": {"preset": "aris3000-128"}}
    images = 1288 * 128 * 4 * 40                   # 40 float32 images of the frame
    rays = 128 * 1 * 16 * 600                      # 600 bytes per ray
    fields = 2 * 4 * 1288 * 4 * 128 + 3 * 1288 * 128 * 8  # speckle + noise pools, and one field being made
    assert images < 30 * 2**20 < images + rays + fields < 36 * 2**20
    monkeypatch.setenv(memory.ENV_VAR, "30M")     # each part fits alone, not all three
    with pytest.raises(ConfigError, match="at once") as e:
        sonarsim.render(doc)
    assert e.value.key == "sonar.n_range_bins"     # the largest part
    assert f"{(images + rays + fields) / 2**30:.3g} GiB" in str(e.value)
    monkeypatch.setenv(memory.ENV_VAR, "36M")
    assert sonarsim.render(doc).polar.shape == (1288, 128)


# Issue 21 item 3: no hang, no traceback, no silent nonsense ---------------------------------

SONAR = {"n_beams": 16, "azimuth_fov_deg": 30, "elevation_fov_deg": 14, "range_min_m": 0.5, "range_max_m": 5.0,
         "n_range_bins": 100}


@pytest.mark.parametrize("value", [1e308, 1e7, 10000.5])
def test_a_range_window_beyond_kilometres_is_refused(value, tmp_path):
    # range_max_m 1e308 rendered an axis ending in inf with every echo in row 0.
    with pytest.raises(ConfigError, match="at most 10000 metres") as e:
        sonarsim.load_scene({"sonar": {**SONAR, "range_max_m": value}})
    assert e.value.key == "sonar.range_max_m"
    p = tmp_path / "far.yaml"
    p.write_text(f"sonar: {{preset: aris3000-128, range_max_m: {value:.6e}}}\n")  # YAML 1.1 floats need the dot
    with pytest.raises(ConfigError) as e:
        sonarsim.load_scene(p)
    assert e.value.key == "sonar.range_max_m" and str(p) in str(e.value)


def test_the_longest_window_renders_finite_axes():
    img = sonarsim.render({"sonar": {**SONAR, "range_min_m": 9000.0, "range_max_m": 1e4, "n_range_bins": 50},
                           "render": {"elevation_samples": 4}})
    assert np.all(np.isfinite(img.range_m)) and img.range_m[-1] < 1e4


@pytest.mark.parametrize("sonar, key", [
    ({"range_min_m": 9999.99, "range_max_m": 1e4, "n_range_bins": 100_000}, "sonar.n_range_bins"),
    ({"range_min_m": 9999.99, "range_max_m": 1e4, "n_range_bins": None, "range_resolution_m": 1e-7},
     "sonar.range_resolution_m"),
])
def test_range_bins_finer_than_float32_ranges_are_refused(sonar, key):
    doc = {**SONAR, **sonar}
    if doc["n_range_bins"] is None:
        del doc["n_range_bins"]
    with pytest.raises(ConfigError, match="finer than float32 ranges") as e:
        sonarsim.load_scene({"sonar": doc})
    assert e.value.key == key


@pytest.mark.parametrize("resolution", [100.0, 4.5, 2.3])
def test_a_resolution_that_leaves_fewer_than_two_bins_is_refused(resolution):
    # 4.5 m over a 4.5 m window was a one-bin image.
    sonar = {k: v for k, v in SONAR.items() if k != "n_range_bins"}
    with pytest.raises(ConfigError, match=r"at most half the range window .*= 2.25 m") as e:
        sonarsim.load_scene({"sonar": {**sonar, "range_resolution_m": resolution}})
    assert e.value.key == "sonar.range_resolution_m"
    assert sonarsim.load_scene({"sonar": {**sonar, "range_resolution_m": 2.25}}).sonar.n_range_bins == 2


@pytest.mark.parametrize("sensor, key, message", [
    ({"frequency_khz": 1e-9}, "sensor.frequency_khz", r"within \[1, 100000\] kHz"),
    ({"frequency_khz": 1e9}, "sensor.frequency_khz", r"within \[1, 100000\] kHz"),
    ({"pulse": {"kind": "chirp", "bandwidth_khz": 1e9}}, "sensor.pulse.bandwidth_khz", r"within \(0, 100000\] kHz"),
    # The aris3000-128 preset's carrier is 3 MHz.
    ({"pulse": {"kind": "chirp", "bandwidth_khz": 4000}}, "sensor.pulse.bandwidth_khz",
     r"at most the carrier frequency \(sensor.frequency_khz"),
    ({"pulse": {"kind": "cw", "length_us": 1e-9}}, "sensor.pulse.length_us", r"within \[0.1, 100000\] us"),
    ({"azimuth_pattern": {"width_deg": 1e-9}}, "sensor.azimuth_pattern.width_deg", r"within \[0.01, 180\) degrees"),
    ({"elevation_pattern": {"width_deg": 1e-9}}, "sensor.elevation_pattern.width_deg", r"within \[0.01, 180\)"),
    ({"elevation_pattern": {"span_deg": 1e-300}}, "sensor.elevation_pattern.span_deg", r"within \[0.01, 170\]"),
    # The preset's beams are about 0.237 degrees apart: a pattern narrower than an eighth of that aliases.
    ({"azimuth_pattern": {"width_deg": 0.02}}, "sensor.azimuth_pattern.width_deg", "at least 0.0297 degrees"),
])
def test_sensor_values_beyond_physics_are_refused(sensor, key, message):
    doc = {"sonar": {"preset": "aris3000-128"}, "sensor": {"preset": "aris3000-128", **sensor}}
    with pytest.raises(ConfigError, match=message) as e:
        sonarsim.load_scene(doc)
    assert e.value.key == key


def test_the_carrier_and_the_beam_width_may_be_the_sonars():
    sonar = {**SONAR, "frequency_khz": 900.0}
    chirp = {"pulse": {"kind": "chirp", "bandwidth_khz": 1000.0}}
    with pytest.raises(ConfigError, match=r"\(0, 900\] kHz: at most the carrier frequency \(sonar.frequency_khz") as e:
        sonarsim.load_scene({"sonar": sonar, "sensor": chirp})
    assert e.value.key == "sensor.pulse.bandwidth_khz"
    assert sonarsim.load_scene({"sonar": sonar, "sensor": {"pulse": {"kind": "chirp", "bandwidth_khz": 900.0}}})
    # 16 beams over 30 degrees: 1.875 degrees apart; a beam 0.01 degree wide is the pattern's width.
    with pytest.raises(ConfigError, match="at least 0.234 degrees") as e:
        sonarsim.load_scene({"sonar": {**sonar, "beam_width_deg": 0.01}, "sensor": {"azimuth_pattern": True}})
    assert e.value.key == "sonar.beam_width_deg"
    with pytest.raises(ConfigError, match=r"within \[0.01, 90\) degrees") as e:
        sonarsim.load_scene({"sonar": {**sonar, "beam_width_deg": 1e-9}})
    assert e.value.key == "sonar.beam_width_deg"


@pytest.mark.parametrize("length_us, bin_m", [(0.1, 0.0033), (1.0, 1.0)])
def test_a_pulse_shorter_than_a_bin_stays_in_it(length_us, bin_m):
    # Missed by every sub-sample of a bin, its kernel was 0 / 0: NaN over the whole image.
    from sonarsim.config.sensor import PulseSpec
    from sonarsim.sensor.pulse import range_kernels

    intensity, amplitude = range_kernels(PulseSpec("cw", length_us), bin_m, 1500.0)
    assert intensity.tolist() == [1.0] and amplitude.tolist() == [1.0]
    img = sonarsim.render({"sonar": {**SONAR, "range_max_m": 100.0, "n_range_bins": 95},
                           "render": {"elevation_samples": 8}, "ground": {"height_m": -1.0},
                           "sensor": {"pulse": {"kind": "cw", "length_us": 1.0}}}, speckle=False)
    assert np.all(np.isfinite(img.polar)) and img.polar.max() > 0


@pytest.mark.parametrize("threads", [1_000_000, 257, 0, -1])
def test_thread_counts_are_bounded(threads):
    with pytest.raises(ConfigError, match="from 1 to 256 or null") as e:
        sonarsim.load_scene({"sonar": SONAR, "render": {"threads": threads}})
    assert e.value.key == "render.threads"
    assert sonarsim.load_scene({"sonar": SONAR, "render": {"threads": 256}}).render.threads == 256


@pytest.mark.parametrize("name, planes, ground", [
    ("ground", [], {}),          # two ids named ground in the labels
    ("ground", [], None),        # also the planes' direct-echo component
    ("surface", [{"name": "surface", "point_m": [0, 0, 2], "normal": [0, 0, -1]}], {}),
])
def test_an_object_may_not_take_a_planes_name(name, planes, ground):
    doc = {"sonar": SONAR, "planes": planes,
           "objects": [{"name": "ball", "primitive": "sphere", "radius_m": 0.2, "pose": {"position_m": [2, 0, 0.5]}},
                       {"name": name, "primitive": "sphere", "radius_m": 0.2, "pose": {"position_m": [3, 0, 0.5]}}]}
    if ground is not None:
        doc["ground"] = ground
    with pytest.raises(ConfigError, match="is a reflecting plane's name") as e:
        sonarsim.load_scene(doc)
    assert e.value.key == "objects[1].name"


def test_a_pipe_as_a_pattern_table_is_refused_not_read(tmp_path):
    import os

    from sonarsim.config.loader import scene_from_dict
    from sonarsim.config.sensor import PatternSpec
    from sonarsim.sensor.patterns import pattern_gain
    from tests.fifo import no_hang

    fifo = tmp_path / "pattern.csv"
    os.mkfifo(fifo)
    doc = {"sonar": SONAR, "sensor": {"azimuth_pattern": {"shape": "table", "table": "pattern.csv"}}}
    with pytest.raises(ConfigError, match="not a regular file") as e:  # was "not found"
        no_hang(lambda: scene_from_dict(doc, base_dir=tmp_path), [fifo])
    assert e.value.key == "sensor.azimuth_pattern.table" and str(fifo) in str(e.value)
    # Built in Python, the table is read when the gain is asked for: refused there too.
    spec = PatternSpec(shape="table", table=str(fifo))
    with pytest.raises(ConfigError, match="not a regular file"):
        no_hang(lambda: pattern_gain(np.zeros(3), spec, 1.0, 1), [fifo])


# Found by sweeping every numeric key through 0, -1, 1e-300, 1e300, inf and nan.

@pytest.mark.parametrize("where, value, key, message", [
    ("sonar", {"azimuth_fov_deg": 1e-300}, "sonar.azimuth_fov_deg", r"\[0.01, 180\) degrees"),   # every beam on one line
    ("sonar", {"elevation_fov_deg": 1e-300}, "sonar.elevation_fov_deg", r"\[0.01, 180\) degrees"),
    ("object", {"primitive": "sphere", "radius_m": 1e-300}, "objects[0].radius_m", r"\[1e-06, 10000\] metres"),
    ("object", {"primitive": "box", "size_m": [1, 1e-300, 1]}, "objects[0].size_m", r"\[1e-06, 10000\]"),
    ("object", {"primitive": "box", "size_m": [1, 1, 1], "scale": 1e-300}, "objects[0].scale", r"\[1e-06, 10000\]"),
    ("object", {"primitive": "box", "size_m": [1, 1, 1],
                "material": {"law": "rough", "specular_strength": 1e300, "roughness": 0.2}},
     "objects[0].material.specular_strength", r"\[0, 1e\+06\]"),                  # an infinite image
    ("object", {"primitive": "box", "size_m": [1, 1, 1],
                "material": {"law": "rough", "specular_strength": 1.0, "roughness": 1e-300}},
     "objects[0].material.roughness", r"\[0.001, 0.5\]"),                         # 0 / 0 at normal incidence
])
def test_tiny_and_huge_values_found_by_the_sweep_are_refused(where, value, key, message):
    doc = {"sonar": dict(SONAR)}
    if where == "sonar":
        doc["sonar"].update(value)
    else:
        doc["objects"] = [{"name": "o", "pose": {"position_m": [3, 0, 0]}, **value}]
    with pytest.raises(ConfigError, match=message) as e:
        sonarsim.load_scene(doc)
    assert e.value.key == key


def test_the_strongest_lobe_allowed_keeps_the_image_finite():
    doc = {"sonar": SONAR, "render": {"elevation_samples": 8},
           "objects": [{"name": "wall", "primitive": "box", "size_m": [0.1, 4, 4], "pose": {"position_m": [3, 0, 0]},
                        "material": {"law": "rough", "specular_strength": 1e6, "roughness": 0.001}}]}
    assert np.all(np.isfinite(sonarsim.render(doc).polar))


def test_a_pattern_table_with_a_byte_order_mark_reads(tmp_path):
    from sonarsim.config.sensor import PatternSpec
    from sonarsim.sensor.patterns import pattern_gain

    table = tmp_path / "pattern.csv"
    table.write_text("-10,-20\n0,0\n10,-20\n", encoding="utf-8-sig")   # as spreadsheets save it
    gain = pattern_gain(np.radians([0.0, 10.0]), PatternSpec(shape="table", table=str(table)), 1.0, 1)
    np.testing.assert_allclose(gain, [1.0, 0.01])
