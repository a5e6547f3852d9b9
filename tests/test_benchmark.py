"""Smoke test: the benchmark script runs end to end at tiny sizes (no timing is asserted)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def test_benchmark_runs_at_tiny_sizes(tmp_path):
    out = tmp_path / "bench.json"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_render.py"), "--quick", "--json", str(out)],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "frame/cast" in proc.stdout
    res = json.loads(out.read_text())
    assert [c["case"][:2] for c in res["cases"]] == ["a:", "b:", "c:", "d:", "e:", "f:", "g:", "h:", "i:", "a "]
    assert res["machine"]["cpu_model"]
    for c in res["cases"]:
        assert c["frame_ms"] > 0 and c["bare_cast_ms"] > 0 and c["rays_per_frame"] > 0 and c["build_s"] > 0
        assert c["frame_over_cast"] == c["frame_ms"] / c["bare_cast_ms"]
    assert res["speedup_fast_over_paper"] > 0
    assert res["peak_memory_b"]["process_peak_rss_mb"] > 0
    # The sensor stage: frames with and without it, the stage alone, the full preset's wider span.
    sensor = res["sensor"]
    for key in ("frame_no_sensor_ms", "frame_sensor_ms", "frame_sensor_expected_ms", "stage_ms", "stage_expected_ms",
                "frame_full_preset_ms"):
        assert sensor[key] > 0, key
    assert sensor["stage_fraction_of_frame"] == sensor["stage_ms"] / sensor["frame_sensor_ms"]
    assert sensor["elevation_span_deg_full_preset"] == 42.0
    assert sensor["primary_rays_full_preset"] >= sensor["primary_rays"] > 0
    assert "sensor stage" in proc.stdout
    assert len(res["sweep_rays"]) >= 2 and len(res["sweep_triangles"]) >= 2
    # The sweeps really vary what they claim to.
    rays = [r["rays_per_frame"] for r in res["sweep_rays"]]
    tris = [r["triangles"] for r in res["sweep_triangles"]]
    assert rays == sorted(rays) and len(set(rays)) == len(rays)
    assert tris == sorted(tris) and len(set(tris)) == len(tris)
    assert [r["planes"] for r in res["sweep_planes"]] == [1, 3]
    assert [r["max_order"] for r in res["sweep_order"]] == [1, 3]
    # More planes and a higher order cast more rays (reflected ones) in the same tank.
    assert res["sweep_planes"][1]["rays_per_frame"] > res["sweep_planes"][0]["rays_per_frame"]
    assert res["sweep_order"][1]["rays_per_frame"] > res["sweep_order"][0]["rays_per_frame"]
    # More beams cast about proportionally more rays (primary and reflected); the big cases are
    # what they say.
    beams = res["sweep_beams"]
    assert 1.8 < beams[1]["rays_per_frame"] / beams[0]["rays_per_frame"] < 2.2
    by_case = {c["case"][:2]: c for c in res["cases"]}
    assert 7.0 < by_case["g:"]["rays_per_frame"] / by_case["a:"]["rays_per_frame"] < 9.0
    assert by_case["h:"]["image"].startswith("8000 x") and by_case["i:"]["triangles"] >= 20_000
    # The cost model: one exponent per sweep, for the frame and for bare casting.
    model = res["cost_model_exponents"]
    assert set(model) == {"rays (elevation samples)", "beams", "range bins", "triangles",
                          "reflecting planes (order 3)", "path order (6 planes)"}
    assert all(np.isfinite(e["frame"]) and np.isfinite(e["bare_cast"]) for e in model.values())
    workers = res["two_single_threaded_workers"]
    assert workers["single_threaded_workers_fps"] > 0 and workers["one_simulator_all_cores_fps"] > 0


def test_realism_benchmark_skips_cleanly_without_the_data(tmp_path):
    out = tmp_path / "realism.json"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_realism.py"), "--data", str(tmp_path / "absent.raw"),
         "--json", str(out)], capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert "skipped" in proc.stderr and "absent.raw" in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists()


def test_bench_against_measures_two_trees_in_turn(tmp_path):
    out = tmp_path / "against.json"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_against.py"), str(ROOT), str(ROOT), "--runs", "1",
         "--repeats", "5", "--json", str(out)], capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count("frame/cast") == 2
    res = json.loads(out.read_text())
    (runs,) = res.values()  # the same tree twice: one entry, two runs
    assert len(runs) == 2
    for r in runs:
        assert r["demo_frame_ms"] > 0 and r["demo_frame_over_cast"] == r["demo_frame_ms"] / r["demo_bare_cast_ms"]
        assert r["tank_over_demo"] == r["tank_frame_ms"] / r["demo_frame_ms"]
    bad = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_against.py"), str(tmp_path), str(ROOT)],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode != 0 and "not a sonarsim checkout" in bad.stderr and "Traceback" not in bad.stderr


def test_the_differentiable_benchmark_runs_at_tiny_sizes(tmp_path):
    import pytest

    pytest.importorskip("jax")
    out = tmp_path / "diff.json"
    proc = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_diff.py"), "--quick", "--json", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    (case,) = json.loads(out.read_text())["cases"]
    assert case["image"] == [1288, 128] and case["paths"] > 10_000 and case["parameters"] > 20
    for key in ("compiled_frame_ms", "forward_ms", "value_and_grad_ms", "batch_frames_per_s", "compile_value_and_grad_s"):
        assert case[key] > 0, key
    assert case["value_and_grad_over_compiled"] == case["value_and_grad_ms"] / case["compiled_frame_ms"]
    assert "value and gradient" in proc.stdout
