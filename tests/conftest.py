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


def still_doc(doc: dict, name: str, pose) -> dict:
    """A scene-file dict with object ``name`` standing still at ``pose`` (its track dropped): the
    independent reference of a moved or tracked object."""
    out = {**doc, "objects": [dict(o) for o in doc["objects"]]}
    for o in out["objects"]:
        if o["name"] == name:
            o.pop("track", None)
            o["pose"] = pose.to_dict()
    return out


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


# --- the quick subset (``pytest -m quick``) ----------------------------------------------------
#
# A representative fast slice: modules of every layer (core, config, scene, trace, paths,
# reference, renderer, image, sensor, io, analysis, dataset; the command line through
# core/test_interrupts and sensor/test_sensor_presets), chosen for what they cover per second
# (measured with --junitxml). Marked here by module, so that a test file needs no marker of its
# own; a name that is no test file stops the run (pytest_configure), so that none drops out
# silently when a file is renamed.
QUICK_MODULES = frozenset({
    "tests/core/test_core_imports_nothing.py",
    "tests/core/test_heap.py",
    "tests/core/test_interrupts.py",  # the command in subprocesses: Ctrl-C at each import
    "tests/core/test_radiometry.py",
    "tests/core/test_streams.py",
    "tests/core/test_transforms.py",
    "tests/config/test_presets.py",
    "tests/config/test_loader.py",
    "tests/config/test_materials.py",
    "tests/config/test_ground_plane.py",
    "tests/config/test_planes.py",
    "tests/scene/test_primitives.py",
    "tests/scene/test_inside.py",
    "tests/trace/test_backends.py",
    "tests/paths/test_engine.py",
    "tests/reference/test_algorithm2.py",
    "tests/renderer/test_components.py",
    "tests/renderer/test_formation.py",
    "tests/renderer/test_materials.py",
    "tests/image/test_grid.py",
    "tests/image/test_fan.py",
    "tests/image/test_labels.py",
    "tests/image/test_layering.py",
    "tests/sensor/test_bang_hold.py",
    "tests/sensor/test_channels.py",
    "tests/sensor/test_stage.py",
    "tests/sensor/test_pattern_correction.py",
    "tests/sensor/test_tvg_correction.py",
    "tests/sensor/test_sensor_presets.py",  # and render through the command line (in process and not)
    "tests/io/test_npz.py",
    "tests/io/test_output.py",
    "tests/io/test_run_record.py",
    "tests/analysis/test_metrics.py",
    "tests/analysis/test_baselines.py",
    "tests/dataset/test_trajectory.py",
    "tests/dataset/test_variation.py",
    "tests/test_quick_subset.py",
})

_ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config) -> None:
    missing = sorted(m for m in QUICK_MODULES if not (_ROOT / m).is_file())
    if missing:
        raise pytest.UsageError(f"tests/conftest.py QUICK_MODULES names no such test file: {', '.join(missing)}")


def _quick_only(config) -> bool:
    return config.getoption("markexpr", "").strip() == "quick"


def pytest_ignore_collect(collection_path: Path, config) -> bool | None:
    """With ``-m quick``, test files outside :data:`QUICK_MODULES` are not even imported: the
    suite's collection alone (JAX, the viewer, ...) takes half a minute on 2 cores."""
    if not _quick_only(config) or collection_path.suffix != ".py" or not collection_path.name.startswith("test_"):
        return None
    try:
        module = collection_path.resolve().relative_to(_ROOT).as_posix()
    except ValueError:
        return None
    return True if module not in QUICK_MODULES else None


def pytest_collection_modifyitems(config, items) -> None:
    """Mark the tests of :data:`QUICK_MODULES` ``quick``."""
    for item in items:
        try:
            module = item.path.resolve().relative_to(_ROOT).as_posix()
        except ValueError:  # a test file outside the repository (a plugin's)
            continue
        if module in QUICK_MODULES:
            item.add_marker(pytest.mark.quick)
