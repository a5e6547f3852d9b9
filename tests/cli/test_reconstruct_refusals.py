"""``sonarsim reconstruct`` refuses, before building anything, what would cost more than the
budgets or mean nothing (issue 37): each case one line naming the option or file, exit 2 for
bad input and 3 for an outcome without meaning, nothing written."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim.cli.main import main
from sonarsim.core.transforms import Pose

pytest.importorskip("jax")

from sonarsim.diff import reconstruct as rec  # noqa: E402

SONAR = {"preset": "aris3000-128", "range_min_m": 0.7, "range_max_m": 3.5, "n_range_bins": 200}
RENDER = {"bounces": [1], "max_order": 1}
EXTENT = "1,3,-0.8,0.8"


def run(argv) -> int:
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A flat floor seen from (0, 0, 1) pitched 25 degrees; the same image with NaN rows and
    with no echo; the starting scene."""
    d = tmp_path_factory.mktemp("rec")
    doc = {"sonar": SONAR, "render": RENDER, "ground": {"albedo": 0.6}}
    with sonarsim.Simulator(doc) as sim:
        sim.render(pose=Pose((0.0, 0.0, 1.0), (0.0, 25.0, 0.0)), speckle=False).save_npz(d / "view.npz")
    (d / "start.yaml").write_text(yaml.safe_dump(doc))
    members = dict(np.load(d / "view.npz"))
    nan = members["polar"].copy()
    nan[50:53] = np.nan
    np.savez(d / "nan.npz", **{**members, "polar": nan})
    np.savez(d / "zero.npz", **{**members, "polar": np.zeros_like(members["polar"])})
    return d


@pytest.fixture
def nothing_built(monkeypatch):
    """Fail the test if the grid is built or the reconstruction starts."""
    def built(*args, **kwargs):
        raise AssertionError("the grid was built before the refusal")

    monkeypatch.setattr(rec, "grid_mesh", built)
    monkeypatch.setattr(rec, "reconstruct_heights", built)


def _refused(capsys, files, *extra, images=("view.npz",), status=2, budgets=()):
    out = files / "h.npz"
    code = run([*budgets, "reconstruct", *(files / i for i in images), "--scene", files / "start.yaml", "--out", out,
                *extra])
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if "error:" in line]
    assert code == status, err
    assert len(errors) == 1 and "Traceback" not in err, err
    assert not out.exists() and not (files / "h_figure.png").exists()
    return errors[0]


# Sizes: estimated from the grid, the views and the scene, against the budgets -------------

@pytest.mark.parametrize("extent, resolution, words", [
    ("1,3,-0.8,0.8", "1e-4", ["20,001 x 16,001 vertices", "memory budget", "--max-memory"]),
    ("-1e6,1e6,-1e6,1e6", "1000", ["2,001 x 2,001 vertices", "memory budget", "--max-memory"]),
    ("1,3,-0.8,0.8", "1e-300", ["more than 1e300 GiB", "memory budget"]),
    ("1,3,-0.8,0.8", "5e-324", ["memory budget"]),
    ("1,3,-0.8,0.8", "0.002", ["1,001 x 801 vertices", "build-time budget", "--max-build-time"]),
    ("1,3,-0.8,0.8", "5", ["fewer than two vertices", "less than 3.2 m"]),
    ("1,3,-0.8,2e6", "0.1", ["within 1e+06 m"]),
    ("3,1,-0.8,0.8", "0.1", ["x0 < x1"]),
])
def test_sizes_are_refused_before_anything_is_built(capsys, files, nothing_built, extent, resolution, words):
    line = _refused(capsys, files, f"--extent={extent}", "--resolution", resolution)
    key = "--extent" if "within" in words[0] or "x0" in words[0] else "--resolution"
    assert f"error: {key}: " in line and all(w in line for w in words), line


def test_the_budgets_given_are_the_ones_checked(capsys, files, nothing_built):
    # 161 x 201 vertices, one view: (1800 + 1000) bytes each, and the view's rays and images;
    # 64,000 triangles x 5 searches x 16 us = 5.1 s.
    from sonarsim.config.loader import load_scene
    from sonarsim.config.sonar import image_bytes
    from sonarsim.core.rays import ray_bytes

    scene = load_scene(files / "start.yaml")
    view = ray_bytes(scene.sonar, scene.render) + image_bytes(200, 128)
    line = _refused(capsys, files, "--extent", EXTENT, "--resolution", "0.01", budgets=("--max-memory", "64M"))
    assert "201 x 161 vertices" in line and f"{(201 * 161 * 2800 + view) / 2**30:.3g} GiB" in line, line
    assert "0.0625 GiB" in line
    line = _refused(capsys, files, "--extent", EXTENT, "--resolution", "0.01", budgets=("--max-build-time", "2"))
    assert "about 5.12 s" in line and "budget of 2 s" in line and "--max-build-time" in line


def test_the_plan_counts_the_grid_by_hand():
    plan = rec.plan_grid((1.0, 3.0, -0.8, 0.8), 0.1, 2)
    assert (plan.nx, plan.ny, plan.vertices, plan.triangles) == (21, 17, 357, 2 * 20 * 16)
    assert plan.bytes == pytest.approx(357 * (rec.BYTES_PER_VERTEX + 2 * rec.BYTES_PER_VERTEX_VIEW))
    assert plan.seconds == pytest.approx(2 * rec.min_searches(2) * 640 * rec.SECONDS_PER_TRIANGLE_SEARCH)
    x, y = rec.grid_axes((1.0, 3.0, -0.8, 0.8), 0.1)
    assert len(x) == 21 and len(y) == 17 and x[0] == 1.0 and y[-1] == pytest.approx(0.8)


# NaN and nonsense ----------------------------------------------------------------------------

@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "-10", "-1e-9", "1e4"])
def test_smoothness_outside_its_range_is_refused(capsys, files, nothing_built, value):
    line = _refused(capsys, files, "--extent", EXTENT, "--resolution", "0.1", "--smoothness", value)
    assert "--smoothness: must be a number from 0" in line and "to 1000" in line


def test_smoothness_bounds_are_allowed():
    assert rec.check_smoothness(0) == 0.0 and rec.check_smoothness("1e3") == 1e3
    with pytest.raises(sonarsim.errors.ConfigError, match="smoothness"):
        rec.check_smoothness(math.nextafter(0.0, -1.0))


def test_an_image_with_nan_rows_is_refused_naming_the_file(capsys, files, nothing_built):
    line = _refused(capsys, files, "--extent", EXTENT, "--resolution", "0.1", images=("view.npz", "nan.npz"))
    # The one loader of stored images refuses it (the same words as show and compare give).
    assert "nan.npz" in line and "NaN or infinite values (384 of 25600 pixels)" in line


def test_an_image_without_echo_means_nothing(capsys, files, nothing_built):
    line = _refused(capsys, files, "--extent", EXTENT, "--resolution", "0.1", images=("zero.npz",), status=3)
    assert "zero.npz (frame 0): holds no echo" in line


@pytest.mark.parametrize("truth, words", [
    ("missing.obj", ["--truth", "missing.obj: mesh file not found"]),
    ("badindex.obj", ["--truth", "a face refers to a vertex the file does not define"]),
    ("elsewhere.obj", ["--truth", "lies over none of the grid's vertices"]),
])
def test_truth_is_read_and_checked_before_reconstructing(capsys, files, nothing_built, truth, words):
    (files / "badindex.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n")
    (files / "elsewhere.obj").write_text("v 50 50 0\nv 51 50 0\nv 50 51 0\nf 1 2 3\n")
    line = _refused(capsys, files, "--extent", EXTENT, "--resolution", "0.1", "--truth", files / truth)
    assert all(w in line for w in words), line


def test_poses_far_away_mean_nothing(capsys, files, nothing_built):
    (files / "far.yaml").write_text(yaml.safe_dump([{"position_m": [1e6, 0, 1], "rpy_deg": [0, 25, 0]}]))
    line = _refused(capsys, files, "--extent", EXTENT, "--resolution", "0.1", "--poses", files / "far.yaml", status=3)
    assert "no image can see --extent" in line and "view.npz" in line and "999997.0 m from it" in line
    assert "range of 3.5 m" in line


def test_a_view_that_looks_away_sees_too_few_vertices(capsys, files):
    # Within range of the extent but turned round: the first searches meet none of the grid.
    (files / "away.yaml").write_text(yaml.safe_dump([{"position_m": [0, 0, 1], "rpy_deg": [0, 25, 180]}]))
    line = _refused(capsys, files, "--extent", EXTENT, "--resolution", "0.1", "--poses", files / "away.yaml", status=3)
    assert "at the start, the views saw 0 of the grid's 357 vertices, fewer than the 4 needed" in line


def test_the_seen_threshold():
    rec.seen_enough(np.ones(4, bool), "x")
    with pytest.raises(rec.ReconstructionRefused, match="saw 3 of the grid's 4 vertices, fewer than the 4"):
        rec.seen_enough(np.array([1, 1, 1, 0], bool), "x")
    seen = np.zeros(1000, bool)
    seen[:9] = True  # 1 % of 1000 is 10
    with pytest.raises(rec.ReconstructionRefused, match="fewer than the 10 needed"):
        rec.seen_enough(seen, "x")
    assert rec.ReconstructionRefused.exit_status == 3


def test_the_library_refuses_the_same_before_building(files, monkeypatch):
    from sonarsim.analysis.comparison import load_image
    from sonarsim.config.loader import load_scene
    from sonarsim.errors import ConfigError

    def built(*args, **kwargs):
        raise AssertionError("the grid was built before the refusal")

    monkeypatch.setattr(rec, "grid_mesh", built)
    scene = load_scene(files / "start.yaml")
    view = load_image(files / "view.npz")
    far = Pose((1e6, 0.0, 1.0), (0.0, 25.0, 0.0))
    cases = [
        ([view.polar], [view.pose], {"smoothness": -10.0}, ConfigError, "smoothness: must be a number from 0"),
        ([np.zeros_like(view.polar)], [view.pose], {}, rec.ReconstructionRefused, "images[0]: holds no echo"),
        ([np.full_like(view.polar, np.nan)], [view.pose], {}, ConfigError, "images[0]: must be a finite 2D image"),
        ([view.polar], [far], {}, rec.ReconstructionRefused, "no view can see the extent"),
        ([view.polar], [view.pose], {"resolution": 1e-300}, ConfigError, "resolution: a grid of"),
    ]
    for images, poses, kwargs, error, words in cases:
        kwargs = {"resolution": 0.1, **kwargs}
        with pytest.raises(error) as e:
            rec.reconstruct_heights(scene, images, poses, (1.0, 3.0, -0.8, 0.8), **kwargs)
        assert words in str(e.value), str(e.value)
