"""Every image says its unit (issue 39 item 6): from its configuration, in NPZ files, figures and
bags; and the unit means what it says (a sphere's target strength from a render)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import sonarsim
from sonarsim.image.units import UNITS, unit_of
from tests.conftest import sonar_dict


@pytest.mark.parametrize("config, name", [
    ({"sonar": {}, "render": {"tvg": True}}, "backscatter"),
    ({"sonar": {}}, "backscatter"),
    ({"sonar": {}, "render": {"tvg": False}}, "backscatter_per_r2"),
    ({"sonar": {}, "sensor": {"source_level_db": 200.0, "output": False}}, "uPa^2"),
    ({"sonar": {}, "sensor": {"output": {"dtype": "uint8"}}}, "counts"),
    ({"source": "x.aris", "format": "aris", "frame": 0}, "counts"),
    ({}, "backscatter"),
])
def test_the_unit_follows_the_configuration(config, name):
    assert unit_of(config) is UNITS[name]


def test_a_spheres_target_strength_from_the_backscatter_unit():
    # Lambert's law on a sphere of radius a: sigma_bs = int mu cos^2 dA = 2 pi a^2 mu / 3 (m^2).
    # The unit: value * beam width (rad) * r^2, summed over the sphere's cells, is that.
    a, r0, mu = 0.1, 4.0, 0.1
    doc = {"sonar": sonar_dict(n_beams=64, azimuth_fov_deg=10.0, elevation_fov_deg=10.0, range_max_m=6.0,
                               n_range_bins=600),
           "objects": [{"name": "ball", "primitive": "sphere", "radius_m": a, "pose": {"position_m": [r0, 0.0, 0.0]},
                        "material": {"law": "lambert", "mu": mu}}],
           "render": {"elevation_samples": 400, "azimuth_samples": 8}}
    img = sonarsim.render(doc)
    assert img.unit.name == "backscatter"
    width = np.radians(img.sonar.effective_beam_width_deg())
    sigma = float((img.polar.astype(float) * width[None, :] * img.range_m[:, None] ** 2).sum())
    # (the sphere's mesh is facetted: 0.3 dB)
    assert 10 * math.log10(sigma) == pytest.approx(10 * math.log10(2 * math.pi * a * a * mu / 3), abs=0.3)


def test_npz_files_say_the_unit(tmp_path):
    img = sonarsim.render({"sonar": sonar_dict(), "render": {"tvg": False},
                           "objects": [{"name": "b", "primitive": "sphere", "radius_m": 0.2,
                                        "pose": {"position_m": [3.0, 0.0, 0.0]}}]})
    path = tmp_path / "frame.npz"
    img.save_npz(path)
    with np.load(path) as z:
        assert str(z["unit"]) == "backscatter_per_r2"
    back = sonarsim.read(path)
    assert back.unit.name == "backscatter_per_r2" and "unit" not in back.components


def test_a_sensors_images_are_in_its_units():
    doc = {"sonar": {"preset": "aris1800-96"}, "sensor": {"preset": "aris1800-96"}, "ground": {"height_m": -2.0}}
    assert sonarsim.render(doc).unit.name == "counts"
    doc["sensor"]["output"] = False
    assert sonarsim.render(doc).unit.name == "uPa^2"


# The instruments' films (issue 39 item 6) -------------------------------------------------

def _instrument_doc(kind: str, sensor: dict | None = None) -> dict:
    section = {"type": kind, "pose": {"position_m": [0.0, 0.0, 5.0], "rpy_deg": [0.0, 0.0, 0.0]}}
    if kind in ("sidescan", "scanning", "singlebeam"):
        section.update(range_max_m=10.0, n_samples=128)
    if sensor is not None:
        section["sensor"] = sensor
    return {"sonar": section, "ground": {"height_m": 0.0}, "render": {"max_order": 1}}


@pytest.mark.parametrize("kind", ["sidescan", "scanning", "singlebeam", "multibeam"])
@pytest.mark.parametrize("sensor, expected", [(None, None), ({"source_level_db": 200.0}, "uPa^2"),
                                              ({"output": {"dtype": "uint16"}}, "counts")])
def test_every_films_unit_follows_its_instruments_sensor_and_is_in_its_npz(kind, sensor, expected, tmp_path):
    from sonarsim.instruments import render_pings

    with sonarsim.Simulator(_instrument_doc(kind, sensor)) as sim:
        film = render_pings(sim, n_pings=1, speckle=False)
    if expected is None:  # no sensor: the engine's image (a single-beam's summed over its cone)
        expected = "cross_section_per_r2" if kind == "singlebeam" else "backscatter"
    assert film.unit is UNITS[expected] and film.unit_name == expected
    path = tmp_path / "film.npz"
    film.save_npz(path)
    with np.load(path) as z:
        assert str(z["unit"]) == expected


def test_a_films_unit_must_be_one_of_the_units():
    from sonarsim.image.films import Envelope, PingGeometry

    with pytest.raises(ValueError, match="unit must be one of"):
        Envelope(np.zeros((1, 4), np.float32), 0.0, 1.0, np.zeros(1), PingGeometry.of(1), unit_name="dB")


@pytest.mark.parametrize("folder, name, unit", [("multibeam", "r2sonic2026_pings_0-459.xtf", "uPa"),
                                                ("sidescan", "iver2_seascan_pings_0-179.xtf", "counts"),
                                                ("singlebeam", "imagenex852_2016-11-18.852", "counts")])
def test_a_recordings_films_are_in_the_devices_units(shared_data, folder, name, unit):
    from sonarsim.io.readers import imagenex, r2sonic, xtf

    if name.endswith(".xtf"):
        pytest.importorskip("pyxtf", reason="pyxtf (the xtf extra) is not installed")
    read = {"multibeam": r2sonic.read_soundings, "sidescan": xtf.read_waterfall, "singlebeam": imagenex.read_envelope}
    film = read[folder](shared_data / "real" / folder / name)
    assert film.unit.name == unit


def test_film_figures_say_the_unit():
    pytest.importorskip("matplotlib")
    from sonarsim.image.films import Envelope, PingGeometry, Waterfall
    from sonarsim.plot.films import envelope_figure, waterfall_figure

    g = PingGeometry.of(2, altitude_m=np.array([5.0, 5.0]))
    w = Waterfall(np.ones((2, 2, 16), np.float32), 0.0, 10.0, g, unit_name="uPa^2")
    assert UNITS["uPa^2"].label in waterfall_figure(w).axes[0].get_title()
    e = Envelope(np.ones((2, 16), np.float32), 0.0, 10.0, np.array([5.0, np.nan]), g, unit_name="cross_section_per_r2")
    assert UNITS["cross_section_per_r2"].label in envelope_figure(e).axes[0].get_title()
