"""``sonarsim reconstruct``: heights from render.npz files (their poses), the NPZ and the figure,
the error against a true mesh, bad input without a traceback."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

import sonarsim
from sonarsim.cli.main import main
from sonarsim.core.transforms import Pose

SONAR = {"preset": "aris3000-128", "range_min_m": 0.7, "range_max_m": 3.5, "n_range_bins": 600}
RENDER = {"bounces": [1], "max_order": 1}


def run(argv) -> int:
    try:
        return main([str(a) for a in argv])
    except SystemExit as exc:
        return exc.code


@pytest.fixture
def seabed(tmp_path):
    pytest.importorskip("jax")
    from sonarsim.diff.reconstruct import grid_mesh

    extent = (1.0, 3.0, -0.8, 0.8)
    _, x, y = grid_mesh(extent, 0.02)
    gx, gy = np.meshgrid(x, y)
    mesh, _, _ = grid_mesh(extent, 0.02, 0.1 * np.exp(-((gx - 2.0) ** 2 + (gy - 0.1) ** 2) / (2 * 0.25 ** 2)))
    mesh.export(tmp_path / "seabed.obj")
    doc = {"sonar": SONAR, "render": RENDER, "objects": [{"name": "bed", "mesh": str(tmp_path / "seabed.obj"), "albedo": 0.6}]}
    with sonarsim.Simulator(doc) as sim:
        for k, (y0, yaw) in enumerate(((0.0, 0.0), (-0.5, 12.0))):
            sim.render(pose=Pose((0.0, y0, 1.0), (0.0, 25.0, yaw)), speckle=False).save_npz(tmp_path / f"view{k}.npz")
    (tmp_path / "start.yaml").write_text(yaml.safe_dump({"sonar": SONAR, "render": RENDER, "ground": {"albedo": 0.6}}))
    return tmp_path


def test_reconstruct_writes_heights_and_a_figure_and_reports_the_error(seabed, capsys):
    out = seabed / "h.npz"
    status = run(["reconstruct", seabed / "view0.npz", seabed / "view1.npz", "--scene", seabed / "start.yaml",
                  "--extent", "1,3,-0.8,0.8", "--resolution", "0.1", "--out", out, "--truth", seabed / "seabed.obj"])
    captured = capsys.readouterr()
    assert status in (0, None), captured.err
    d = np.load(out)
    assert d["heights_m"].shape == (17, 21) and d["seen"].shape == (17, 21) and len(d["x_m"]) == 21
    assert d["loss"][-1] < d["loss"][0]
    rms = float(captured.out.split("seen vertices under --truth ")[1].split(" m")[0])
    assert rms < 0.01  # of a 10 cm bump (measured 3.6 mm from these two views)
    assert (seabed / "h_figure.png").stat().st_size > 10_000


def test_reconstruct_refuses_an_image_without_a_pose_and_a_bad_extent(seabed, capsys):
    status = run(["reconstruct", seabed / "view0.npz", "--scene", seabed / "start.yaml", "--extent", "3,1,0,1",
                  "--resolution", "0.1", "--out", seabed / "h.npz"])
    err = capsys.readouterr().err
    assert status == 2 and "extent" in err and "Traceback" not in err
    status = run(["reconstruct", seabed / "view0.npz", "--scene", seabed / "start.yaml", "--extent", "1,3",
                  "--resolution", "0.1", "--out", seabed / "h.npz"])
    assert status == 2 and "--extent x0,x1,y0,y1" in capsys.readouterr().err
    (seabed / "poses.yaml").write_text(yaml.safe_dump([{"position_m": [0, 0, 1], "rpy_deg": [0, 25, 0]}] * 3))
    status = run(["reconstruct", seabed / "view0.npz", "--scene", seabed / "start.yaml", "--extent", "1,3,-0.8,0.8",
                  "--resolution", "0.1", "--out", seabed / "h.npz", "--poses", seabed / "poses.yaml"])
    err = capsys.readouterr().err
    assert status == 2 and "one pose per image (1)" in err and not (seabed / "h.npz").exists()


def test_reconstruct_a_recording_with_poses_given(shared_data, tmp_path, capsys):
    """A recording carries no pose: --poses gives it. The real Oculus ping of a flat tank floor,
    with the calibrated Oculus preset at its pose (docs/presets.md), from a flat start: the
    heights stay near the flat floor (measured RMS 22 mm, at most 60 mm: one ping's speckle
    pulls them; the flat floor itself scores 0)."""
    pytest.importorskip("jax")
    pose = {"position_m": [0, 0, 0.433], "rpy_deg": [1.42, 29.06, 0]}
    (tmp_path / "scene.yaml").write_text(yaml.safe_dump({
        "sonar": {"preset": "oculus-m1200d-hf", "pose": pose}, "render": {"bounces": [1]}, "ground": {},
        "sensor": {"preset": "oculus-m1200d-hf"}}))
    (tmp_path / "poses.yaml").write_text(yaml.safe_dump([pose]))
    ping = shared_data / "real" / "oculus" / "one_ping_8bit.raw"
    out = tmp_path / "h.npz"
    status = run(["reconstruct", ping, "--scene", tmp_path / "scene.yaml", "--poses", tmp_path / "poses.yaml",
                  "--extent", "0.4,1.2,-0.5,0.5", "--resolution", "0.1", "--out", out])
    captured = capsys.readouterr()
    assert status in (0, None) and "Traceback" not in captured.err, captured.err
    d = np.load(out)
    seen = d["seen"]
    assert seen.mean() > 0.8
    h = d["heights_m"][seen]
    assert float(np.sqrt(np.mean(h ** 2))) < 0.04 and float(np.max(np.abs(h))) <= 0.09 + 1e-9
    # Without --poses the recording is refused by name.
    status = run(["reconstruct", ping, "--scene", tmp_path / "scene.yaml", "--extent", "0.4,1.2,-0.5,0.5",
                  "--resolution", "0.1", "--out", tmp_path / "g.npz"])
    err = capsys.readouterr().err
    assert status == 2 and "give --poses" in err and not (tmp_path / "g.npz").exists()
