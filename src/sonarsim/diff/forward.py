"""The differentiable forward: a held search's paths formed again from the parameters (JAX).

One pure function, :func:`form_stack`, maps the parameters (a flat dict of JAX arrays, see
:mod:`sonarsim.diff.params`) and the frame's held search (:class:`~sonarsim.diff.search.Search`
as arrays) to the image stack, doing what the compiled engine does after its search, in the
same order:

1. **The fan.** Each path's fan ray, rotated by the sonar's roll-pitch-yaw
   (``R = Rz(yaw) Ry(pitch) Rx(roll)``, :mod:`sonarsim.core.transforms`), from the sonar's
   position.
2. **The receive leg.** The ray is reflected off the ``g`` mirrors of its chain in order
   (``t = (offset - n.o) / (n.d)``, ``d' = d - 2 (n.d) n``): planes, and the triangles of
   mirroring objects it met, their planes posed from the objects' vertices (so a mirror's pose
   and vertices turn the reflected rays); each mirror's specular reflectance is multiplied into
   the leg's attenuation. The leg ends on its scatterer: a plane, or the plane of the
   object's triangle the search found, its corners posed and scaled from the object's own mesh
   (the hit point slides on that triangle's plane as the parameters move).
3. **The weight.** ``w(ray) l(r) f(cos alpha)``: the fan ray's weight (beam patterns), the
   range law (``1 / r^2`` without TVG), the surface's law (``albedo cos`` or ``mu cos``, plus the
   rough law's Kirchhoff lobe), held texture factors.
4. **The transmit leg.** The receive leg reversed (its length again), or the scatterer
   unfolded by the transmit chain's mirrors, planes or mesh mirrors' planes (image sources,
   ``A* = M_1(M_2(... M_K(A)))``),
   ``|A* - O|`` long, times the chain's reflectances.
5. **The splat** (:func:`splat`): each path's energy spread uniformly over its range cell,
   from the midpoints towards its neighbours in the ray column (the compiled engine's range
   splatting), deposited exactly into range bins.

The splat is differentiable because it is written as differences of ramps: a cell ``[lo, hi]``
of density ``rho`` puts ``rho * (h(lo) - h(hi))`` into the bins, where ``h_x(b) = clip(b + 1 -
x, 0, 1)`` is, along the range axis, the running sum of ``1 - frac(x)`` at ``floor(x)`` and
``frac(x)`` at ``floor(x) + 1``. Four scattered values per path and one running sum per
column form the image; the bins' values are piecewise linear in ``lo`` and ``hi``, so the
gradient with respect to a path's range is the density moving across the bin edges at its two
ends. A path without neighbours on its surface (a cell narrower than a millionth of a bin: an
isolated ray, as on a small object's edge) is deposited in the bin of its range, as the
compiled engine does; its gradient is that of a unit-wide cell starting at its range
(straight-through: the value is the bin's, the derivative the cell's).

What the held search does not move: which surfaces and triangles the paths meet (an occluding
edge stays where the search found it: a ray that the parameters would move off its triangle
still ends on that triangle's plane), which paths are neighbours on one surface, which
transmit legs are valid and in which beam they leave, and the fan rays' beams. Refresh the
search (:meth:`sonarsim.diff.Renderer.refresh`) after large steps.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from ..core.splat import MIN_SPREAD_BINS

DEG = jnp.pi / 180.0


def rpy_matrix(rpy_deg: jax.Array) -> jax.Array:
    """(3, 3) ``Rz(yaw) Ry(pitch) Rx(roll)`` of ``(roll, pitch, yaw)`` in degrees
    (:func:`sonarsim.core.transforms.rpy_to_matrix`)."""
    r, p, y = rpy_deg[0] * DEG, rpy_deg[1] * DEG, rpy_deg[2] * DEG
    cr, sr, cp, sp, cy, sy = jnp.cos(r), jnp.sin(r), jnp.cos(p), jnp.sin(p), jnp.cos(y), jnp.sin(y)
    return jnp.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def _dot(a: jax.Array, b: jax.Array) -> jax.Array:
    return jnp.sum(a * b, axis=-1)


# Degenerate geometry inside ``jit``: a collapsed triangle (or an object scaled to nothing) has
# no normal, a ray parallel to a plane no intersection. Such a path contributes nothing. Each
# division and root below is taken of a stand-in value where its argument is degenerate and
# the result then dropped by a second ``where`` (a ``where`` alone passes 0 * inf = NaN back
# through the branch it did not take).


def safe_length(v: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(|v|, ok)`` along the last axis: ``ok`` where ``|v|^2`` is a normal float (above the
    dtype's smallest), and there the length; elsewhere length 1 (a stand-in whose gradient is
    finite and unused)."""
    sq = _dot(v, v)
    ok = sq > jnp.finfo(sq.dtype).tiny
    return jnp.sqrt(jnp.where(ok, sq, 1.0)), ok


def safe_divide(num: jax.Array, den: jax.Array, ok: jax.Array) -> jax.Array:
    """``num / den`` where ``ok``, 0 elsewhere (gradients finite everywhere)."""
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def rpy_matrices(rpy_deg: jax.Array) -> jax.Array:
    """(N, 3, 3) :func:`rpy_matrix` of (N, 3) angles at once."""
    r, p, y = rpy_deg[:, 0] * DEG, rpy_deg[:, 1] * DEG, rpy_deg[:, 2] * DEG
    cr, sr, cp, sp, cy, sy = jnp.cos(r), jnp.sin(r), jnp.cos(p), jnp.sin(p), jnp.cos(y), jnp.sin(y)
    return jnp.stack([
        jnp.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
        jnp.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
        jnp.stack([-sp, cp * sr, cp * cr], axis=-1),
    ], axis=-2)


def plane_table(params: dict, names: tuple[str, ...]) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """The planes' unit normals (P, 3), offsets (P,), specular reflectances (P,) and whether
    each normal is one (P,) (a zero normal, possible only inside ``jit``, is the zero vector
    here: nothing meets that plane)."""
    if not names:
        z = jnp.zeros((1, 3)).at[0, 2].set(1.0)
        return z, jnp.zeros(1), jnp.zeros(1), jnp.ones(1, bool)
    n = jnp.stack([params[f"planes.{p}.normal"] for p in names])
    length, ok = safe_length(n)
    n = jnp.where(ok[:, None], n / length[:, None], 0.0)
    off = jnp.stack([jnp.asarray(params[f"planes.{p}.offset_m"]).reshape(()) for p in names])
    spec = jnp.stack([jnp.asarray(params[f"planes.{p}.specular"]).reshape(()) for p in names])
    return n, off, spec, ok


def object_values(params: dict, objects: tuple[str, ...], suffix: str, default: float | None = None) -> jax.Array:
    """(N, ...) one parameter of every object, stacked in object order (``default`` for an
    object without it)."""
    return jnp.stack([jnp.asarray(params[f"objects.{o}.{suffix}"] if default is None
                                  else params.get(f"objects.{o}.{suffix}", default)) for o in objects])


def mirror_table(params: dict, static: Any, normal: jax.Array, offset: jax.Array, spec: jax.Array, tri_n: jax.Array,
                 tri_off: jax.Array, face_object: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The chains' mirrors by row, as the search numbers them: the planes, then the held
    triangles (unit normals, offsets, and their objects' specular reflectance, 0 for an object
    that does not mirror: its triangles are then only scatterers). A collapsed triangle's
    normal is the zero vector: no leg meets it."""
    n_planes = len(static.planes)
    length, ok = safe_length(tri_n)
    if static.objects and tri_n.shape[0]:
        tri_spec = object_values(params, static.objects, "specular", 0.0).astype(tri_n.dtype)[face_object]
    else:
        tri_spec = jnp.zeros(tri_n.shape[0], tri_n.dtype)
    n = jnp.concatenate([normal[:n_planes], jnp.where(ok[:, None], tri_n / length[:, None], 0.0)])
    off = jnp.concatenate([offset[:n_planes], jnp.where(ok, tri_off / length, 0.0)])
    r = jnp.concatenate([spec[:n_planes], tri_spec])
    if n.shape[0] == 0:  # nothing at all: the stand-in row
        return normal[:1], offset[:1], spec[:1]
    return n, off, r


def triangle_table(params: dict, objects: tuple[str, ...], faces: jax.Array,
                   face_object: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array]:
    """The hit triangles' planes: unnormalised normals ``(b - a) x (c - a)`` (F, 3) and
    offsets ``n . a`` (F,), and their corners (F, 3, 3), posed and scaled from each object's
    own mesh.

    ``faces``: (F, 3) indices into every object's vertices, concatenated in object order;
    ``face_object``: (F,) the object of each. All objects are posed at once (one gather, one
    batched product), so that the compiled function does not grow with the object count.
    """
    if not objects or faces.shape[0] == 0:
        return jnp.zeros((0, 3)), jnp.zeros(0), jnp.zeros((0, 3, 3))
    vertices = jnp.concatenate([params[f"objects.{o}.vertices_m"] for o in objects])
    scale = object_values(params, objects, "scale")[face_object]  # (F, 3)
    rot = rpy_matrices(object_values(params, objects, "rpy_deg"))[face_object]  # (F, 3, 3)
    position = object_values(params, objects, "position_m")[face_object]
    local = vertices[faces] * scale[:, None, :]  # (F, 3 corners, 3)
    tri = jnp.einsum("fcj,fij->fci", local, rot) + position[:, None, :]
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    n = jnp.cross(b - a, c - a)
    return n, _dot(n, a), tri


def law_table(params: dict, surfaces: tuple[tuple[str, str], ...]) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Diffuse coefficient, lobe strength and roughness by surface id (S,), from the
    parameters of each surface's law (``surfaces``: ``(prefix, law)`` in surface-id order)."""
    coef, strength, rough = [], [], []
    for prefix, law in surfaces:
        coef.append(jnp.asarray(params[f"{prefix}.mu" if law == "lambert" else f"{prefix}.albedo"]).reshape(()))
        if law == "rough":
            strength.append(jnp.asarray(params[f"{prefix}.specular_strength"]).reshape(()))
            rough.append(jnp.asarray(params[f"{prefix}.roughness"]).reshape(()))
        else:
            strength.append(jnp.zeros(()))
            rough.append(jnp.ones(()))
    if not coef:  # no surface at all: a stand-in (nothing is met)
        return jnp.zeros(1), jnp.zeros(1), jnp.ones(1)
    return jnp.stack(coef), jnp.stack(strength), jnp.stack(rough)


def specular_lobe(c: jax.Array, s: jax.Array) -> jax.Array:
    """``exp(-tan^2 / (2 s^2)) / cos^5`` (:func:`sonarsim.core.radiometry.specular_lobe`), 0 at
    grazing (where ``cos^5`` is below the dtype's smallest float the lobe has long been 0) and
    for a roughness of 0 or less (possible only inside ``jit``)."""
    ok = (c > jnp.finfo(c.dtype).tiny ** 0.2) & (s > 0)
    c = jnp.where(ok, c, 1.0)
    s = jnp.where(ok, s, 1.0)
    c2 = c * c
    t2 = (1.0 - c2) / c2
    return jnp.where(ok, jnp.exp(-t2 / (2.0 * s * s)) / (c2 * c2 * c), 0.0)


def path_ranges(params: dict, data: dict, static: Any) -> tuple[jax.Array, jax.Array, dict]:
    """Each path's recorded range (m) and energy, and the geometry formed on the way.

    A path that meets degenerate geometry (a collapsed triangle, an object scaled to nothing,
    a leg parallel to its mirror or scatterer, a plane's zero normal: all only inside ``jit``,
    where values are not checked) has no energy and the range the search recorded; its
    gradients are 0, never NaN.

    Returns
    -------
    distance : (C,) half the path's length, metres
    energy : (C,)
    parts : dict
        ``point`` (C, 3) the scatterers, ``rx`` (C,) receive-leg lengths, ``cos`` (C,)
        incidences, ``valid`` (C,) whether the path met no degenerate geometry.
    """
    rot = rpy_matrix(params["sonar.rpy_deg"])
    origin = params["sonar.position_m"]
    direction, weight = data["direction"], data["weight"]
    if static.sensor is not None and static.sensor.elevation is not None:
        from .sensor import fan_rays  # the elevation pattern's width moves the rays' weights

        direction, weight = fan_rays(params, data, static.sensor)
    plane_n, plane_off, plane_spec, plane_ok = plane_table(params, static.planes)
    tri_n, tri_off, tri_corners = triangle_table(params, static.objects, data["faces"], data["face_object"])
    # The chains' mirrors: the planes, then the held triangles (a mesh mirror's).
    normal, offset, spec = mirror_table(params, static, plane_n, plane_off, plane_spec, tri_n, tri_off,
                                        data["face_object"])
    shift = jnp.zeros(direction.shape[0], direction.dtype)
    if static.attach == "surfaces" and tri_corners.shape[0]:
        direction, shift = follow_azimuth(params, data, static, rot, origin, direction, normal, offset, tri_corners)
    d = direction @ rot.T  # (C, 3) the fan rays in the world
    o = jnp.broadcast_to(origin, d.shape)
    gen = data["gen"]
    dist = jnp.zeros(d.shape[0], d.dtype)
    atten = jnp.ones(d.shape[0], d.dtype)
    tiny = jnp.finfo(d.dtype).tiny
    # A leg meets a plane where it is not parallel to it (a zero normal is parallel to all).
    valid = jnp.ones(d.shape[0], bool)
    for j in range(data["rx_planes"].shape[1]):
        on = j < gen
        p = jnp.maximum(data["rx_planes"][:, j], 0)
        n = normal[p]
        dn = _dot(d, n)
        hit = jnp.abs(dn) > tiny
        valid = valid & (hit | ~on)
        t = safe_divide(offset[p] - _dot(o, n), dn, on & hit)
        o = o + t[:, None] * d
        d = jnp.where(on[:, None], d - 2.0 * dn[:, None] * n, d)
        dist = dist + t
        atten = atten * jnp.where(on, spec[p], 1.0)
    n_planes = len(static.planes)  # (the plane table has a stand-in row where there is none)
    surf_n = jnp.concatenate([plane_n[:n_planes], tri_n])
    surf_off = jnp.concatenate([plane_off[:n_planes], tri_off])
    if surf_n.shape[0] == 0:  # nothing to meet (an empty search): the stand-in row
        surf_n, surf_off = plane_n[:1], plane_off[:1]
    ns = surf_n[data["surface"]]
    length_n, has_normal = safe_length(ns)
    dn = _dot(d, ns)
    # (Below eps^2 of incidence the range would overflow float32: such a path grazes its
    # surface and has no energy anyway.)
    meets = has_normal & (jnp.abs(dn) > jnp.finfo(d.dtype).eps ** 2 * length_n)
    valid = valid & meets
    t = safe_divide(surf_off[data["surface"]] - _dot(o, ns), dn, meets)
    point = o + t[:, None] * d
    dist = dist + t
    cos = safe_divide(jnp.abs(dn), length_n, meets)

    coef, strength, rough = law_table(params, static.surfaces)
    sid = data["sid"]
    f = coef[sid] * data["texel"] * cos  # a texture scales the diffuse part, not the lobe
    if static.rough:
        f = f + strength[sid] * specular_lobe(cos, rough[sid])
    if static.reflective:
        f = f * vertex_reflectivity(params, data, static)
    intensity = weight * f * data["factor"]
    if not static.tvg:
        intensity = intensity / jnp.maximum(dist, 1e-6) ** 2
    # The transmit leg: reversed, or by image sources along its chain.
    mirror_ok = jnp.concatenate([plane_ok[:n_planes], safe_length(tri_n)[1]])
    if mirror_ok.shape[0] == 0:
        mirror_ok = plane_ok[:1]
    a = point
    tx_spec = jnp.ones(d.shape[0], d.dtype)
    for j in range(data["tx_planes"].shape[1] - 1, -1, -1):
        q = data["tx_planes"][:, j]
        on = q >= 0
        q = jnp.maximum(q, 0)
        valid = valid & (mirror_ok[q] | ~on)
        n = normal[q]
        a = jnp.where(on[:, None], a - 2.0 * (_dot(a, n) - offset[q])[:, None] * n, a)
        tx_spec = tx_spec * jnp.where(on, spec[q], 1.0)
    length, apart = safe_length(a - origin)
    length = jnp.where(apart, length, 0.0)
    same = data["same"]
    distance = jnp.where(same, dist, 0.5 * (dist + length))
    distance = jnp.where(valid, distance, data["held_distance"])
    energy = atten * jnp.where(same, atten, tx_spec) * intensity
    energy = jnp.where(data["live"] & valid, energy, 0.0)
    return distance, energy, {"point": point, "rx": dist, "cos": cos, "shift": shift, "valid": valid}


def vertex_reflectivity(params: dict, data: dict, static: Any) -> jax.Array:
    """(C,) each path's reflectivity factor: an object's ``reflectivity`` per vertex (see
    :class:`~sonarsim.diff.Renderer`) interpolated at its scatterer over its triangle by the
    held barycentric coordinates; 1 on planes and on the other objects."""
    n_planes = len(static.planes)
    surface = data["surface"]
    faces, face_object = data["faces"], data["face_object"]
    if faces.shape[0] == 0:
        return jnp.ones(surface.shape[0], data["uv"].dtype)
    row = jnp.clip(surface - n_planes, 0, faces.shape[0] - 1)
    # Every object's vertices in one table (1 where an object has no reflectivity).
    rho = jnp.concatenate([params[f"objects.{o}.reflectivity"] if o in static.reflective else
                           jnp.ones(params[f"objects.{o}.vertices_m"].shape[0], data["uv"].dtype)
                           for o in static.objects])
    reflective = jnp.asarray([o in static.reflective for o in static.objects])
    u, v = data["uv"][:, 0], data["uv"][:, 1]
    f = faces[row]
    value = (1.0 - u - v) * rho[f[:, 0]] + u * rho[f[:, 1]] + v * rho[f[:, 2]]
    mine = (surface >= n_planes) & reflective[face_object[row]]
    return jnp.where(mine, value, 1.0)


def follow_azimuth(params: dict, data: dict, static: Any, rot: jax.Array, origin: jax.Array, direction: jax.Array,
                   normal: jax.Array, offset: jax.Array, corners: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``attach: surfaces``: each object path's fan ray turned in azimuth to where its
    scatterer, held on its triangle (barycentric), now lies, keeping the ray's elevation.

    The scatterer ``A`` is seen through the receive leg's mirrors (``A* = M_1(... M_g(A))``);
    its azimuth in the sonar's frame replaces the ray's. The leg is then traced along the
    turned ray as for any path (range, incidence, weight at the point it meets), and the
    turn, ``shift`` (radians), moves the path's energy across the beams in the splat. Across
    the beams an object's echo thus follows the object (and the sonar's turns); along a beam's
    elevation the rays stay the fan's, exact at the aperture's edges and the floor's onset.

    Returns
    -------
    direction : (C, 3)
        The paths' directions in the sonar's frame.
    shift : (C,)
        Their turns, radians (0 for planes' paths).
    """
    n_planes = len(static.planes)
    on_object = data["surface"] >= n_planes
    row = jnp.maximum(data["surface"] - n_planes, 0)
    tri = corners[row]
    u, v = data["uv"][:, 0:1], data["uv"][:, 1:2]
    a = (1.0 - u - v) * tri[:, 0] + u * tri[:, 1] + v * tri[:, 2]
    for j in range(data["rx_planes"].shape[1] - 1, -1, -1):
        p = data["rx_planes"][:, j]
        on = (p >= 0) & (j < data["gen"])
        p = jnp.maximum(p, 0)
        n = normal[p]
        a = jnp.where(on[:, None], a - 2.0 * (_dot(a, n) - offset[p])[:, None] * n, a)
    local = (a - origin) @ rot  # R^T (A* - O): the sonar's frame
    # (A scatterer on the sonar's z axis has no azimuth: it keeps its ray's.)
    seen = on_object & (local[:, 0] ** 2 + local[:, 1] ** 2 > jnp.finfo(local.dtype).tiny)
    # the beam's azimuth of the scatterer: atan2(y, x) for plane beams; for cone beams that of its
    # direction cosine along the array, atan2(y, sqrt(x^2 + z^2)) (image.grid.beam_azimuth_deg;
    # the turn below stays about z, exact at rest, first-order off it)
    across = jnp.sqrt(local[:, 0] ** 2 + local[:, 2] ** 2) if getattr(static, "cone", False) else local[:, 0]
    shift = jnp.where(seen, jnp.arctan2(jnp.where(seen, local[:, 1], 0.0), jnp.where(seen, across, 1.0))
                      - data["ray_azimuth"], 0.0)
    c, s_ = jnp.cos(shift), jnp.sin(shift)
    turned = jnp.stack([c * direction[:, 0] - s_ * direction[:, 1], s_ * direction[:, 0] + c * direction[:, 1],
                        direction[:, 2]], axis=1)  # a turn about the sonar's z axis keeps the elevation
    return turned, shift


def splat(distance: jax.Array, energy: jax.Array, row: jax.Array, n_rows: int, data: dict, geometry: tuple,
          spread: bool = True, shift: jax.Array | None = None) -> jax.Array:
    """Paths into an image stack (n_rows, n_range_bins, n_beams) by range splatting (see the
    module docstring).

    Parameters
    ----------
    distance, energy : (C,)
        Each path's range (m) and energy.
    row : (C,) int
        The stack row each path goes to.
    n_rows : int
    data : dict
        ``down``, ``up``, ``has_down``, ``has_up`` (the held neighbours) and ``beam``.
    geometry : (range_min_m, range_resolution_m, n_range_bins, n_beams)
    spread : bool
        Range splatting (``render.range_splat``); ``False``: each path in the bin of its range.
    shift : (C,), optional
        Each path's azimuth off its ray's, radians (``attach: surfaces``): its energy is shared
        with the neighbouring beam it moves towards, in proportion to the shift over the beams'
        spacing (``data``'s ``beam_plus``/``beam_minus`` and ``step_plus``/``step_minus``; at
        the fan's edges it stays in its beam).
    """
    r0, dr, n, nb = geometry
    x = (distance - r0) / dr
    if spread:
        hd, hu = data["has_down"], data["has_up"]
        m_dn = 0.5 * (x + x[data["down"]])
        m_up = 0.5 * (x + x[data["up"]])
        lower = jnp.where(hd, m_dn, jnp.where(hu, 2.0 * x - m_up, x))
        upper = jnp.where(hu, m_up, jnp.where(hd, 2.0 * x - m_dn, x))
        lo = jnp.minimum(jnp.minimum(lower, upper), x)
        hi = jnp.maximum(jnp.maximum(lower, upper), x)
    else:
        lo = hi = x
    width = hi - lo
    point = width < MIN_SPREAD_BINS
    # A point fills its bin (the value); its derivative is a unit cell's starting at its range.
    lo_point = lo + jax.lax.stop_gradient(jnp.floor(lo) - lo)
    lo = jnp.where(point, lo_point, lo)
    hi = jnp.where(point, lo_point + 1.0, hi)
    density = energy / jnp.where(point, 1.0, width)
    lo = jnp.clip(lo, 0.0, n)
    hi = jnp.clip(hi, 0.0, n)
    fl_lo = jax.lax.stop_gradient(jnp.floor(lo))
    fl_hi = jax.lax.stop_gradient(jnp.floor(hi))
    fr_lo, fr_hi = lo - fl_lo, hi - fl_hi
    # Columns (row, beam) of n + 2 bins, range last: the running sums read memory in order.
    beams, shares = [data["beam"]], [None]
    if shift is not None:
        t_plus = jnp.clip(shift / data["step_plus"], 0.0, 1.0)
        t_minus = jnp.clip(shift / data["step_minus"], 0.0, 1.0)
        beams = [data["beam"], data["beam_plus"], data["beam_minus"]]
        shares = [1.0 - t_plus - t_minus, t_plus, t_minus]
    index, value = [], []
    for beam, share in zip(beams, shares):
        base = (row * nb + beam) * (n + 2)
        i_lo = base + fl_lo.astype(jnp.int32)
        i_hi = base + fl_hi.astype(jnp.int32)
        rho = density if share is None else density * share
        index += [i_lo, i_lo + 1, i_hi, i_hi + 1]
        value += [rho * (1.0 - fr_lo), rho * fr_lo, -rho * (1.0 - fr_hi), -rho * fr_hi]
    index, value = jnp.concatenate(index), jnp.concatenate(value)
    size = n_rows * nb * (n + 2)
    image = running_sum(jnp.zeros(size, energy.dtype).at[index].add(value).reshape(n_rows, nb, n + 2))[:, :, :n]
    # The running sums leave round-off (1e-16 of a column's values, of either sign) in bins
    # no cell covers; the count of cells over each bin (+1 at a cell's first bin, -1 after
    # its last, exact in integers) zeroes their values, as they are in the compiled engine's
    # images, and leaves their derivatives alone (an isolated path's derivative moves its
    # energy into the next bin, which its value does not cover).
    live = (hi > lo) & (energy != 0)
    count_index, count_value = [], []
    for beam, share in zip(beams, shares):
        base = (row * nb + beam) * (n + 2)
        i_lo = base + fl_lo.astype(jnp.int32)
        end = base + fl_hi.astype(jnp.int32) + (fr_hi > 0).astype(jnp.int32)
        on = (live if share is None else live & (share > 0)).astype(jnp.int32)
        count_index += [i_lo, end]
        count_value += [on, -on]
    count = jnp.zeros(size, jnp.int32).at[jnp.concatenate(count_index)].add(jnp.concatenate(count_value))
    covered = jnp.cumsum(count.reshape(n_rows, nb, n + 2), axis=2)[:, :, :n] > 0
    image = image + jax.lax.stop_gradient(jnp.where(covered, 0.0, -image))
    return jnp.swapaxes(image, 1, 2)


def running_sum(x: jax.Array, block: int = 48) -> jax.Array:
    """Cumulative sums along the last axis, by blocks: within each block a product with a
    triangular matrix of ones, then the blocks' totals carried (twice the speed of
    ``jnp.cumsum`` on a CPU for an image's columns, and the same sums to round-off)."""
    length = x.shape[-1]
    n_blocks = -(-length // block)
    y = jnp.pad(x, [(0, 0)] * (x.ndim - 1) + [(0, n_blocks * block - length)])
    y = y.reshape(x.shape[:-1] + (n_blocks, block)) @ jnp.triu(jnp.ones((block, block), x.dtype))
    carried = y[..., -1] @ jnp.triu(jnp.ones((n_blocks, n_blocks), x.dtype), k=1)
    return (y + carried[..., None]).reshape(x.shape[:-1] + (n_blocks * block,))[..., :length]
