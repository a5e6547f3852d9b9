"""sonarsim.plot.figures / axes: the annotated figures, checked through matplotlib's objects
(axis labels, ring radii and labels, tick labels, colour bars, titles), not through pixels."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from sonarsim.config.sonar import SonarConfig
from sonarsim.core.transforms import Pose
from sonarsim.image.result import SonarImage
from sonarsim.plot import figures as F
from sonarsim.plot.axes import azimuth_ticks_deg, format_azimuth, range_rings_m, round_step
from sonarsim.plot.style import OUTSIDE_FAN_RGB, colormap_lut


def synthetic(polar: np.ndarray | None = None, *, fov: float = 30.0, rmin: float = 0.7, rmax: float = 5.0,
              bins: int = 200, beams: int = 40, preset: str | None = None, **components) -> SonarImage:
    """A SonarImage made by hand: uniform beams, the given polar image (or zeros)."""
    sonar = SonarConfig.uniform(beams, fov, 14.0, rmin, rmax, bins, preset=preset)
    polar = np.zeros((bins, beams), np.float32) if polar is None else polar.astype(np.float32)
    comps = {"total": polar, **{k: np.asarray(v, np.float32) for k, v in components.items()}}
    return SonarImage(polar=polar, range_m=sonar.range_m, azimuth_deg=sonar.azimuth_deg, components=comps,
                      sonar=sonar, pose=Pose(position_m=(0.0, 0.0, 1.0), rpy_deg=(0.0, 20.0, 0.0)),
                      config={"render": {"bounces": [1, 2, 3]}})


def point_target(bins: int = 200, beams: int = 40, row: int = 100, col: int = 4) -> np.ndarray:
    """Zeros with a small bright spot (3 x 3) at (row, col), on a faint floor."""
    polar = np.full((bins, beams), 1e-3, np.float32)
    polar[row - 1:row + 2, col - 1:col + 2] = 1.0
    return polar


def colorbars(fig):
    return [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]


# ------------------------------------------------------------------------------ round steps


def test_ring_radii_are_round_metres_inside_the_window():
    # Hand-computed: the smallest step of 1, 2, 2.5, 5 x 10^k with at most 6 multiples inside.
    assert range_rings_m(0.7, 5.0)[0].tolist() == [1.0, 2.0, 3.0, 4.0, 5.0]
    assert range_rings_m(0.5, 8.0) == (pytest.approx([2.0, 4.0, 6.0, 8.0]), 2.0)  # 1 m would give 8
    assert range_rings_m(3.3, 23.4)[0].tolist() == [5.0, 10.0, 15.0, 20.0]  # 2.5 m would give 8
    assert range_rings_m(0.0, 1.998)[0].tolist() == [0.5, 1.0, 1.5]  # none at the apex
    assert range_rings_m(0.2, 0.6)[0] == pytest.approx([0.2, 0.3, 0.4, 0.5, 0.6])
    assert round_step(100.0, 5) == 25.0


def test_azimuth_ticks_and_their_labels():
    assert azimuth_ticks_deg(15.13, -15.13).tolist() == [15, 10, 5, 0, -5, -10, -15]
    assert azimuth_ticks_deg(30.13, -30.13).tolist() == [30, 20, 10, 0, -10, -20, -30]
    assert azimuth_ticks_deg(15.13, -15.13, 3).tolist() == [10, 0, -10]
    assert [format_azimuth(a) for a in (10.0, 0.0, -2.5)] == ["+10°", "0°", "\u22122.5°"]


# ------------------------------------------------------------------------------ the fan figure


def test_fan_figure_axes_rings_spokes_colour_bar_and_title():
    image = synthetic(point_target(), preset="aris3000-128")
    fig = F.fan_figure(image, dynamic_range_db=40.0)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "lateral (m), + = sonar's left"
    assert ax.get_ylabel() == "forward (m)"
    texts = [t.get_text() for t in ax.texts]
    # Rings of the 0.7-5 m window: 1 to 5 m; spokes of a 30 degree fan: every 5 degrees.
    assert [t for t in texts if t.endswith(" m")] == [" 1 m", " 2 m", " 3 m", " 4 m", " 5 m"]
    assert [t for t in texts if t.endswith("°")] == ["+15°", "+10°", "+5°", "0°", "\u22125°", "\u221210°", "\u221215°"]
    # Each ring is an arc of its radius around the apex; each label sits on its ring.
    arcs = [line for line in ax.lines if len(line.get_xdata()) == 181]
    radii = sorted({round(float(np.hypot(line.get_xdata(), line.get_ydata()).mean()), 6) for line in arcs})
    assert radii == [1.0, 2.0, 3.0, 4.0, 5.0]
    for text in ax.texts:
        if text.get_text().endswith(" m"):
            x, y = text.get_position()
            assert math.hypot(x, y) == pytest.approx(float(text.get_text().strip()[:-2]))
    (bar,) = colorbars(fig)
    # the image's unit said beside the reference (sonarsim.image.units)
    assert bar.get_ylabel() == "echo level (dB re the image's maximum; sigma / r^2 per bin and radian of beam)"
    assert bar.get_ylim() == pytest.approx((-40.0, 0.0))
    title = ax.get_title()
    assert "aris3000-128" in title and "0.7\u20135 m" in title and "total (orders 1, 2, 3)" in title
    assert "no sensor model" in title and "roll/pitch/yaw (0, 20, 0)" in title


def test_gain_and_window_move_the_colour_bar():
    fig = F.fan_figure(synthetic(point_target()), gain_db=6.0, dynamic_range_db=30.0)
    assert colorbars(fig)[0].get_ylim() == pytest.approx((-36.0, -6.0))
    fig = F.fan_figure(synthetic(point_target()), mapping="linear")
    assert colorbars(fig)[0].get_ylabel() == "intensity / the image's maximum; sigma / r^2 per bin and radian of beam"
    assert colorbars(fig)[0].get_ylim() == pytest.approx((0.0, 1.0))


def test_a_target_on_the_sonars_left_is_drawn_on_the_left():
    """The brightest pixel of a target in beam 4 of 40 (left-most first) lies left of the apex."""
    image = synthetic(point_target(col=4))
    fig = F.fan_figure(image)
    fig.canvas.draw() if hasattr(fig.canvas, "draw") else None
    ax = fig.axes[0]
    shown = ax.images[0]
    rgb = np.asarray(shown.get_array())
    lut = colormap_lut("inferno")
    brightest = np.all(rgb == lut[255], axis=-1)
    rows, cols = np.nonzero(brightest)
    assert rows.size
    left, right, bottom, top = shown.get_extent()
    col_x = left + (cols.mean() + 0.5) * (right - left) / rgb.shape[1]  # data coordinate: + = left
    row_y = top - (rows.mean() + 0.5) * (top - bottom) / rgb.shape[0]
    # Beam 4's centre is +15 - 4.5 * 0.75 = 11.625 degrees; bin 100 of 0.7-5 m is at 2.86 m.
    assert math.degrees(math.atan2(col_x, row_y)) == pytest.approx(11.625, abs=1.0)
    assert math.hypot(col_x, row_y) == pytest.approx(0.7 + 100.5 * 4.3 / 200, abs=0.05)
    # On screen: left of the apex.
    target = ax.transData.transform((col_x, row_y))
    apex = ax.transData.transform((0.0, 0.0))
    assert target[0] < apex[0]


def test_outside_the_fan_differs_from_no_echo_and_grey_is_offered():
    polar = point_target()
    polar[:40] = 0.0  # no echo in the near fifth of the window
    image = synthetic(polar)
    rgb = np.asarray(F.fan_figure(image).axes[0].images[0].get_array())
    assert (rgb[0, 0] == OUTSIDE_FAN_RGB).all()  # a top corner lies outside a 30 degree fan
    assert (rgb[-1, 0] == OUTSIDE_FAN_RGB).all()  # so does a bottom corner, beside the apex
    # No echo (1.2 m ahead: bin 30 of 200) is the map's darkest colour, not the outside's.
    row = int(round((F.figure_pixel_size(image.sonar) * rgb.shape[0] - 1.2) / F.figure_pixel_size(image.sonar)))
    assert (rgb[row, rgb.shape[1] // 2] == colormap_lut("inferno")[0]).all()
    grey = np.asarray(F.fan_figure(image, colormap="grey").axes[0].images[0].get_array())
    fan = grey[np.any(grey != OUTSIDE_FAN_RGB, axis=-1)]
    assert (fan[:, 0] == fan[:, 1]).all() and (fan[:, 1] == fan[:, 2]).all()


def test_two_different_scenes_give_different_pictures():
    a = F.fan_figure(synthetic(point_target(col=4))).axes[0].images[0].get_array()
    b = F.fan_figure(synthetic(point_target(col=30))).axes[0].images[0].get_array()
    assert np.asarray(a).shape == np.asarray(b).shape
    assert (np.asarray(a) != np.asarray(b)).any(axis=-1).sum() > 20


def test_device_output_is_shown_in_counts():
    image = synthetic(point_target() * 200.0)
    image = SonarImage(**{**image.__dict__, "config": {"sensor": {"output": {"dtype": "uint8"}}}})
    fig = F.fan_figure(image)
    (bar,) = colorbars(fig)
    assert bar.get_ylabel() == "device output (counts)" and bar.get_ylim() == pytest.approx((0.0, 255.0))
    assert "sensor model on" in fig.axes[0].get_title()


# ------------------------------------------------------------------------------ polar


def test_polar_figure_axes_far_range_up_left_beam_left():
    image = synthetic(point_target(col=4))
    fig = F.polar_figure(image)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "azimuth (deg), + = sonar's left" and ax.get_ylabel() == "range (m)"
    x0, x1 = ax.get_xlim()
    assert x0 == pytest.approx(15.0) and x1 == pytest.approx(-15.0)  # the left-most beam on the left
    assert ax.get_ylim() == pytest.approx((0.7, 5.0))  # far range at the top
    assert [t.get_text() for t in ax.get_yticklabels()] == ["1", "2", "3", "4", "5"]
    assert [t.get_text() for t in ax.get_xticklabels()][0] == "+15°"
    # The mesh: cell (row 100, column 4) is the target, at 11.625 deg and ~2.86 m.
    levels = np.asarray(ax.images[0].get_array()).reshape(200, 40)
    assert levels[100, 4] == 255 and levels[100, 35] < 255
    assert colorbars(fig)[0].get_ylabel().startswith("echo level (dB")


# ------------------------------------------------------------------------------ the comparisons


def test_ground_echo_panels_share_one_scale():
    bins, beams = 200, 40
    single = point_target(bins, beams, row=80, col=20)
    triple = point_target(bins, beams, row=150, col=20) * 0.1
    image = synthetic(single + triple, single=single, double=np.zeros_like(single), triple=triple)
    fig = F.ground_echo_figure(image)
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert [ax.get_title() for ax in panels] == ["single", "single + triple", "all bounces"]
    (bar,) = colorbars(fig)
    assert bar.get_ylabel() == "echo level (dB re the all-bounce image's maximum)"
    assert fig.get_suptitle().startswith("Ground echo:")
    first, second = (np.asarray(ax.images[0].get_array()) for ax in panels[:2])
    assert (first != second).any()  # the triple bounce's ghost appears in the second panel only


def test_multipath_panels_are_the_path_families_in_a_grid():
    from sonarsim.config.examples import tank_scene_dict
    from sonarsim.io.figures import path_families
    import sonarsim

    doc = tank_scene_dict()
    doc["sonar"].update(n_beams=48, n_range_bins=160)
    doc["render"]["elevation_samples"] = 12
    image = sonarsim.render(doc)
    fig = F.multipath_figure(image)
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert [ax.get_title() for ax in panels] == [name for name, _ in path_families(image)]
    assert len(colorbars(fig)) == 1
    # A 2 x 2 grid: two rows of two.
    rows = sorted({round(ax.get_position().y0, 3) for ax in panels})
    assert len(rows) == 2


def test_real_and_simulated_side_by_side_on_one_scale(shared_data):
    from sonarsim.io.readers import read

    real = read(shared_data / "real" / "oculus" / "three_pings_8bit.raw", 0)
    other = read(shared_data / "real" / "oculus" / "three_pings_8bit.raw", 2)
    fig = F.comparison_figure([real, other], ["A", "B"])
    (bar,) = colorbars(fig)  # both in the device's counts: one bar, 0-255
    assert bar.get_ylim() == pytest.approx((0.0, 255.0)) and bar.get_ylabel() == "device output (counts)"
    sim = synthetic(point_target(), fov=60.0, rmin=0.0, rmax=2.0)
    fig = F.comparison_figure([real, sim], ["real", "simulated"])
    (bar,) = colorbars(fig)  # counts beside intensity: each over its maximum, one bar
    assert bar.get_ylabel() == "intensity / each image's maximum" and bar.get_ylim() == pytest.approx((0.0, 1.0))
    assert [ax.get_title() for ax in fig.axes if ax.get_label() != "<colorbar>"] == ["real", "simulated"]


# ------------------------------------------------------------------------------ files


@pytest.mark.parametrize("fmt, magic", [("png", b"\x89PNG"), ("svg", b"<?xml"), ("pdf", b"%PDF")])
def test_save_figure_writes_each_format_the_same_every_time(tmp_path, fmt, magic):
    image = synthetic(point_target())
    a, b = tmp_path / f"a.{fmt}", tmp_path / f"b.{fmt}"
    F.save_figure(F.fan_figure(image), a)
    F.save_figure(F.fan_figure(image), b)
    assert a.read_bytes().startswith(magic)
    assert a.read_bytes() == b.read_bytes()  # no dates: the same figure, the same file
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([a.name, b.name])  # no temp files left


def test_save_figure_refuses_an_unknown_format(tmp_path):
    with pytest.raises(ValueError, match="'tiff'.*allowed: png, svg, pdf"):
        F.save_figure(F.fan_figure(synthetic()), tmp_path / "a.tiff")
    assert list(tmp_path.iterdir()) == []


def test_fit_figure_marks_the_fitted_band_on_the_real_image():
    import sonarsim
    from tests.conftest import block_scene_dict

    from sonarsim.analysis.fitting import floor_band_m

    image = sonarsim.render(block_scene_dict(n_range_bins=200))
    # The band is passed in: the figures do not import the analysis (issue 23, item 5).
    fig = F.fit_figure(image, image, frame=2, band=floor_band_m(image))
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert [ax.get_title() for ax in panels] == ["real (frame 2), fitted floor band", "render at the fitted pose"]
    assert [t.get_text() for t in panels[0].get_legend().get_texts()] == ["near edge", "far edge"]
    near = panels[0].lines[-2]
    # The band's near edge (1 m up, 20 deg down, 14 deg aperture: 1 / sin(27 deg) = 2.2 m) in metres.
    assert np.median(np.hypot(near.get_xdata(), near.get_ydata())) == pytest.approx(1 / math.sin(math.radians(27)),
                                                                                   abs=0.1)
    # Without a band: the two images, unmarked.
    fig = F.fit_figure(image, image, frame=2)
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert [ax.get_title() for ax in panels] == ["real (frame 2)", "render at the fitted pose"]
    assert panels[0].get_legend() is None
    assert not {"near edge", "far edge"} & {line.get_label() for line in panels[0].lines}


def test_calibration_figure_shows_three_panels_in_counts():
    real = synthetic(point_target() * 180.0)
    fig = F.calibration_figure(real, real, real, 255.0, frame=4)
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert [ax.get_title() for ax in panels] == ["real (frame 4)", "calibrated model: expected (no speckle)",
                                                 "calibrated model: speckled frame"]
    (bar,) = colorbars(fig)
    assert bar.get_ylabel() == "device output (counts)" and bar.get_ylim() == pytest.approx((0.0, 255.0))


def _rendered_rgb(fig) -> np.ndarray:
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3]


def _pixel(fig, ax, az_deg: float, r_m: float) -> np.ndarray:
    """The drawn colour at a data point (azimuth, range) of polar axes."""
    rgb = _rendered_rgb(fig)
    x, y = ax.transData.transform((az_deg, r_m))
    return rgb[rgb.shape[0] - 1 - int(round(y)), int(round(x))]


def test_polar_figure_draws_unequal_beams_at_their_own_edges_as_one_image():
    # An asymmetric lens table: beam 0 at +20 deg spans (25, 15), beam 7 at -3 deg (-2.5, -3.5).
    table = (20.0, 10.0, 5.0, 2.0, 0.0, -1.0, -2.0, -3.0)
    sonar = SonarConfig(beam_angles_deg=table, elevation_fov_deg=14.0, range_min_m=0.5, range_max_m=6.0,
                        n_range_bins=300)
    polar = np.full((300, 8), 1e-6, np.float32)
    polar[:, 0] = 1.0  # the left-most beam bright, the others 60 dB down (black)
    image = SonarImage(polar=polar, range_m=sonar.range_m, azimuth_deg=sonar.azimuth_deg,
                       components={"total": polar}, sonar=sonar, pose=None, config={})
    fig = F.polar_figure(image)
    ax = fig.axes[0]
    assert ax.get_xlim() == pytest.approx((25.0, -3.5))
    bright, dark = colormap_lut()[255], colormap_lut()[0]
    assert (_pixel(fig, ax, 16.0, 3.0) == bright).all()  # inside beam 0, near its right edge at 15 deg
    assert (_pixel(fig, ax, 14.0, 3.0) == dark).all()  # beam 1
    assert (_pixel(fig, ax, -3.2, 3.0) == dark).all()
    # One image, not one quadrilateral per cell: 8000 x 512 cells took seconds to draw.
    assert len(ax.images) == 1 and not ax.collections


def test_titles_write_long_ranges_and_far_poses_without_exponents():
    image = synthetic(rmin=100.0, rmax=1000.0, bins=50)
    image = SonarImage(polar=image.polar, range_m=image.range_m, azimuth_deg=image.azimuth_deg,
                       components=image.components, sonar=image.sonar,
                       pose=Pose(position_m=(1500.0, -0.25, 12.0), rpy_deg=(0.0, 20.0, -135.0)), config=image.config)
    title = F.describe(image)
    assert "40 beams, 100\u20131000 m" in title  # was "100–1e+03 m"
    assert "sonar at (1500, -0.25, 12) m, roll/pitch/yaw (0, 20, -135)\u00b0" in title


def test_a_dark_frame_says_so_on_its_colour_bar():
    fig = F.fan_figure(synthetic())  # all zero
    (bar,) = colorbars(fig)
    assert bar.get_ylabel().startswith("echo level (dB re 1; no echo: nothing above 0")  # not "re the image's maximum"
    assert bar.get_ylim() == pytest.approx((-40.0, 0.0))
    rgb = np.asarray(fig.axes[0].images[0].get_array()).reshape(-1, 3)
    inside = rgb[(rgb != OUTSIDE_FAN_RGB).any(axis=1)]
    assert len(inside) > 1000 and (inside == colormap_lut()[0]).all()  # black: no echo


@pytest.mark.parametrize("fill", [0.0, -1.0, np.nan])
def test_comparison_with_an_image_without_a_positive_maximum(fill):
    # compare --out divides each image by its maximum: a negative image (values in dB, say) or
    # an all-NaN one crashed the command with a traceback (reference -1.0 / nan).
    real = synthetic(point_target())
    dark = synthetic(np.full((200, 40), fill, np.float32))
    fig = F.comparison_figure([real, dark], ["A", "B"])
    labels = sorted(bar.get_ylabel() for bar in colorbars(fig))
    assert labels == ["intensity / 1; no echo: nothing above 0", "intensity / each image's maximum"]


def test_ctrl_c_while_a_figure_is_drawn_is_delivered_after_it_as_keyboard_interrupt(tmp_path):
    # matplotlib's C code turned a Ctrl-C that landed inside it into "ValueError: Invalid affine
    # transformation matrix" (sonarsim demo --figure-format svg: a traceback, exit status 1). The
    # signal is now held while the figure is drawn, then raised as KeyboardInterrupt, and the
    # unfinished file is discarded.
    import os
    import signal

    from matplotlib.artist import Artist

    drawn = []

    class Interrupting(Artist):
        def draw(self, renderer):
            os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C in the middle of drawing
            drawn.append("interrupting")

    class Later(Artist):
        zorder = 10

        def draw(self, renderer):
            drawn.append("later")

    fig = F.fan_figure(synthetic(point_target()))
    fig.axes[0].add_artist(Interrupting())
    fig.axes[0].add_artist(Later())
    with pytest.raises(KeyboardInterrupt):
        F.save_figure(fig, tmp_path / "fan.svg")
    assert drawn[0] == "interrupting" and drawn[-1] == "later"  # drawing went on to its end
    assert os.listdir(tmp_path) == []  # no figure, no temporary file
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


# ------------------------------------------------------------------------------ issue 37's figure defects


def _drawn(fig):
    """Draw ``fig`` on an Agg canvas; its renderer."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def test_panels_keep_their_labels_inside_the_figure_and_the_title_above_theirs():
    # ground_echo_figure.png cut its x labels off at the bottom and its title sat on the middle
    # panel's: the fans keep their aspect, and the figure was too short for the layout to fit them.
    image = synthetic(point_target(), single=point_target(), triple=point_target() * 0.1,
                      double=point_target() * 0.2, object=point_target(), ground=point_target() * 0.01)
    fig = F.ground_echo_figure(image)
    renderer = _drawn(fig)
    height = fig.bbox.height
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    for ax in panels:
        box = ax.get_tightbbox(renderer)
        assert box.y0 >= 0.0 and box.y1 <= height, (ax.get_title(), box.y0, box.y1, height)
        assert ax.xaxis.label.get_window_extent(renderer).y0 >= 0.0
    title = fig._suptitle.get_window_extent(renderer)
    assert min(title.y0 - ax.title.get_window_extent(renderer).y1 for ax in panels) > 2.0  # pixels apart


def test_the_sensor_figure_shows_the_ideal_image_it_is_given():
    # The demo labelled "ideal" the sensor render's own total, formed over the elevation
    # pattern's 42-degree ray span; the ideal image is the scene without the sensor.
    ideal = synthetic(point_target())
    wide = synthetic(np.full((200, 40), 0.5, np.float32), total=np.full((200, 40), 0.5, np.float32))
    recorded = replace(wide, config={"sensor": {"output": {"dtype": "uint8"}}})
    fig = F.sensor_figure(recorded, recorded, "a device", ideal=ideal)
    first = fig.axes[0]
    assert first.get_title() == "ideal (the paper's model, no sensor)"
    rgb = np.asarray(first.images[0].get_array()).reshape(-1, 3)
    inside = rgb[(rgb != OUTSIDE_FAN_RGB).any(axis=1)]
    # The point target on a faint floor (-30 dB: black in a 40 dB window at most partly), not
    # the uniform image of the recorded total (one colour everywhere).
    assert len(np.unique(inside, axis=0)) > 2
    fig = F.sensor_figure(recorded, recorded, "a device")  # without: the title says what it is
    assert fig.axes[0].get_title() == "renderer's image over the sensor's ray span"


def test_the_comparison_shows_its_metrics_and_the_difference_centred_on_zero():
    a = synthetic(point_target())
    b = synthetic(point_target(row=120))
    metrics = {"polar": {"mse": 12.5, "psnr": 37.16, "ssim": 0.912}, "fan": {"mse": 10.0, "psnr": 38.1, "ssim": 0.93}}
    fig = F.comparison_figure([a, b], ["A", "B"], metrics=metrics, difference=True, title="sonarsim compare")
    text = fig._suptitle.get_text()
    assert "polar: MSE 12.5, PSNR 37.16 dB, SSIM 0.912" in text and "fan: MSE 10, PSNR 38.1 dB" in text
    panels = [ax for ax in fig.axes if ax.get_label() != "<colorbar>"]
    assert [ax.get_title() for ax in panels] == ["A", "B", "A \u2212 B"]
    bars = colorbars(fig)
    signed = [bar for bar in bars if bar.get_ylabel().startswith("A \u2212 B")]
    assert len(signed) == 1
    lo, hi = signed[0].get_ylim()
    assert lo == pytest.approx(-hi) and hi == pytest.approx(1.0 - 1e-3)  # spot (1) minus floor (1e-3), over each maximum
    # Different grids: no difference, and the title says why.
    c = synthetic(point_target(bins=100), bins=100)
    fig = F.comparison_figure([a, c], ["A", "C"], difference=True)
    assert "no difference panel" in fig._suptitle.get_text()
    assert len([ax for ax in fig.axes if ax.get_label() != "<colorbar>"]) == 2


def test_the_reconstruction_figure_shares_one_height_scale_and_centres_the_error():
    x, y = np.linspace(0.0, 1.0, 11), np.linspace(-0.5, 0.5, 11)
    truth = 0.1 * np.exp(-((x[None, :] - 0.5) ** 2 + y[:, None] ** 2) / 0.02)
    result = truth * 0.8 + 0.002
    seen = np.ones_like(truth, bool)
    seen[0, 0] = False
    fig = F.reconstruction_figure(result, x, y, seen, truth_m=truth)
    images = [ax.images[0] for ax in fig.axes if ax.get_label() != "<colorbar>"]
    (truth_im, result_im, error_im) = images
    assert truth_im.norm.vmin == result_im.norm.vmin and truth_im.norm.vmax == result_im.norm.vmax  # one scale
    assert truth_im.norm.vmax == pytest.approx(truth[seen].max())
    assert error_im.norm.vmin == pytest.approx(-error_im.norm.vmax)  # centred on zero
    assert error_im.norm.vmax == pytest.approx(np.abs(result - truth)[seen].max())
    assert error_im.get_cmap().name == F.SIGNED_COLORMAP
    assert len(colorbars(fig)) == 2  # heights (truth and result) and the error
