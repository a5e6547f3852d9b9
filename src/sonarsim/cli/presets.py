"""The ``sonarsim presets`` command: the built-in sonar presets as a table or JSON."""

from __future__ import annotations

import argparse
from typing import Any

__all__ = ["add_presets_parser", "cmd_presets"]


def add_presets_parser(subparsers: Any) -> argparse.ArgumentParser:
    """Add the ``presets`` sub-command to an ``add_subparsers()`` object; sets ``func=cmd_presets``."""
    p = subparsers.add_parser("presets", help="list the sonar presets",
                              description="List the built-in sonar presets with their main figures.")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=cmd_presets)
    return p


def cmd_presets(args) -> None:
    import json

    from ..config.presets import PRESETS

    rows = []
    for name, p in PRESETS.items():
        from ..config.loader import parse_sonar

        s = parse_sonar({"preset": name}, None)
        rows.append({
            "name": name, "n_beams": s.n_beams, "azimuth_fov_deg": round(s.azimuth_fov_deg, 2),
            "elevation_fov_deg": s.elevation_fov_deg, "range_min_m": s.range_min_m, "range_max_m": s.range_max_m,
            "n_range_bins": s.n_range_bins, "frequency_khz": s.frequency_khz, "description": p.description,
        })
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    head = f"{'name':<22} {'beams':>5} {'az fov':>7} {'el fov':>6} {'range m':>11} {'bins':>5} {'kHz':>6}  description"
    print(head)
    for r in rows:
        rng = f"{r['range_min_m']:g}-{r['range_max_m']:g}"
        khz = f"{r['frequency_khz']:g}" if r["frequency_khz"] else "-"
        print(f"{r['name']:<22} {r['n_beams']:>5} {r['azimuth_fov_deg']:>7g} {r['elevation_fov_deg']:>6g} "
              f"{rng:>11} {r['n_range_bins']:>5} {khz:>6}  {r['description']}")
