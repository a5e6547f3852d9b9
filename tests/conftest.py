"""Shared fixtures: small scenes built from dicts, and the location of ../shared data."""

from __future__ import annotations

from pathlib import Path

import pytest

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
