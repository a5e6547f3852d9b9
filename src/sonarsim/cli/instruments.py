"""``sonarsim render`` for a scene with instruments: each instrument's pings into its film's files.

An FLS writes what ``render`` always wrote (``polar.png``, ``fan.png``, ``render.npz``, in a
folder named after it when the scene has several instruments); a side-scan writes its waterfall
(``NAME_waterfall.png``: port on the left far to near, starboard near to far, the first ping at
the top; ``NAME_ground_range.png``, slant-corrected; ``NAME.npz``: samples, per-ping geometry,
labels; ``NAME_figure.png``); a scanning sonar its scan (``NAME_scan.png``, samples x steps, far
range up) and its top view (``NAME_top.png``); a single-beam its echogram; a multibeam its
soundings' depths (pings x beams) and its first ping's water column. Each writes ``NAME.npz``
(every array of its film, ``sonarsim.image.films``).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..core.console import log as _log

__all__ = ["instrument_files", "render_instruments", "WATERFALL_FILES"]

#: What a side-scan writes, per instrument (``{name}`` its name).
WATERFALL_FILES = ("{name}_waterfall.png", "{name}_ground_range.png", "{name}.npz")
#: What each other type writes.
FILM_FILES = {"sidescan": WATERFALL_FILES, "scanning": ("{name}_scan.png", "{name}_top.png", "{name}.npz"),
              "singlebeam": ("{name}_echogram.png", "{name}.npz"), "multibeam": ("{name}_depth.png", "{name}.npz")}


def _chosen(scene, args) -> list:
    chosen = getattr(args, "instrument", None)
    if chosen is None:
        return list(scene.instruments)
    specs = [s for s in scene.instruments if s.name == chosen]
    if not specs:
        from ..errors import ConfigError

        raise ConfigError("--instrument", f"no instrument {chosen!r} in the scene; it has: "
                          f"{', '.join(s.name for s in scene.instruments)}")
    return specs


#: The instrument type whose pings each film of a recording is.
TYPE_OF_FILM = {"waterfall": "sidescan"}


def read_along(path, pings):
    """The film of ``--along``'s recording (``--pings A:B`` of it), a side-scan's waterfall."""
    from ..errors import ConfigError
    from ..io.readers import FILMS, detect_format, open_recording
    from ..instruments.replay import ping_slice

    film = FILMS.get(detect_format(path), "polar")
    if film not in TYPE_OF_FILM:
        raise ConfigError("--along", f"{path} holds {film} frames; --along replays a side-scan recording's pings "
                          "(an XTF side-scan file)")
    with open_recording(path, film) as recording:
        chosen = ping_slice(recording.n_frames, pings, str(path))
        return getattr(recording, film)(slice(chosen.start, chosen.stop))


def _along_instrument(scene, args, film):
    """The scene's instrument that replays ``film`` (``--instrument``, or the first of its type)."""
    from ..errors import ConfigError

    kind = TYPE_OF_FILM["waterfall"]
    specs = [s for s in _chosen(scene, args) if s.type_name == kind]
    if not specs:
        raise ConfigError("--along", f"the scene has no {kind} instrument to replay the recording's pings with"
                          + (f" (--instrument {args.instrument} is not one)" if getattr(args, "instrument", None) else ""))
    return specs[0]


def _render_along(sim, spec, film, speckle):
    """The recording's pings rendered where its geometry puts the vehicle, in its layout."""
    from dataclasses import replace

    from ..instruments import RENDERERS
    from ..instruments.replay import poses_from_geometry

    layout = replace(spec, range_min_m=film.range_min_m, range_max_m=film.range_max_m, n_samples=film.n_samples)
    poses = poses_from_geometry(sim.scene, film.geometry)
    t = film.geometry.time_s
    times = np.where(np.isfinite(t), t, 0.0)
    return RENDERERS[spec.type_name](sim, layout, poses, times, 0, speckle, True)


def instrument_files(scene, args, fls_files: list[str]) -> list[str]:
    """The files ``render`` writes for the scene's instruments (``--instrument``: one);
    ``fls_files``: what an FLS writes (``cli.render.render_files``)."""
    specs = _chosen(scene, args)
    if getattr(args, "along", None) is not None:
        specs = [_along_instrument(scene, args, None)]
    names: list[str] = []
    for spec in specs:
        if spec.type_name == "fls":
            prefix = f"{spec.name}/" if len(specs) > 1 else ""
            names += [prefix + f for f in fls_files]
        else:
            names += [f.format(name=spec.name) for f in FILM_FILES.get(spec.type_name, ("{name}.npz",))]
    return names


def _film_pictures(kind: str, name: str, film, args):
    """The exact-pixel PNGs of a film (name -> uint8 image) and its figure's builder."""
    from ..image.levels import to_uint8
    from ..plot.films import envelope_figure, soundings_figure, waterfall_figure

    db = lambda a: to_uint8(np.nan_to_num(np.asarray(a, np.float64)), args.mapping or "db", args.gain_db,  # noqa: E731
                            args.dynamic_range_db)
    if kind == "sidescan":
        ground, _ = film.ground_range()
        return ({f"{name}_waterfall.png": _waterfall_png(film.display(), args),
                 f"{name}_ground_range.png": _waterfall_png(film.display(ground), args)},
                lambda: waterfall_figure(film, args.dynamic_range_db, args.gain_db,
                                         title=f"{name}: {film.n_pings} pings rendered"))
    if kind == "scanning":
        return ({f"{name}_scan.png": db(film.samples[::-1]), f"{name}_top.png": db(film.cartesian())}, None)
    if kind == "singlebeam":
        return ({f"{name}_echogram.png": db(film.samples.T)}, lambda: envelope_figure(film, args.dynamic_range_db))
    # multibeam: the first ping's water column (range up) and the soundings' depths
    pictures = {f"{name}_depth.png": to_uint8(np.nan_to_num(-film.head_points()[..., 2]), "linear")}
    if film.water_column is not None:
        pictures[f"{name}_water_column.png"] = db(film.water_column[0][::-1])
    return pictures, lambda: soundings_figure(film)


def _waterfall_png(samples: np.ndarray, args) -> np.ndarray:
    from ..image.levels import to_uint8

    finite = np.nan_to_num(samples, nan=0.0)
    return to_uint8(finite, args.mapping or "db", args.gain_db, args.dynamic_range_db)


def render_instruments(scene, out: Path, args, run=None, render_fls=None) -> list:
    """Render every instrument of ``scene`` (or ``--instrument``) and write their files into ``out``;
    an FLS through ``render_fls(scene, folder, args, run)`` (``cli.render.render_and_write``).

    Returns
    -------
    list
        Each instrument's film, in order.
    """
    from ..errors import ConfigError
    from ..instruments import instrument, render_pings
    from ..io.output import write_png
    from ..renderer.simulator import Simulator

    sim = Simulator(scene, backend=args.backend)
    names = [s.name for s in _chosen(scene, args)]
    n_pings = getattr(args, "pings", None)
    trajectory = None
    if getattr(args, "trajectory", None) is not None:
        from ..dataset.trajectory import read_trajectory

        if getattr(args, "along", None) is not None:
            raise ConfigError("--trajectory", "the vehicle's poses come from --along's recording; give one of the two")
        trajectory = read_trajectory(args.trajectory, key="--trajectory")
    along = None
    if getattr(args, "along", None) is not None:
        along = read_along(args.along, n_pings)
        names = [_along_instrument(scene, args, along).name]
    elif isinstance(n_pings, tuple):
        raise ConfigError("--pings", "A:B chooses pings of a recording (with --along); give a number of pings")
    films = []
    out.mkdir(parents=True, exist_ok=True)
    for name in names:
        spec = instrument(sim, name)
        t0 = time.perf_counter()
        if spec.type_name == "fls":
            from dataclasses import replace

            pose = sim.scene.vehicle_pose
            from ..config.instruments import mounted

            sub = out / name if len(names) > 1 else out  # (instrument_files names them so)
            fls_scene = replace(scene, sonar=spec.sonar, sonar_pose=mounted(pose, spec.mount))
            films.append(render_fls(fls_scene, sub, args, run))
            continue
        speckle = False if getattr(args, "no_speckle", False) else None
        if along is not None:
            film = _render_along(sim, spec, along, speckle)
        else:
            default = 400 if spec.type_name == "scanning" else 100  # (a Ping360's turn)
            count = n_pings if n_pings is not None else (None if trajectory is not None else default)
            film = render_pings(sim, name, n_pings=count, trajectory=trajectory, speckle=speckle,
                                labels=spec.type_name == "sidescan")
        t1 = time.perf_counter()
        images, figure = _film_pictures(spec.type_name, name, film, args)
        for fname, png in images.items():  # all made before any is written
            if run is not None:
                run.add(out / fname)
            write_png(out / fname, png)
        if run is not None:
            run.add(out / f"{name}.npz")
        film.save_npz(out / f"{name}.npz")
        from .figures import write_figure

        if figure is not None:
            write_figure(args, out / f"{name}_figure", figure, run)
        _log(f"{name}: {spec.type_name} pings rendered in {t1 - t0:.3f} s; "
             f"wrote {', '.join(str(out / f) for f in (*images, name + '.npz'))}")
        films.append(film)
    sim.close()
    return films
