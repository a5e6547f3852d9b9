"""Shared fixtures: small scenes built from dicts, renders to compare, and the location of
../shared data."""

from __future__ import annotations

from pathlib import Path

import pytest

import sonarsim

SHARED = Path(__file__).resolve().parents[2] / "shared"


@pytest.fixture
def shared_data() -> Path:
    """``../shared/data`` beside the clone; tests that need it skip when it is absent."""
    path = SHARED / "data"
    if not path.is_dir():
        pytest.skip("../shared/data is not present")
    return path


def sonar_dict(**overrides) -> dict:
    """A small uniform sonar at the origin looking along +x."""
    d = {
        "n_beams": 32,
        "azimuth_fov_deg": 30.0,
        "elevation_fov_deg": 14.0,
        "range_min_m": 0.5,
        "range_max_m": 5.0,
        "n_range_bins": 400,
        "pose": {"position_m": [0.0, 0.0, 0.0], "rpy_deg": [0.0, 0.0, 0.0]},
    }
    d.update(overrides)
    return d


# Renders shared by the comparison tests (tests/analysis) and the compare command (tests/cli).


def block_scene_dict(**sonar) -> dict:
    """A block on a floor seen from 1 m up, tilted 20 degrees down (ground, shadow, echoes)."""
    return {
        "sonar": sonar_dict(pose={"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 20.0, 0.0]}, **sonar),
        "render": {"elevation_samples": 32},
        "ground": {"height_m": 0.0, "albedo": 0.5, "specular": 0.5},
        "objects": [{"name": "block", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
                     "pose": {"position_m": [2.5, 0.2, 0.2], "rpy_deg": [0, 0, 30]}}],
    }


@pytest.fixture(scope="module")
def renders():
    """The same scene at full and half range resolution, and in a disjoint range window."""
    return {
        "full": sonarsim.render(block_scene_dict()),
        "half": sonarsim.render(block_scene_dict(n_range_bins=200)),
        "far": sonarsim.render(block_scene_dict(range_min_m=6.0, range_max_m=9.0, n_range_bins=100)),
        "narrow": sonarsim.render(
            block_scene_dict(range_max_m=4.5, n_range_bins=300, n_beams=48, azimuth_fov_deg=24.0)
        ),
    }


@pytest.fixture(scope="module")
def npz_files(renders, tmp_path_factory):
    folder = tmp_path_factory.mktemp("npz")
    paths = {}
    for key, image in renders.items():
        paths[key] = folder / f"{key}.npz"
        image.save_npz(paths[key])
    return paths
