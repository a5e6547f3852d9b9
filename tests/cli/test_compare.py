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
    table = table[:table.index("")] if "" in table else table  # the band tables follow
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


# --------------------------------------------------------------------------------------------
# --stats: B beside the trivial images made from A, per range band, and to a classifier (issue 22)
# --------------------------------------------------------------------------------------------


def _pattern(n_ranges: int = 200, n_beams: int = 64) -> np.ndarray:
    """A floor band that fades across the fan, and an object's echo beyond it, in counts."""
    rows, cols = np.arange(n_ranges)[:, None], np.arange(n_beams)[None, :]
    band = 90.0 * np.exp(-0.5 * ((rows - 90) / 22.0) ** 2) * np.cos((cols - 31.5) / 40.0) ** 2
    blob = 120.0 * np.exp(-0.5 * (((rows - 160) / 6.0) ** 2 + ((cols - 40) / 4.0) ** 2))
    return 6.0 + band + blob


@pytest.fixture(scope="module")
def synthetic_recording(tmp_path_factory):
    """Three 8-bit Oculus pings of :func:`_pattern` under speckle drawn anew in each (gamma, contrast
    0.35), and PNGs of the pattern itself (a model with the right structure) and of a flat image."""
    from tests.io.test_readers import ascending_bearings, oculus_message

    folder = tmp_path_factory.mktemp("recording")
    truth = _pattern()
    rng = np.random.default_rng(3)
    pings = [np.clip(np.round(truth * rng.gamma(8.0, 1.0 / 8.0, truth.shape)), 0, 255) for _ in range(3)]
    # Oculus files hold the port beam first; the reader flips nothing for ascending bearings.
    (folder / "pings.raw").write_bytes(b"".join(
        oculus_message(p.astype(np.uint32), ascending_bearings(truth.shape[1]), ping_id=k + 1)
        for k, p in enumerate(pings)))
    write_png(folder / "truth.png", np.round(truth[::-1]).astype(np.uint8))  # far range at the top
    write_png(folder / "flat.png", np.full(truth.shape, int(truth.mean()), np.uint8))
    return folder


def test_compare_stats_scores_b_beside_the_trivial_images_on_a_held_out_frame(capsys, synthetic_recording):
    pings, truth = synthetic_recording / "pings.raw", synthetic_recording / "truth.png"
    doc = json.loads(_run(capsys, pings, truth, "--stats", "--json")[0])
    rep = doc["realism"]
    # The default held-out frame: the one after A's; nothing was made from it.
    assert rep["calibration_frame"] == 0 and rep["held_out_frames"] == [1] and rep["optimistic"] is False
    assert "made from frame 0" in rep["note"] and "held-out frame 1" in rep["note"]
    scores = rep["scores"]
    assert set(scores) == {"model", "range profile", "separable", "ceiling"}
    # The pattern has 2D structure (the object) that no trivial image holds.
    assert rep["margin_db"] == pytest.approx(scores["model"]["psnr"] - scores[rep["best_baseline"]]["psnr"])
    assert rep["margin_db"] > 1.0 and rep["warning"] is None and rep["below_baseline"] is False
    assert [len(rep["bands"][r]) for r in ("lit", "water")] == [8, 8]
    assert rep["bands"]["lit"][0]["range_m"][0] < rep["bands"]["lit"][-1]["range_m"][1]
    assert rep["beam_profile"]["beams"] == 64
    # A smooth image against speckled pings: the classifier tells them apart at once.
    assert rep["c2st"]["accuracy"] > 0.9 and rep["c2st"]["n_tested"] > 100

    doc = json.loads(_run(capsys, pings, truth, "--held-out", "2", "--held-out", "1", "--json")[0])  # implies --stats
    assert doc["realism"]["held_out_frames"] == [2, 1] and "stats" in doc
    doc = json.loads(_run(capsys, pings, truth, "--frame-a", "2", "--stats", "--json")[0])
    assert doc["realism"]["calibration_frame"] == 2 and doc["realism"]["held_out_frames"] == [1]
    # B a frame of the same recording: not scored on its own frame.
    doc = json.loads(_run(capsys, pings, pings, "--frame-b", "1", "--stats", "--json")[0])
    assert doc["realism"]["held_out_frames"] == [2]
    with pytest.raises(SonarsimError, match="--held-out 0: that is A's frame"):
        _run(capsys, pings, truth, "--held-out", "0")


def test_compare_stats_table_and_the_warning_below_a_trivial_image(capsys, synthetic_recording):
    pings = synthetic_recording / "pings.raw"
    out, err = _run(capsys, pings, synthetic_recording / "truth.png", "--stats")
    lines = out.splitlines()
    scores = {line.split()[0]: line.split() for line in lines[lines.index("image            PSNR dB     SSIM  margin dB"):]
              if line.split() and line.split()[0] in ("B", "separable", "ceiling")}
    assert set(scores) == {"B", "separable", "ceiling"} and float(scores["B"][3]) > 1.0
    assert [line.split()[0] for line in lines if line.startswith(("lit/", "water/"))] == (
        [f"lit/{k}" for k in range(8)] + [f"water/{k}" for k in range(8)])
    assert any(line.startswith("beam profile over the lit region: B - A RMS") for line in lines)
    assert any(line.startswith("classifier two-sample test (0.5 = indistinguishable): accuracy") for line in lines)
    assert "warning" not in err

    # A flat image scores below the range profile of A: one line on stderr, in the JSON too.
    out, err = _run(capsys, pings, synthetic_recording / "flat.png", "--stats")
    warnings = [line for line in err.splitlines() if "warning" in line]
    assert len(warnings) == 1 and warnings[0].startswith("sonarsim: warning: B: the model scores")
    assert "below the trivial" in warnings[0]
    doc = json.loads(_run(capsys, pings, synthetic_recording / "flat.png", "--stats", "--json")[0])
    assert doc["realism"]["below_baseline"] is True and doc["realism"]["margin_db"] < 0


def test_compare_stats_with_one_frame_says_its_figures_are_optimistic(capsys, npz_files):
    out, _ = _run(capsys, npz_files["full"], npz_files["full"], "--stats")
    assert "one real frame" in out and "optimistic figures" in out
    doc = json.loads(_run(capsys, npz_files["full"], npz_files["half"], "--stats", "--json")[0])
    assert doc["realism"]["optimistic"] is True and doc["realism"]["held_out_frames"] == [0]
    # Too few lit pixels per band in this small render: marked with a reason, null in strict JSON.
    marked = [b for b in doc["realism"]["bands"]["lit"] if not b["ok"]]
    assert marked and all(b["ks"] is None and "fewer than" in b["reason"] for b in marked)


def test_compare_stats_on_the_real_oculus_pings(capsys, shared_data):
    # Ping 1 as "B" against ping 0's trivial images, scored on ping 2 (the default: not B's frame).
    # Consecutive pings agree to 27 dB: far above the trivial images (19.2 dB) and the ceiling (21.3);
    # to the classifier ping 1 and ping 2 are indistinguishable (a little below 0.5: the speckle
    # is frozen between pings, so a patch's near-twin in training has the other label).
    three = shared_data / "real" / "oculus" / "three_pings_8bit.raw"
    doc = json.loads(_run(capsys, three, three, "--frame-b", "1", "--stats", "--json")[0])
    rep = doc["realism"]
    assert rep["held_out_frames"] == [2] and rep["best_baseline"] == "separable"
    assert rep["scores"]["separable"]["psnr"] == pytest.approx(19.2, abs=0.1)
    assert rep["scores"]["ceiling"]["psnr"] == pytest.approx(21.35, abs=0.1)
    assert rep["scores"]["model"]["psnr"] == pytest.approx(26.7, abs=0.2) and rep["margin_db"] > 7
    assert 0.44 < rep["c2st"]["accuracy"] < 0.5 + 3 * rep["c2st"]["null_standard_error"]
    assert rep["band_summary"]["lit"]["bands_ok"] == 8 and rep["band_summary"]["lit"]["max_ks"] < 0.1
