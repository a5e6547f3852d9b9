"""Tests of the ``sonarsim compare`` command (sonarsim.cli.compare)."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from sonarsim.analysis.comparison import compare_images
from sonarsim.cli.compare import add_compare_parser, cmd_compare
from sonarsim.errors import SonarsimError
from sonarsim.io.output import to_uint8, write_png

# --------------------------------------------------------------------------------------------
# The compare command
# --------------------------------------------------------------------------------------------


def _parser():
    parser = argparse.ArgumentParser(prog="sonarsim")
    add_compare_parser(parser.add_subparsers(dest="command"))
    return parser


def _run(capsys, *argv):
    args = _parser().parse_args(["compare", *map(str, argv)])
    assert args.func is cmd_compare
    args.func(args)
    out = capsys.readouterr()
    return out.out, out.err


def test_compare_prints_a_table_of_domains_and_metrics(capsys, npz_files, renders):
    out, _ = _run(capsys, npz_files["full"], npz_files["half"])
    expected = compare_images(renders["full"], renders["half"])
    lines = out.splitlines()
    header = next(line for line in lines if line.startswith("domain"))
    assert header.split() == ["domain", "MSE", "PSNR", "dB", "SSIM", "pixels"]
    for domain in ("polar", "fan"):
        row = next(line for line in lines if line.startswith(domain)).split()
        m = expected[domain]
        assert float(row[1]) == pytest.approx(m["mse"], abs=1e-4)
        assert float(row[2]) == pytest.approx(m["psnr"], abs=1e-3)
        assert float(row[3]) == pytest.approx(m["ssim"], abs=1e-4)
        assert int(row[4]) == m["n_pixels"]
    assert "resampled" in out


def test_compare_json_output(capsys, npz_files):
    out, _ = _run(capsys, npz_files["full"], npz_files["full"], "--json", "--pixel-size", "0.02")
    doc = json.loads(out)
    assert doc["a"]["shape"] == [400, 32] and doc["b"]["n_range_bins"] == 400
    assert doc["pixel_size_m"] == 0.02 and doc["resampled"] is False
    for domain in ("polar", "fan"):
        assert doc["metrics"][domain]["mse"] == 0.0
        assert doc["metrics"][domain]["psnr"] is None  # inf is not JSON
        assert doc["metrics"][domain]["ssim"] == pytest.approx(1.0)

    out, _ = _run(capsys, npz_files["full"], npz_files["full"], "--json", "--component-b", "single")
    doc = json.loads(out)
    assert doc["b"]["component"] == "single"
    assert 0 < doc["metrics"]["polar"]["mse"] and 0 < doc["metrics"]["polar"]["psnr"] < 100


def test_compare_a_png_pair(capsys, tmp_path, renders):
    rng = np.random.default_rng(7)
    a = to_uint8(renders["full"].polar[::-1], "db", dynamic_range_db=40)
    b = np.clip(a.astype(int) + rng.integers(-3, 4, a.shape), 0, 255).astype(np.uint8)
    write_png(tmp_path / "a.png", a)
    write_png(tmp_path / "b.png", b)
    out, err = _run(capsys, tmp_path / "a.png", tmp_path / "b.png", "--normalize", "none")
    row = next(line for line in out.splitlines() if line.startswith("polar")).split()
    expected_mse = float(np.mean((a.astype(float) - b) ** 2))
    assert float(row[1]) == pytest.approx(expected_mse, abs=1e-4)
    assert float(row[2]) == pytest.approx(10 * math.log10(255**2 / expected_mse), abs=1e-3)
    assert not any(line.startswith("fan") for line in out.splitlines())
    assert "no geometry" in out and "fan domain skipped" in err

    out, _ = _run(capsys, tmp_path / "a.png", tmp_path / "b.png", "--json")
    doc = json.loads(out)
    assert set(doc["metrics"]) == {"polar"} and "fan" in doc["skipped"]


def test_compare_errors_are_sonarsim_errors(capsys, tmp_path, npz_files):
    with pytest.raises(SonarsimError, match="no such file"):
        _run(capsys, tmp_path / "nope.npz", npz_files["full"])
    with pytest.raises(SonarsimError, match="ranges"):
        _run(capsys, npz_files["full"], npz_files["far"])
    with pytest.raises(SystemExit):
        _parser().parse_args(["compare", "a", "b", "--pixel-size", "-1"])
    capsys.readouterr()


def test_compare_through_the_main_cli_exits_2_without_traceback(capsys, npz_files):
    from sonarsim.cli import main as cli

    try:
        cli.main(["compare", "--help"])
    except SystemExit as exc:
        if exc.code != 0:
            pytest.skip("`compare` is not wired into sonarsim.cli.main yet")
    capsys.readouterr()
    assert cli.main(["compare", str(npz_files["full"]), str(npz_files["half"])]) == 0
    assert "polar" in capsys.readouterr().out
    assert cli.main(["compare", str(npz_files["full"]), str(npz_files["far"])]) == 2
    err = capsys.readouterr().err
    assert "ranges" in err and "Traceback" not in err


def test_compare_help_promises_what_out_writes(capsys, tmp_path, npz_files):
    """compare writes one figure and no exact-pixel images: its help says so, and --out holds
    just that figure (and the run record), or nothing with --no-figures."""
    with pytest.raises(SystemExit):
        _parser().parse_args(["compare", "--help"])
    help_text = " ".join(capsys.readouterr().out.split())
    assert "only the exact-pixel images" not in help_text
    assert "compare_figure.png into DIR, compare's only image (no exact-pixel PNGs)" in help_text
    assert "--no-figures write no figure (this command writes no other image" in help_text

    out = tmp_path / "out"
    _run(capsys, npz_files["full"], npz_files["half"], "--out", out)
    assert sorted(p.name for p in out.iterdir()) == ["compare_figure.png", "sonarsim-run.json"]
    quiet = tmp_path / "quiet"
    _run(capsys, npz_files["full"], npz_files["half"], "--out", quiet, "--no-figures")
    assert not quiet.exists() or not any(quiet.iterdir())


def test_compare_real_oculus_pings(capsys, shared_data):
    """Real recordings through sonarsim.io.readers: a ping equals itself, and differs from the next."""
    three = shared_data / "real" / "oculus" / "three_pings_8bit.raw"
    one = shared_data / "real" / "oculus" / "one_ping_8bit.raw"
    doc = json.loads(_run(capsys, three, one, "--json")[0])  # one_ping is the first of three
    assert doc["metrics"]["polar"]["mse"] == 0.0 and doc["metrics"]["fan"]["mse"] == 0.0
    doc = json.loads(_run(capsys, three, three, "--frame-b", "1", "--json")[0])
    assert doc["b"]["frame"] == 1 and doc["a"]["n_beams"] == 256
    for domain in ("polar", "fan"):
        m = doc["metrics"][domain]
        assert m["mse"] > 0 and 0 < m["psnr"] < 60 and 0 < m["ssim"] < 1


def test_compare_stats_reports_the_shadow_region_in_the_table_and_the_json(capsys, npz_files, renders):
    from sonarsim.analysis.realism import auto_regions

    expected = {k: int(v.sum()) for k, v in auto_regions(renders["full"].polar).items()}
    assert expected["shadow"] > 0
    out, _ = _run(capsys, npz_files["full"], npz_files["full"], "--stats", "--normalize", "none")
    lines = out.splitlines()
    table = lines[next(i for i, line in enumerate(lines) if line.startswith("region")) + 1:]
    rows = {line.split()[0]: line.split() for line in table}
    assert list(rows) == ["all", "lit", "water", "shadow"]
    for region in ("lit", "water", "shadow"):
        assert int(rows[region][1]) == expected[region]
    # Against itself: KS and W1 0; a noise-free shadow is 0, so it has no contrast or profile.
    assert rows["shadow"][-3:] == ["0.000", "0", "n/a"]
    assert rows["shadow"][2:8] == ["0", "|", "0", "n/a", "|", "n/a"]  # mean, contrast
    doc = json.loads(_run(capsys, npz_files["full"], npz_files["half"], "--stats", "--json")[0])
    assert list(doc["stats"]) == ["all", "lit", "water", "shadow"]
    assert doc["stats"]["shadow"]["pixels"] == expected["shadow"]
    assert doc["stats"]["shadow"]["mean_a"] < 0.01 * doc["stats"]["lit"]["mean_a"]


def test_compare_region_masks_from_npy_and_png_files(capsys, tmp_path, npz_files, renders):
    from sonarsim.analysis.realism import REGIONS

    wreck = np.zeros(renders["full"].polar.shape, dtype=bool)
    wreck[150:250, 4:20] = True  # the block and its surroundings; bin 0 nearest
    np.save(tmp_path / "wreck.npy", wreck)
    write_png(tmp_path / "wreck.png", (wreck[::-1] * 255).astype(np.uint8))  # far range at the top
    expected = compare_images(renders["full"], renders["half"], regions={"wreck": wreck})["stats"]["wreck"]
    assert expected["pixels"] == 1600
    # --region implies --stats; the PNG and the .npy give the same region.
    doc = json.loads(_run(capsys, npz_files["full"], npz_files["half"], "--json",
                          "--region", f"wreck={tmp_path / 'wreck.npy'}",
                          "--region", f"wreck_drawn={tmp_path / 'wreck.png'}")[0])
    assert list(doc["stats"]) == ["all", *REGIONS, "wreck", "wreck_drawn"]
    for name in ("wreck", "wreck_drawn"):
        assert doc["stats"][name] == pytest.approx(expected)
    out, _ = _run(capsys, npz_files["full"], npz_files["half"], "--region", f"wreck_drawn={tmp_path / 'wreck.png'}")
    row = next(line for line in out.splitlines() if line.startswith("wreck_drawn")).split()
    assert int(row[1]) == 1600 and float(row[-3]) == pytest.approx(expected["ks"], abs=1e-3)


def test_compare_region_errors_name_the_option_and_the_file(capsys, tmp_path, npz_files):
    from sonarsim.cli import main as cli

    np.save(tmp_path / "small.npy", np.ones((10, 32), dtype=bool))
    np.save(tmp_path / "float.npy", np.ones((400, 32)))
    (tmp_path / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 20)
    np.save(tmp_path / "fine.npy", np.ones((400, 32), dtype=bool))
    a, b = str(npz_files["full"]), str(npz_files["half"])
    cases = [
        (["x=" + str(tmp_path / "small.npy")], ["--region x=", "small.npy", "(10, 32)", "400 range bins and 32 beams"]),
        (["x=" + str(tmp_path / "float.npy")], ["--region x=", "float.npy", "float64"]),
        (["x=" + str(tmp_path / "broken.png")], ["--region x=", "broken.png", "cannot read the PNG"]),
        (["x=" + str(tmp_path / "nope.npy")], ["--region x=", "nope.npy", "no such file"]),
        (["x=" + a], ["--region x=", "full.npz", "not a region"]),
        (["shadow=" + str(tmp_path / "fine.npy")], ["--region shadow=", "automatic region"]),
        (["x=" + str(tmp_path / "fine.npy")] * 2, ["--region x=", "given twice"]),
    ]
    for specs, words in cases:
        argv = ["compare", a, b] + [arg for spec in specs for arg in ("--region", spec)]
        assert cli.main(argv) == 2, specs
        captured = capsys.readouterr()
        assert captured.out == "" and "Traceback" not in captured.err
        for word in words:
            assert word in captured.err, (word, captured.err)
    for bad in ("x", "=x.npy", "x="):
        with pytest.raises(SystemExit) as exc:
            cli.main(["compare", a, b, "--region", bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert "--region" in err and "NAME=PATH" in err and "Traceback" not in err
