"""core/ is the bottom layer: it imports nothing of the package (issue 23, item 5).

Every import in src/sonarsim/core/*.py is read with ``ast`` -- at module level and inside
functions (lazy imports count: they close a cycle just the same) -- and none may reach a
sonarsim module outside core, save those in ``ALLOWED``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parents[2] / "src" / "sonarsim" / "core"

# sonarsim.errors: the package's exception types (ConfigError, SonarsimError), which
# core.memory raises so that a budget refusal is the same error as any other bad input. It is a
# leaf (it imports nothing of sonarsim), so it sits below core and closes no cycle; moving it
# into core would change a module that core does not own.
ALLOWED = {"sonarsim.errors"}


def _imports(path: Path) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import in ``path`` (relative ones resolved)."""
    package = ["sonarsim", "core"]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            if node.module is None or module in ("sonarsim", "sonarsim.core"):
                # ``from . import x`` / ``from .. import x``: each name may be a module
                found += [(node.lineno, f"{module}.{alias.name}") for alias in node.names]
            else:
                found.append((node.lineno, module))
    return found


def _outside_core(name: str) -> bool:
    if not (name == "sonarsim" or name.startswith("sonarsim.")):
        return False
    if name == "sonarsim.core" or name.startswith("sonarsim.core."):
        return False
    return not any(name == a or name.startswith(a + ".") for a in ALLOWED)


def test_the_core_modules_are_found():
    names = {p.name for p in CORE.glob("*.py")}
    assert {"__init__.py", "rays.py", "radiometry.py", "memory.py", "transforms.py"} <= names


@pytest.mark.parametrize("path", sorted(CORE.glob("*.py")), ids=lambda p: p.name)
def test_core_imports_nothing_of_the_package(path):
    bad = [f"{path.name}:{line}: {name}" for line, name in _imports(path) if _outside_core(name)]
    assert not bad, "core imports the package above it:\n" + "\n".join(bad)


def test_the_reader_sees_relative_and_lazy_imports(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("from ..config.scene import Scene\n"
                   "def f():\n    from .. import errors\n    import sonarsim.image\n    from .memory import require\n")
    names = [name for _, name in _imports(src)]
    assert names == ["sonarsim.config.scene", "sonarsim.errors", "sonarsim.image", "sonarsim.core.memory"]
    assert [n for n in names if _outside_core(n)] == ["sonarsim.config.scene", "sonarsim.image"]


def test_the_law_codes_are_configs():
    """core.radiometry repeats config.materials' law codes (it may not import them)."""
    from sonarsim.config import materials
    from sonarsim.core import radiometry

    assert (radiometry.LAMBERTIAN, radiometry.LAMBERT, radiometry.ROUGH, radiometry.SEDIMENT) == (
        materials.LAMBERTIAN, materials.LAMBERT, materials.ROUGH, materials.SEDIMENT)
    codes = {"lambertian": radiometry.LAMBERTIAN, "lambert": radiometry.LAMBERT, "rough": radiometry.ROUGH,
             "sediment": radiometry.SEDIMENT, "plate": radiometry.SEDIMENT}  # (every table law: SEDIMENT's code)
    for law in materials.LAWS:
        kw = {"area_m2": 1.0} if law == "plate" else ({"mu": 0.1} if law == "lambert" else {})
        if law == "rough":
            kw = {"specular_strength": 1.0, "roughness": 0.1}
        assert materials.Material(law, **kw).code == codes[law]
        assert (law in materials.TABULATED_LAWS) == (codes[law] == radiometry.SEDIMENT)
    # The kernels' own copy of the tabulated law's code.
    from pathlib import Path
    kernels = (Path(radiometry.__file__).parents[1] / "renderer" / "_kernels.pyx").read_text()
    assert f"cdef int SEDIMENT = {radiometry.SEDIMENT}" in kernels


def test_config_passes_what_ray_sampling_reads():
    """core.rays reads the sonar and the render settings through protocols, not config's classes:
    config's own classes have every member the protocols name."""
    from sonarsim.config.scene import RenderSettings
    from sonarsim.config.sonar import SonarConfig
    from sonarsim.core.rays import RaySettings, SonarGeometry, make_ray_fan

    sonar = SonarConfig.uniform(n_beams=8, azimuth_fov_deg=40.0, elevation_fov_deg=14.0, range_min_m=0.5,
                                range_max_m=6.0, n_range_bins=300)
    settings = RenderSettings()
    for protocol, obj in ((SonarGeometry, sonar), (RaySettings, settings)):
        members = [name for name in vars(protocol) if not name.startswith("_")]
        assert members and all(hasattr(obj, name) for name in members), protocol.__name__
    assert make_ray_fan(sonar, settings).shape[0] == 8
