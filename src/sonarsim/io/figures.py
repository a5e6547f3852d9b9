"""Figures made of several images: the paper's Fig. 9 comparison of bounce variants, and the
multipath families of a tank (direct echoes, ghosts via the water surface, via the walls)."""

from __future__ import annotations

import numpy as np

from .output import to_uint8

# Grey level of the pixels outside the fan in the multipath figure (inside, no echo is black).
OUTSIDE_FAN_GREY = 72

# (title, components summed) of the paper's Fig. 9 panels (b)-(d).
BOUNCE_VARIANTS = (
    ("single", ("single",)),
    ("single + triple", ("single", "triple")),
    ("all bounces", ("single", "double", "triple")),
)


def bounce_comparison(image, pixel_size_m: float | None = None, mapping: str = "db",
                      gain_db: float = 0.0, dynamic_range_db: float = 40.0, gap_px: int = 8) -> np.ndarray:
    """Fan views of single, single + triple and all bounces side by side (paper Fig. 9).

    All panels share one intensity reference (the maximum of the all-bounce image), so their
    brightness compares directly.

    Parameters
    ----------
    image : SonarImage
        A render with its ``components``.

    Returns
    -------
    (H, 3 W + 2 gap_px) uint8 ndarray
    """
    from ..image.fan import FanMapper

    s = image.sonar
    mapper = FanMapper(s.n_range_bins, s.range_min_m, s.range_max_m, image.azimuth_deg, pixel_size_m)
    # Orders beyond the render's max_order are absent: they add nothing to a panel.
    comp = image.components
    panels = [mapper(sum(comp[k].astype(np.float64) for k in keys if k in comp)) for _, keys in BOUNCE_VARIANTS]
    ref = float(panels[-1].image.max()) or None
    tiles = [to_uint8(p.image, mapping, gain_db, dynamic_range_db, reference=ref, mask=p.mask) for p in panels]
    gap = np.full((tiles[0].shape[0], gap_px), 255, dtype=np.uint8)
    return np.concatenate([tiles[0], gap, tiles[1], gap, tiles[2]], axis=1)


def path_families(image) -> list[tuple[str, np.ndarray]]:
    """(title, polar image) of a tank's path families: all paths, direct echoes, paths that meet
    the water surface, paths that meet a wall (planes named ``*surface*`` and ``*wall*``), and
    where objects mirror (``specular`` > 0), the paths that meet one of them (their ghosts)."""
    from ..paths.engine import parse_path_name

    comp = image.components
    zero = np.zeros(image.polar.shape)
    surface, wall, mirrored = zero.copy(), zero.copy(), zero.copy()
    mirrors = [o.get("name") for o in image.config.get("objects", []) if o.get("specular", 0) > 0]
    for name in comp.signatures:
        tx, _, rx = parse_path_name(name)
        met = set(tx) | set(rx)
        if any("surface" in p for p in met):
            surface += comp[name]
        if any("wall" in p for p in met):
            wall += comp[name]
        if met & set(mirrors):
            mirrored += comp[name]
    order = image.config.get("render", {}).get("max_order", 3)
    out = [
        (f"all paths up to order {order}", comp["total"]),
        ("direct echoes (order 1)", comp["single"]),
        ("ghosts: paths that meet the water surface", surface),
        ("ghosts: paths that meet a wall", wall),
    ]
    if mirrors:
        names = " and ".join(n.replace("_", " ") for n in mirrors)
        out.append((f"ghosts: paths that meet the {names} (mirror)", mirrored))
    return out


def multipath_comparison(image, pixel_size_m: float | None = None, mapping: str = "db", gain_db: float = 0.0,
                         dynamic_range_db: float = 40.0, gap_px: int = 10, title_px: int = 34) -> np.ndarray:
    """Fan views of a tank's path families in a labelled grid, two across.

    All paths | direct echoes; paths that meet the water surface | paths that meet a wall (by
    plane name: planes named ``*surface*`` and ``*wall*``); the paths that meet a mirroring
    object, where there is one. One intensity reference (the
    maximum of all paths) for every panel, so their brightness compares directly.

    Parameters
    ----------
    image : SonarImage
        A render with path-signature components.

    Returns
    -------
    (rows (H + title_px) + (rows - 1) gap_px, 2 W + gap_px) uint8 ndarray
    """
    from PIL import Image, ImageDraw, ImageFont

    from ..image.fan import FanMapper

    s = image.sonar
    mapper = FanMapper(s.n_range_bins, s.range_min_m, s.range_max_m, image.azimuth_deg, pixel_size_m)
    panels = path_families(image)
    fans = [mapper(np.asarray(img, dtype=np.float64)) for _, img in panels]
    ref = float(fans[0].image.max()) or None
    tiles = [to_uint8(f.image, mapping, gain_db, dynamic_range_db, reference=ref, mask=f.mask) for f in fans]
    for tile, f in zip(tiles, fans):
        tile[~f.mask] = OUTSIDE_FAN_GREY  # so that the fan's outline shows against "no echo"
    h, w = tiles[0].shape
    try:
        font = ImageFont.load_default(size=max(10, title_px * 2 // 3))
    except (OSError, TypeError):  # Pillow without FreeType: the small bitmap font
        font = ImageFont.load_default()
    rows = -(-len(tiles) // 2)
    canvas = Image.new("L", (2 * w + gap_px, rows * (h + title_px) + (rows - 1) * gap_px), 255)
    draw = ImageDraw.Draw(canvas)
    for k, ((title, _), tile) in enumerate(zip(panels, tiles)):
        x, y = (k % 2) * (w + gap_px), (k // 2) * (h + title_px + gap_px)
        canvas.paste(Image.fromarray(tile), (x, y + title_px))
        draw.text((x + 6, y + 4), title, fill=0, font=font)
    return np.asarray(canvas)


def labelled_row(tiles: list[np.ndarray], titles: list[str], gap_px: int = 10, title_px: int = 30) -> np.ndarray:
    """uint8 tiles of one height side by side, each under its title (white background)."""
    from PIL import Image, ImageDraw, ImageFont

    h = max(t.shape[0] for t in tiles)
    try:
        font = ImageFont.load_default(size=max(10, title_px * 2 // 3))
    except (OSError, TypeError):  # Pillow without FreeType: the small bitmap font
        font = ImageFont.load_default()
    width = sum(t.shape[1] for t in tiles) + gap_px * (len(tiles) - 1)
    canvas = Image.new("L", (width, h + title_px), 255)
    draw = ImageDraw.Draw(canvas)
    x = 0
    for tile, title in zip(tiles, titles):
        canvas.paste(Image.fromarray(tile), (x, title_px))
        draw.text((x + 6, 4), title, fill=0, font=font)
        x += tile.shape[1] + gap_px
    return np.asarray(canvas)


def device_tile(polar: np.ndarray, image, full_scale: float, pixel_size_m: float | None = None) -> np.ndarray:
    """Fan view of an image in a device's units, shown as they are (0..full scale -> 0..255)."""
    from ..image.fan import FanMapper

    s = image.sonar
    fan = FanMapper(s.n_range_bins, s.range_min_m, s.range_max_m, image.azimuth_deg, pixel_size_m)(
        np.asarray(polar, dtype=np.float64))
    tile = np.clip(fan.image / full_scale * 255.0, 0, 255).astype(np.uint8)
    tile[~fan.mask] = OUTSIDE_FAN_GREY
    return tile


def sensor_comparison(recorded, expected, device: str, full_scale: float, pixel_size_m: float | None = None,
                      dynamic_range_db: float = 40.0, ideal=None) -> np.ndarray:
    """The renderer's ideal image | as the device records it | the device's expected output.

    Parameters
    ----------
    recorded : SonarImage
        A render with a sensor (``polar`` in device units; ``components["total"]`` ideal).
    expected : SonarImage
        The same frame with ``speckle=False``.
    device : str
        Its name, for the titles.
    full_scale : float
        The device's largest value (255 for 8-bit).
    ideal : SonarImage, optional
        The scene rendered without the sensor (the paper's ideal image); default
        ``recorded.components["total"]``, formed over the sensor's ray span.
    """
    from ..image.fan import FanMapper

    s = recorded.sonar
    fan = FanMapper(s.n_range_bins, s.range_min_m, s.range_max_m, recorded.azimuth_deg, pixel_size_m)(
        np.asarray(recorded.components["total"] if ideal is None else ideal.polar, dtype=np.float64))
    ideal = to_uint8(fan.image, "db", 0.0, dynamic_range_db, mask=fan.mask)
    ideal[~fan.mask] = OUTSIDE_FAN_GREY
    tiles = [ideal, device_tile(recorded.polar, recorded, full_scale, pixel_size_m),
             device_tile(expected.polar, expected, full_scale, pixel_size_m)]
    return labelled_row(tiles, ["ideal (the paper's model, dB)", f"as {device} records it",
                                f"{device}: expected (no speckle)"])
