"""Small scenes for the differentiable engine's quick tests (issue 37): a box and a rough ball
on a ground, 16 beams of 80 range bins, with and without a sensor whose elevation and azimuth
widths are parameters. Compiled in seconds; plain dicts, so that a script of an older sonarsim
can render them too (``data/before_issue37.npz``)."""

from __future__ import annotations

SONAR = {"n_beams": 16, "azimuth_fov_deg": 30.0, "elevation_fov_deg": 20.0, "range_min_m": 0.5, "range_max_m": 4.0,
         "n_range_bins": 80, "pose": {"position_m": [0.0, 0.0, 1.0], "rpy_deg": [0.0, 15.0, 0.0]}}
# (double_beam: paper, as data/before_issue37.npz was made: each reciprocal pair once)
SCENE = {"sonar": SONAR, "render": {"elevation_samples": 24, "max_order": 2, "double_beam": "paper"},
         "ground": {"albedo": 0.5, "specular": 0.5},
         "objects": [{"name": "box", "primitive": "box", "size_m": [0.4, 0.4, 0.4],
                      "pose": {"position_m": [2.5, 0.1, 0.2], "rpy_deg": [0, 0, 30]}, "albedo": 0.7},
                     {"name": "ball", "primitive": "sphere", "radius_m": 0.1, "pose": {"position_m": [2.0, -0.3, 0.3]},
                      "material": {"law": "rough", "albedo": 0.3, "specular_strength": 0.5, "roughness": 0.2}}]}
SENSED = {**SCENE, "sensor": {"elevation_pattern": {"shape": "gaussian", "width_deg": 12.0},
                               "azimuth_pattern": {"shape": "gaussian", "width_deg": 2.0}}}
SCENES = {"plain": SCENE, "sensed": SENSED}
