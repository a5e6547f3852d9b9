"""``sonarsim render`` and ``demo`` with reflecting planes: --max-order, --bounces, the tank demo."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from PIL import Image

from sonarsim.config.examples import tank_scene_dict
from sonarsim.cli.main import main
from tests.cli.test_cli import demo_dir  # noqa: F401 (the module-scoped demo run)


def _small_tank(tmp_path: Path) -> Path:
    doc = tank_scene_dict()
    doc["sonar"].update(n_beams=32, n_range_bins=200)
    doc["render"]["elevation_samples"] = 40
    path = tmp_path / "tank.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def test_max_order_sets_the_orders_formed_and_the_total(tmp_path, capsys):
    scene = _small_tank(tmp_path)
    assert main(["render", str(scene), "--out", str(tmp_path / "o2"), "--max-order", "2"]) == 0
    with np.load(tmp_path / "o2" / "render.npz") as z:
        names = set(z.files)
        assert "double" in names and "triple" not in names
        np.testing.assert_allclose(z["total"], z["single"] + z["double"], rtol=1e-5, atol=1e-9)
        # Path signatures are in the file too, each of order 2 at most.
        signatures = [k for k in names if k.startswith("O-")]
        assert signatures and all(k.count("-") - 1 <= 2 for k in signatures)
    assert main(["render", str(scene), "--out", str(tmp_path / "o4"), "--max-order", "4", "--bounces", "1,4"]) == 0
    with np.load(tmp_path / "o4" / "render.npz") as z:
        np.testing.assert_allclose(z["total"], z["single"] + z["order4"], rtol=1e-5, atol=1e-9)


def test_bounces_beyond_max_order_name_the_option(tmp_path, capsys):
    scene = _small_tank(tmp_path)
    code = main(["render", str(scene), "--out", str(tmp_path / "x"), "--max-order", "2", "--bounces", "3"])
    err = capsys.readouterr().err
    assert code == 2 and "--bounces" in err and "Traceback" not in err
    assert not (tmp_path / "x" / "render.npz").exists()


def test_demo_writes_the_tank_and_its_multipath_figure(demo_dir: Path) -> None:  # noqa: F811
    doc = yaml.safe_load((demo_dir / "tank.yaml").read_text())
    assert {p["name"] for p in doc["planes"]} == {"surface", "far_wall", "left_wall", "right_wall"}
    assert [o["name"] for o in doc["objects"] if o.get("specular", 0) > 0] == ["steel_plate"]  # a mesh mirror
    with Image.open(demo_dir / "multipath.png") as im:
        im.load()
        a = np.asarray(im)
    # Five panels, two across in three rows (the last place empty), each with some echo in it:
    # all paths, direct, via the surface, via a wall, via the steel plate.
    h, w = a.shape
    rows = [(0, h // 3), (h // 3, 2 * h // 3), (2 * h // 3, h)]
    panels = [a[r0:r1, c0:c1] for r0, r1 in rows for c0, c1 in ((0, w // 2), (w // 2, w))]
    assert all((p == 255).any() for p in panels[:5])  # the white title strip and gaps
    assert all(((p > 100) & (p < 255)).sum() > 100 for p in panels[:5])
    assert (panels[5] == 255).all()


def test_demo_with_a_lower_max_order_writes_every_figure(tmp_path, capsys):
    for order in ("1", "2"):
        out = tmp_path / order
        code = main(["demo", "--out", str(out), "--max-order", order, "--elevation-samples", "24"])
        err = capsys.readouterr().err
        assert code == 0 and "Traceback" not in err
        for name in ("ground_echo.png", "tank.yaml", "multipath.png"):
            assert (out / name).is_file(), (order, name)
        assert yaml.safe_load((out / "tank.yaml").read_text())["render"]["max_order"] == int(order)


def test_demo_shows_the_tank_as_an_aris_3000_records_it(demo_dir: Path) -> None:  # noqa: F811
    import sonarsim

    doc = yaml.safe_load((demo_dir / "scene_aris3000.yaml").read_text())
    assert doc["sensor"] == {"preset": "aris3000-128"}
    img = sonarsim.render(doc)
    # The scene file renders 8-bit frames: integers with a floor echo mid-scale, not saturated.
    assert np.all(img.polar == np.round(img.polar)) and img.polar.max() <= 255
    lit = img.components["total"] > np.percentile(img.components["total"], 90)
    assert 80 < np.median(img.polar[lit]) < 230
    with Image.open(demo_dir / "aris3000.png") as im:
        im.load()
        a = np.asarray(im)
    thirds = np.array_split(a[40:], 3, axis=1)  # under the titles: ideal | recorded | expected
    assert all(((t > 100) & (t < 255)).sum() > 1000 for t in thirds)
