# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""Compiled per-ray kernels of the path engine, the one engine of every frame.

Each kernel is the loop form of NumPy code that stays in the package as the reference:
``rotate``, ``trace_leg``, ``probe_chains``, ``path_events`` and ``splat_events`` are twinned by
:mod:`sonarsim.paths.engine` (with ``core.splat.accumulate``), kernel by kernel, and the tests
require each pair to agree. :class:`PathBlocks` runs them over a block of beams in one call
without the GIL, casting through the Embree 4 binding's packet loop (``docs/path-buffer.md``);
:class:`LabelMaps` forms the ground truth from the paths. They exist because a frame of the
demo casts ~30,000 rays in ~1 ms, and the same arithmetic as a chain of NumPy passes costs
several times that; fused into one loop per stage it costs about the casting again.

All arrays are flat (C-contiguous) views of the ray fan ``(n_beams, n_azimuth, n_elevation)``.
Nothing here allocates per ray; the caller owns every array.
"""

from libc.math cimport sqrt, sqrtf, fabs, fabsf, atan2, asin, acos, exp, isfinite, INFINITY, NAN
from libc.math cimport M_PI
from libc.string cimport memset, memmove
from libc.stdint cimport int64_t, uint64_t
import numpy as np
cimport cython

from sonarsim.trace.cast_abi cimport cast_rays_t

cdef extern from *:
    """
    /* Watching a flag that another thread sets: an acquiring load, a clock, a pause. */
    #if defined(_MSC_VER)
    #include <windows.h>
    static int ss_flag_load(const unsigned char* p) { return *(const volatile unsigned char*)p; }
    static void ss_flag_store(unsigned char* p, unsigned char v) { *(volatile unsigned char*)p = v; }
    static double ss_now(void) {
        LARGE_INTEGER f, c; QueryPerformanceFrequency(&f); QueryPerformanceCounter(&c);
        return (double)c.QuadPart / (double)f.QuadPart;
    }
    static void ss_pause(void) { YieldProcessor(); }
    static void ss_yield(void) { SwitchToThread(); }
    #else
    #include <time.h>
    #include <sched.h>
    static void ss_yield(void) { sched_yield(); }
    static int ss_flag_load(const unsigned char* p) { return __atomic_load_n(p, __ATOMIC_ACQUIRE); }
    static void ss_flag_store(unsigned char* p, unsigned char v) { __atomic_store_n(p, v, __ATOMIC_RELEASE); }
    static double ss_now(void) {
        struct timespec t; clock_gettime(CLOCK_MONOTONIC, &t);
        return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
    }
    static void ss_pause(void) {
    #if defined(__x86_64__) || defined(__i386__)
        __builtin_ia32_pause();
    #elif defined(__aarch64__)
        __asm__ __volatile__("yield");
    #endif
    }
    #endif
    """
    int ss_flag_load(const unsigned char* p) noexcept nogil
    void ss_flag_store(unsigned char* p, unsigned char v) noexcept nogil
    double ss_now() noexcept nogil
    void ss_pause() noexcept nogil
    void ss_yield() noexcept nogil


def watch_flag(const unsigned char[::1] flag, double seconds, unsigned char[::1] raise_first=None):
    """Watch ``flag[0]`` for up to ``seconds``, without the GIL: True as soon as another thread
    has made it nonzero, False once the time is up (``renderer.compiled.SecondCore``). With
    ``raise_first``, set ``raise_first[0]`` to 1 once the GIL is let go: a thread watching that
    flag can take the GIL without waiting for it. Between short runs of pause instructions it
    offers its core to any other thread that is ready (a busy machine: a watcher that kept its
    core would slow the very thread it waits for)."""
    cdef double end
    cdef bint seen = False
    cdef int k
    if flag.shape[0] < 1 or (raise_first is not None and raise_first.shape[0] < 1):
        raise ValueError("an empty flag")
    with nogil:
        if raise_first is not None:
            ss_flag_store(&raise_first[0], 1)
        end = ss_now() + seconds
        while not seen:
            for k in range(64):
                if ss_flag_load(&flag[0]):
                    seen = True
                    break
                ss_pause()
            if not seen:
                ss_yield()
                if ss_now() >= end:
                    break
    return seen

cdef double CONTINUITY_SINE = 0.5
# Rows of a tile of LabelMaps.resolve: its outputs (an id and three elevations a cell, the
# block's beams wide) and its state stay in the first-level cache.
cdef enum:
    RESOLVE_TILE = 16


cpdef Py_ssize_t tiles_of(Py_ssize_t n_rows) noexcept nogil:
    """Tiles of :data:`RESOLVE_TILE` range rows that ``n_rows`` rows make (the last may be short)."""
    return (n_rows + RESOLVE_TILE - 1) // RESOLVE_TILE
cdef double MIN_SPREAD_BINS = 1e-6
cdef double SURFACE_OFFSET_M = 1e-5
cdef double WATER_TOLERANCE_M = 1e-7
# Law codes (sonarsim.config.materials).
cdef int LAMBERTIAN = 0
cdef int LAMBERT = 1
cdef int SEDIMENT = 3
# How reciprocal pairs are formed (``render.double_beam``; paths.engine.PAIR_MODES): once (paper,
# split), each from its own receive ray (separate), or so, adding coherently within one beam.
cdef int PAIRS_ONCE = 0
cdef int PAIRS_SEPARATE = 1
cdef int PAIRS_COHERENT = 2


cdef inline double scatter(double w, double coef, int law, const double* lobe, Py_ssize_t n_table,
                           double c) noexcept nogil:
    """Backscatter of a ray of weight ``w`` at cos(alpha) ``c`` under a law (twin:
    ``core.radiometry.backscatter``, operation for operation). ``lobe``: (strength, roughness),
    then ``n_table`` samples of a tabulated law (``SEDIMENT``) in incidence from 0 to 90 degrees."""
    cdef double c2, c4, s, a, t
    cdef Py_ssize_t i
    if law == LAMBERTIAN:
        return w * coef * c
    if law == LAMBERT:  # Lambert's law per unit area, mu cos^2: per ray mu cos, the paper's form
        return w * coef * c
    if law == SEDIMENT:  # the table, linear in the incidence angle (core.radiometry.tabulated_law)
        if c > 1.0:
            c = 1.0
        elif c < 0.0:
            c = 0.0
        a = acos(c) * ((n_table - 1) / (M_PI / 2))
        i = <Py_ssize_t>a
        if i > n_table - 2:
            i = n_table - 2
        t = a - i
        return w * coef * (lobe[2 + i] + (lobe[3 + i] - lobe[2 + i]) * t)
    c2 = c * c
    c4 = c2 * c2
    s = lobe[1]
    if c4 > 0 and s > 0:  # the lobe per unit area over cos(alpha): per ray
        return w * (coef * c + lobe[0] * (exp(-((1.0 - c2) / c2) / (2.0 * s * s)) / (c4 * c)))
    return w * (coef * c + lobe[0] * 0.0)


cdef class _Laws:
    """Pointers to the optional law tables of a kernel call (None: every surface Lambertian).

    ``n_ids``: rows of ``albedo_by_id`` (the tables must have as many); ``n_rows``: hits in the
    call (``hit_texel`` must cover them). Checked here: the kernels read without bounds checks.
    """
    cdef const int* law
    cdef const double* lobe
    cdef Py_ssize_t stride  # lobe's row: 2, or 2 + the samples of a tabulated law
    cdef const float* texel
    cdef object keep

    def __cinit__(self, law_by_id, lobe_by_id, hit_texel, Py_ssize_t n_ids, Py_ssize_t n_rows):
        cdef const int[::1] lv
        cdef const double[:, ::1] bv
        cdef const float[::1] tv
        cdef Py_ssize_t i
        self.law = NULL
        self.lobe = NULL
        self.stride = 2
        self.texel = NULL
        self.keep = (law_by_id, lobe_by_id, hit_texel)
        if (law_by_id is None) != (lobe_by_id is None):
            raise ValueError("give both law_by_id and lobe_by_id, or neither")
        if law_by_id is not None:
            lv = law_by_id
            bv = lobe_by_id
            if lv.shape[0] != n_ids or bv.shape[0] != n_ids or not (bv.shape[1] == 2 or bv.shape[1] >= 4):
                raise ValueError(f"law tables of {lv.shape[0]} and {bv.shape[0]} x {bv.shape[1]} rows for {n_ids} surfaces")
            for i in range(lv.shape[0]):
                if lv[i] == SEDIMENT and bv.shape[1] < 4:
                    raise ValueError(f"surface row {i}: a tabulated law without its table")
            self.stride = bv.shape[1]
            if n_ids:
                self.law = &lv[0]
                self.lobe = &bv[0, 0]
        if hit_texel is not None:
            tv = hit_texel
            if tv.shape[0] < n_rows:
                raise ValueError(f"hit_texel has {tv.shape[0]} rows for {n_rows} hits")
            if tv.shape[0]:
                self.texel = &tv[0]


cdef inline double diffuse_weight(_Laws laws, const double* albedo_by_id, Py_ssize_t index,
                                  const float* texel, double w, double c) noexcept nogil:
    """``w * f(alpha)`` of surface ``index`` (surface id + 1); ``texel``: the texture's factor
    at the hit (NULL: none)."""
    cdef double coef = albedo_by_id[index]
    if texel != NULL:
        coef = coef * texel[0]
    if laws.law == NULL:
        return w * coef * c
    return scatter(w, coef, laws.law[index], laws.lobe + laws.stride * index, laws.stride - 2, c)


cdef Py_ssize_t weigh_impl(Py_ssize_t[::1] live, Py_ssize_t n_reached, const int[::1] sid,
                           const double[::1] cosine, const double[::1] dist, const float[::1] texel,
                           bint textured, int n_planes, const double[::1] albedo_by_id,
                           const double[::1] weight, bint tvg, _Laws laws,
                           double[::1] intensity) noexcept nogil:
    """The weighing (run after each generation's search by :func:`trace_leg` and
    :class:`PathBlocks`; twin: ``paths.engine.weigh_leg``): the diffuse weight of each reached ray from what the search
    recorded (its surface, incidence, leg length and, on a textured object, the texture's
    factor), and ``live[:n_reached]`` compacted in place to the rays with some energy."""
    cdef Py_ssize_t j, i, n_live = 0
    cdef int s
    cdef double c, r
    for j in range(n_reached):
        i = live[j]
        s = sid[i]
        c = diffuse_weight(laws, &albedo_by_id[0], s + 1, &texel[i] if textured and s >= n_planes else NULL,
                           weight[i], cosine[i])
        if not tvg:
            r = dist[i] if dist[i] > 1e-6 else 1e-6
            c = c / (r * r)
        intensity[i] = c
        if c != 0:
            live[n_live] = i
            n_live += 1
    return n_live


cdef inline Py_ssize_t beam_of(const double* edges, Py_ssize_t n_edges, double az) noexcept nogil:
    """Index j with edges[j] >= az > edges[j + 1] (edges descending); -1 outside the fan.
    Pointers, not memoryviews, here and in the other per-ray helpers: passing a memoryview to
    a function costs an atomic reference count each call."""
    cdef Py_ssize_t lo = 0, hi = n_edges, mid
    # Count the edges >= az (they come first), minus one; matches
    # numpy.searchsorted(-edges, -az, side="right") - 1.
    while lo < hi:
        mid = (lo + hi) >> 1
        if edges[mid] >= az:
            lo = mid + 1
        else:
            hi = mid
    if lo - 1 < 0 or lo - 1 >= n_edges - 1:
        return -1
    return lo - 1


# Within this relative distance of the aperture's edge (its sine) or a beam's edge (its
# tangent), :func:`beam_in_view` decides with the exact angle: elsewhere round-off cannot
# change the decision, and the sine and the tangent decide it alone (no asin or atan2).
cdef double ANGLE_MARGIN = 1e-9


cdef inline Py_ssize_t beam_in_view(double x, double y, double z, double range_min, double range_max,
                                    double half_elevation_deg, const double* edges, Py_ssize_t n_edges,
                                    double* length, double sin_half=-1.0, const double* tan_edges=NULL,
                                    bint cone=False) noexcept nogil:
    """The beam that sees a point at ``(x, y, z)`` in the sonar frame, or -1 where it lies
    outside the range window, the elevation aperture or the fan; ``length`` receives its
    distance from the sonar. Cheapest test first: most candidate points fail the range window
    or the elevation (twins: ``paths.engine.option_paths`` with ``SonarView.beam_of``, and
    ``paths.algorithm2.ground_echo_rays``).

    ``sin_half``: the sine of the half elevation aperture (negative: none), and ``tan_edges``:
    the tangents of the beam edges (NULL: none; :func:`view_tables`), decide without the angles wherever
    round-off cannot change the decision (:data:`ANGLE_MARGIN`): the same decisions, cheaper.

    ``cone``: a phased array's beams are cones about its axis (y): a direction belongs to the
    beam of its direction cosine along the array, ``asin(y / r)``, which is
    ``atan2(y, sqrt(x^2 + z^2))``: the plane case with ``x`` replaced by that (``core.rays``);
    the array is baffled, so nothing behind it (``x <= 0``) is in the fan."""
    cdef double r = sqrt(x * x + y * y + z * z), el, a, t, tol
    cdef double rad2deg = 180.0 / M_PI
    cdef Py_ssize_t lo, hi, mid
    length[0] = r
    if not (r >= range_min and r < range_max):
        return -1
    el = z / r
    a = fabs(el)
    if sin_half >= 0.0 and a > sin_half * (1.0 + ANGLE_MARGIN):
        return -1
    if sin_half < 0.0 or not a < sin_half * (1.0 - ANGLE_MARGIN):  # near the aperture's edge: the angle
        if el > 1.0:
            el = 1.0
        elif el < -1.0:
            el = -1.0
        el = asin(el) * rad2deg
        if not fabs(el) <= half_elevation_deg:
            return -1
    if cone:
        if not x > 0.0:  # behind the baffled array (its cones' back halves): outside the fan
            return -1
        x = sqrt(x * x + z * z)
    if tan_edges != NULL and x > 0.0:
        # atan2(y, x) rises with y / x for x > 0: count the edges at or above it by tangent.
        t = y / x
        lo = 0
        hi = n_edges
        while lo < hi:
            mid = (lo + hi) >> 1
            if tan_edges[mid] >= t:
                lo = mid + 1
            else:
                hi = mid
        tol = ANGLE_MARGIN * (1.0 + fabs(t))
        if not ((lo > 0 and fabs(tan_edges[lo - 1] - t) <= tol) or (lo < n_edges and fabs(tan_edges[lo] - t) <= tol)):
            if lo - 1 < 0 or lo - 1 >= n_edges - 1:
                return -1
            return lo - 1
    return beam_of(edges, n_edges, atan2(y, x) * rad2deg)


def view_tables(const double[::1] edges, double half_elevation_deg):
    """``(sin_half, tan_edges)`` for :func:`beam_in_view`: the sine of the half aperture, and
    the tangents of the beam edges (None where an edge is not within 89 degrees of the axis)."""
    sin_half = np.sin(np.radians(half_elevation_deg)) if 0.0 <= half_elevation_deg <= 90.0 else -1.0
    e = np.asarray(edges, dtype=np.float64)
    tan_edges = np.tan(np.radians(e)) if e.size and np.all(np.abs(e) < 89.0) else None
    return float(sin_half), tan_edges


cdef inline double ffloor(double v) noexcept nogil:
    """floor() without a libm call (the x86-64 baseline has no rounding instruction)."""
    cdef double t = <double>(<long long>v)
    return t - 1.0 if t > v else t


cdef inline bint range_cell(double x, double x_dn, double x_up, bint c_dn, bint c_up, double energy, double nb,
                            double* lo_out, double* hi_out, double* density_out) noexcept nogil:
    """One ray's range cell in bins, clipped to the window, and its energy per bin (see
    render.formation._segments and expand_cells); False when nothing of it lies in the window."""
    cdef double lower = x, upper = x, lo, hi, width, density, m_dn = 0.0, m_up = 0.0
    if c_dn:
        m_dn = 0.5 * (x + x_dn)
    if c_up:
        m_up = 0.5 * (x_up + x)
    if c_dn or c_up:
        lower = m_dn if c_dn else 2.0 * x - m_up
        upper = m_up if c_up else 2.0 * x - m_dn
    lo = lower if lower < upper else upper
    hi = upper if upper > lower else lower
    if x < lo:
        lo = x
    if x > hi:
        hi = x
    width = hi - lo
    if width < MIN_SPREAD_BINS:
        lo = ffloor(lo)
        hi = lo + 1.0
        density = energy
    else:
        density = energy / width
    if lo < 0.0:
        lo = 0.0
    if hi > nb:
        hi = nb
    lo_out[0] = lo
    hi_out[0] = hi
    density_out[0] = density
    return hi > lo


cdef inline Py_ssize_t bin_end(double hi) noexcept nogil:
    """ceil(hi) for 0 < hi (truncation is floor, and ceil is one more)."""
    cdef Py_ssize_t b1 = <Py_ssize_t>hi
    if b1 < hi:
        b1 += 1
    return b1


cdef inline void deposit(double x, double x_dn, double x_up, bint c_dn, bint c_up, double energy,
                         float* column, Py_ssize_t stride, double nb) noexcept nogil:
    """Spread one ray's energy over its range cell (see render.formation._segments) into ``column``.

    ``column`` points at bin 0 of the ray's (label, beam) image column, whose bins are
    ``stride`` floats apart; x are in bins.
    """
    cdef double lo, hi, density, ov
    cdef Py_ssize_t b
    if not range_cell(x, x_dn, x_up, c_dn, c_up, energy, nb, &lo, &hi, &density):
        return
    for b in range(<Py_ssize_t>lo, bin_end(hi)):
        ov = (hi if hi < b + 1.0 else b + 1.0) - (lo if lo > b else <double>b)
        column[b * stride] += <float>(density * ov)


cdef inline bint neighbours(const double* points, const float* normals, const int* key,
                            const Py_ssize_t* ray, const double* energy, Py_ssize_t m, Py_ssize_t k,
                            Py_ssize_t n_elevation) noexcept nogil:
    """Whether path k + 1 of a compact set of ``m`` paths is path k's upper neighbour on one
    continuous surface (see ``splat_events``). A path without energy is no neighbour (as in
    formation.accumulate). ``points``, ``normals``: (n, 3) C-contiguous (float64, float32)."""
    cdef Py_ssize_t i = ray[k]
    cdef double cx, cy, cz, off0, off1, limit
    if not (k + 1 < m and ray[k + 1] == i + 1 and (i + 1) % n_elevation != 0
            and key[i] >= 0 and key[i + 1] == key[i] and energy[k] != 0 and energy[k + 1] != 0):
        return False
    cx = points[3 * i + 3] - points[3 * i]
    cy = points[3 * i + 4] - points[3 * i + 1]
    cz = points[3 * i + 5] - points[3 * i + 2]
    off0 = cx * normals[3 * i] + cy * normals[3 * i + 1] + cz * normals[3 * i + 2]
    off1 = cx * normals[3 * i + 3] + cy * normals[3 * i + 4] + cz * normals[3 * i + 5]
    limit = CONTINUITY_SINE * CONTINUITY_SINE * (cx * cx + cy * cy + cz * cz)
    return off0 * off0 <= limit and off1 * off1 <= limit


cdef void rotate_impl(const double[:, ::1] dirs, const double[:, ::1] rotation, double[:, ::1] out64,
                      float[:, ::1] out32, Py_ssize_t begin, Py_ssize_t end) noexcept nogil:
    """Rows ``begin:end`` of :func:`rotate`'s directions (also run by :class:`PathBlocks`)."""
    cdef Py_ssize_t i
    cdef double x, y, z, a, b, c
    for i in range(begin, end):
        x = dirs[i, 0]
        y = dirs[i, 1]
        z = dirs[i, 2]
        a = rotation[0, 0] * x + rotation[0, 1] * y + rotation[0, 2] * z
        b = rotation[1, 0] * x + rotation[1, 1] * y + rotation[1, 2] * z
        c = rotation[2, 0] * x + rotation[2, 1] * y + rotation[2, 2] * z
        out64[i, 0] = a
        out64[i, 1] = b
        out64[i, 2] = c
        out32[i, 0] = <float>a
        out32[i, 1] = <float>b
        out32[i, 2] = <float>c


def rotate(const double[:, ::1] dirs, const double[:, ::1] rotation, double ox, double oy, double oz,
           double[:, ::1] out64, float[:, ::1] out32, float[:, ::1] origins32):
    """World-frame ray directions ``R @ d`` in float64 and float32, and the ray origins in
    float32 (both for Embree), in one pass."""
    cdef Py_ssize_t i, n = dirs.shape[0]
    with nogil:
        for i in range(n):
            origins32[i, 0] = <float>ox
            origins32[i, 1] = <float>oy
            origins32[i, 2] = <float>oz
        rotate_impl(dirs, rotation, out64, out32, 0, n)


# General reflecting planes (sonarsim.paths.engine is the NumPy twin) ----------------------

cdef inline double dot3(const double* a, Py_ssize_t i, double x, double y, double z) noexcept nogil:
    """Row ``i`` of a C-contiguous (n, 3) array dotted with (x, y, z). A pointer, not a
    memoryview: passing a memoryview to a function costs a reference count each call."""
    return a[3 * i] * x + a[3 * i + 1] * y + a[3 * i + 2] * z


# Mesh mirrors (sonarsim.paths.facets is the NumPy twin) -----------------------------------

# A reflection point may lie this far outside its triangle, relative to the triangle's longest
# edge (``paths.facets.EDGE_TOLERANCE``).
cdef double EDGE_TOLERANCE = 1e-9


cdef struct MirrorTables:
    # What the kernels read of ``paths.facets.FacetSet`` (flat normals): pointers into the
    # arrays a :class:`Mirrors` keeps.
    Py_ssize_t n_mirrors          # M
    Py_ssize_t n_objects          # K (every object, mirroring or not)
    const int64_t* obj_start      # (K + 1,): object k's facets are obj_start[k] .. obj_start[k + 1] - 1
    const double* obj_specular    # (K,)
    const signed char* obj_side   # (K,): +1 / -1 the side it mirrors on, 0 both
    const unsigned char* obj_smooth  # (K,): mirrors about the normals interpolated from its corners
    const double* corner_normals  # (F, 3, 3) (NULL: no smooth object)
    const int64_t* facet_mirror   # (F,)
    const double* facet_normal    # (F, 3)
    const double* corners         # (F, 3, 3)
    const int64_t* mirror_start   # (M + 1,)
    const int64_t* mirror_facets  # (F,)
    const int* mirror_obj         # (M,)


cdef class Mirrors:
    """The mesh mirrors as the kernels read them (``paths.facets.FacetSet`` with flat normals;
    :meth:`of` takes one). It keeps the arrays (C-contiguous and of the kernels' dtypes: copied
    only where they are not; a FacetSet's are already) and makes them read-only: the kernels
    read them through pointers for the simulator's life.

    Parameters
    ----------
    start : (K + 1,) int64, specular : (K,) float64, side : (K,) int8
        Per object (every object of the scene).
    mirror : (F,) int64, normal : (F, 3) float64, corners : (F, 3, 3) float64
        Per facet.
    mirror_start : (M + 1,) int64, mirror_facets : (F,) int64, mirror_obj : (M,) int32
    mirror_normal : (M, 3) float64, mirror_offset : (M,) float64
        Per mirror: its facets, its object, its plane (``n . x = offset``).
    smooth : (K,) bool, corner_normals : (F, 3, 3) float64, optional
        The objects that mirror about the normals interpolated from their corners' (``normals:
        smooth``), and those normals (needed where one is).
    """

    cdef MirrorTables t
    cdef readonly object arrays
    cdef readonly Py_ssize_t n_mirrors

    def __init__(self, start, specular, side, mirror, normal, corners, mirror_start, mirror_facets, mirror_obj,
                 mirror_normal, mirror_offset, smooth=None, corner_normals=None):
        n_obj = np.asarray(specular).reshape(-1).shape[0]
        a = dict(smooth=np.ascontiguousarray(np.zeros(n_obj, bool) if smooth is None else smooth, np.uint8),
                 corner_normals=np.ascontiguousarray(np.zeros((0, 3, 3)) if corner_normals is None else corner_normals,
                                                     np.float64).reshape(-1, 3, 3), mirror_normal=np.ascontiguousarray(mirror_normal, np.float64).reshape(-1, 3),
                 mirror_offset=np.ascontiguousarray(mirror_offset, np.float64), start=np.ascontiguousarray(start, np.int64), specular=np.ascontiguousarray(specular, np.float64),
                 side=np.ascontiguousarray(side, np.int8), mirror=np.ascontiguousarray(mirror, np.int64),
                 normal=np.ascontiguousarray(normal, np.float64).reshape(-1, 3),
                 corners=np.ascontiguousarray(corners, np.float64).reshape(-1, 3, 3),
                 mirror_start=np.ascontiguousarray(mirror_start, np.int64),
                 mirror_facets=np.ascontiguousarray(mirror_facets, np.int64),
                 mirror_obj=np.ascontiguousarray(mirror_obj, np.int32))
        cdef Py_ssize_t K = a["specular"].shape[0], F = a["mirror"].shape[0], M = a["mirror_obj"].shape[0]
        if (a["start"].shape[0] != K + 1 or a["side"].shape[0] != K or a["normal"].shape[0] != F
                or a["corners"].shape[0] != F or a["mirror_start"].shape[0] != M + 1 or a["mirror_facets"].shape[0] != F
                or a["mirror_normal"].shape[0] != M or a["mirror_offset"].shape[0] != M or a["smooth"].shape[0] != K
                or (a["smooth"].any() and a["corner_normals"].shape[0] != F)):
            raise ValueError("mirror tables of inconsistent lengths")
        if K and (a["start"][0] != 0 or a["start"][K] != F or np.any(np.diff(a["start"]) < 0)):
            raise ValueError("object facet ranges do not cover the facets in order")
        if M and (a["mirror_start"][0] != 0 or a["mirror_start"][M] != F or np.any(np.diff(a["mirror_start"]) <= 0)):
            raise ValueError("mirror facet ranges do not cover the facets, each mirror one at least")
        if F and (a["mirror"].min() < 0 or a["mirror"].max() >= M or a["mirror_facets"].min() < 0
                  or a["mirror_facets"].max() >= F):
            raise ValueError("facet or mirror ids out of range")
        if M and (a["mirror_obj"].min() < 0 or a["mirror_obj"].max() >= K):
            raise ValueError("a mirror's object out of range")
        for v in a.values():
            v.flags.writeable = False
        self.arrays = a
        self.n_mirrors = M
        self.t.n_mirrors = M
        self.t.n_objects = K
        self.t.obj_start = <const int64_t*>_address(a["start"])
        self.t.obj_specular = <const double*>_address(a["specular"])
        self.t.obj_side = <const signed char*>_address(a["side"])
        self.t.obj_smooth = <const unsigned char*>_address(a["smooth"])
        self.t.corner_normals = <const double*>_address(a["corner_normals"]) if a["smooth"].any() else NULL
        self.t.facet_mirror = <const int64_t*>_address(a["mirror"])
        self.t.facet_normal = <const double*>_address(a["normal"])
        self.t.corners = <const double*>_address(a["corners"])
        self.t.mirror_start = <const int64_t*>_address(a["mirror_start"])
        self.t.mirror_facets = <const int64_t*>_address(a["mirror_facets"])
        self.t.mirror_obj = <const int*>_address(a["mirror_obj"])

    @classmethod
    def of(cls, facets):
        """The tables of a ``FacetSet``."""
        return cls(facets.start, facets.specular, facets.side, facets.mirror, facets.normal, facets.corners,
                   facets.mirror_start, facets.mirror_facets, facets.mirror_obj, facets.mirror_normal,
                   facets.mirror_offset, facets.smooth, facets.corner_normals)



cdef size_t _address(a):
    """Address of a C-contiguous array's data (0 where it is empty)."""
    return <size_t>a.ctypes.data if a.size else 0


cdef struct Reflectance:
    # The mirrors' coherent reflectance (``SurfaceLaws.reflectance``; twin:
    # ``core.reflection.reflectance``): row ``s + 1`` surface s's ``|V|^2`` against
    # ``c = |cos(incidence)|`` on T points evenly from 0 to 1, times ``exp(-q c^2)``.
    const double* table           # (n_surfaces + 1, T)
    const double* q               # (n_surfaces + 1,)
    Py_ssize_t T
    Py_ssize_t rows


cdef class ReflectanceTable:
    """The mirrors' reflectance as the kernels read it: ``table`` (n_surfaces + 1, T >= 2)
    float64 and ``q`` (n_surfaces + 1,) float64 (``SurfaceLaws.reflectance`` and
    ``reflect_q``), kept read-only for the kernels' pointers."""

    cdef Reflectance t
    cdef readonly object arrays

    def __init__(self, table, q):
        table = np.ascontiguousarray(table, np.float64)
        q = np.ascontiguousarray(q, np.float64).reshape(-1)
        if table.ndim != 2 or table.shape[1] < 2 or q.shape[0] != table.shape[0]:
            raise ValueError("a reflectance table (n_surfaces + 1, T >= 2) and its q (n_surfaces + 1,)")
        if not (np.all(np.isfinite(table)) and np.all(np.isfinite(q)) and table.min(initial=0.0) >= 0.0
                and q.min(initial=0.0) >= 0.0):
            raise ValueError("reflectances and roughness exponents must be finite and not negative")
        table.flags.writeable = False
        q.flags.writeable = False
        self.arrays = (table, q)
        self.t.table = <const double*>_address(table)
        self.t.q = <const double*>_address(q)
        self.t.T = table.shape[1]
        self.t.rows = table.shape[0]


cdef inline double reflect_at(const Reflectance* rf, Py_ssize_t row, double c) noexcept nogil:
    """Surface ``row - 1``'s reflectance at ``c = |cos(incidence)|`` (linear in the table)."""
    cdef const double* t = rf.table + row * rf.T
    cdef double x, f
    cdef Py_ssize_t i
    if c > 1.0:
        c = 1.0
    if not c > 0.0:  # (NaN too)
        c = 0.0
    x = c * <double>(rf.T - 1)
    i = <Py_ssize_t>x
    if i > rf.T - 2:
        i = rf.T - 2
    f = x - <double>i
    return (t[i] + f * (t[i + 1] - t[i])) * exp(-rf.q[row] * c * c)


cdef inline int64_t facet_of(const MirrorTables* mt, Py_ssize_t obj, int prim) noexcept nogil:
    """Facet of triangle ``prim`` of object ``obj``, -1 where the object does not mirror (twin:
    ``FacetSet.facet``)."""
    cdef int64_t f
    if mt == NULL or obj < 0 or obj >= mt.n_objects or prim < 0:
        return -1
    f = mt.obj_start[obj] + prim
    return f if f < mt.obj_start[obj + 1] else -1


cdef inline void smooth_normal(const double* c, float u, float v, double dx, double dy, double dz,
                               double* nx, double* ny, double* nz) noexcept nogil:
    """The normal a ray along ``d`` meeting a smooth facet at barycentric ``(u, v)`` reflects
    about: its corners' normals ``c`` (9 numbers) interpolated and made unit; where that would
    turn a grazing ray into the surface, the facet's own (``n*`` on entry) (twin:
    ``FacetSet.reflecting_normal`` and ``engine.trace_generation``)."""
    cdef double uu = u, vv = v, w = 1.0 - uu - vv
    cdef double mx = w * c[0] + uu * c[3] + vv * c[6]
    cdef double my = w * c[1] + uu * c[4] + vv * c[7]
    cdef double mz = w * c[2] + uu * c[5] + vv * c[8]
    cdef double length = sqrt(mx * mx + my * my + mz * mz), twice, rx, ry, rz
    if length < 1e-300:
        length = 1e-300
    mx = mx / length
    my = my / length
    mz = mz / length
    twice = 2.0 * (dx * mx + dy * my + dz * mz)
    rx = dx - twice * mx
    ry = dy - twice * my
    rz = dz - twice * mz
    if (rx * nx[0] + ry * ny[0] + rz * nz[0]) * (dx * nx[0] + dy * ny[0] + dz * nz[0]) > 0:
        return  # the interpolated normal would send it on through: the facet's own
    nx[0] = mx
    ny[0] = my
    nz[0] = mz


cdef inline bint in_triangle(const double* c, double wx, double wy, double wz) noexcept nogil:
    """The point, on the plane of the triangle with corners ``c`` (9 numbers), lies inside it,
    edges included within EDGE_TOLERANCE of its size (twin: ``FacetSet.contains``)."""
    cdef double e1x = c[3] - c[0], e1y = c[4] - c[1], e1z = c[5] - c[2]
    cdef double e2x = c[6] - c[0], e2y = c[7] - c[1], e2z = c[8] - c[2]
    cdef double px = wx - c[0], py = wy - c[1], pz = wz - c[2]
    cdef double d11 = e1x * e1x + e1y * e1y + e1z * e1z
    cdef double d12 = e1x * e2x + e1y * e2y + e1z * e2z
    cdef double d22 = e2x * e2x + e2y * e2y + e2z * e2z
    cdef double det = d11 * d22 - d12 * d12, p1, p2, u, v, tol
    if not det > 0.0:
        return False
    p1 = px * e1x + py * e1y + pz * e1z
    p2 = px * e2x + py * e2y + pz * e2z
    u = (d22 * p1 - d12 * p2) / det
    v = (d11 * p2 - d12 * p1) / det
    tol = sqrt(d11 if d11 > d22 else d22)
    tol = EDGE_TOLERANCE * (tol if tol > 1.0 else 1.0)
    return u >= -tol and v >= -tol and u + v <= 1.0 + tol


cdef inline bint on_mirror(const MirrorTables* mt, Py_ssize_t m, double wx, double wy, double wz) noexcept nogil:
    """The point, on mirror ``m``'s plane, lies on one of its triangles (twin:
    ``FacetSet.contains_mirror``)."""
    cdef int64_t j
    for j in range(mt.mirror_start[m], mt.mirror_start[m + 1]):
        if in_triangle(mt.corners + 9 * mt.mirror_facets[j], wx, wy, wz):
            return True
    return False


cdef inline Py_ssize_t hash_slot(const int64_t* keys, Py_ssize_t mask, int64_t key) noexcept nogil:
    """The slot of ``key`` in an open-addressing table of ``mask + 1`` slots (a power of 2; -1
    free), or of the free slot where it would go (linear probing)."""
    cdef Py_ssize_t h = <Py_ssize_t>((<uint64_t>key * <uint64_t>0x9E3779B97F4A7C15ULL) >> 40) & mask
    while keys[h] != -1 and keys[h] != key:
        h = (h + 1) & mask
    return h


cdef (Py_ssize_t, int, double, bint, Py_ssize_t) trace_leg_impl(const Py_ssize_t[::1] ray, const float[::1] hit_distance, const int[::1] hit_mesh,
              const float[:, ::1] hit_normal, const double[:, ::1] org, const double[:, ::1] dirs,
              const double[::1] before, const double[::1] atten, const int[::1] chain,
              const double[:, ::1] plane_normal, const double[::1] plane_offset,
              const unsigned char[::1] plane_active, const double[::1] plane_specular,
              double reach, bint first, bint reflect, int[:, ::1] children, int n_chains,
              double[::1] dist, int[::1] sid, double[:, ::1] point,
              float[:, ::1] normal, double[::1] cosine, double[::1] atten_out, int[::1] chain_out,
              int[::1] key, Py_ssize_t[::1] live, int n_surfaces,
              Py_ssize_t[::1] nx_ray, double[:, ::1] nx_org, float[:, ::1] nx_org32,
              double[:, ::1] nx_dir, float[:, ::1] nx_dir32, double[::1] nx_before,
              double[::1] nx_atten, int[::1] nx_chain, const float* hit_texel, float[::1] texel,
              const int[::1] hit_prim, const float[:, ::1] hit_uv, int[::1] prim,
              float[:, ::1] uv, const MirrorTables* mt, int64_t* hkeys, int* hvals, Py_ssize_t hmask,
              int* parent, int* last_mirror, const Reflectance* rf=NULL) noexcept nogil:
    """The loop of :func:`trace_leg`'s search (also run by :class:`PathBlocks`, block by block):
    writes the legs and lists the reached rays in ``live``; :func:`weigh_impl` weighs them.

    ``mt`` (NULL: none) are the mesh mirrors: a ray whose triangle (``hit_prim``) is a facet it
    meets on a side the facet mirrors on reflects about the facet's normal into chain mirror
    ``P + m``, the child found in the open-addressing table ``hkeys`` / ``hvals`` (``hmask + 1``
    slots, at least twice the chain table's rows; key ``chain * M + m``). ``parent`` and
    ``last_mirror`` (NULL: not kept) receive each new chain's parent and last mirror. ``rf``
    (NULL: the constants ``plane_specular`` and the objects') is the mirrors' reflectance
    against the incidence at each reflection."""

    cdef Py_ssize_t k, i, m = ray.shape[0], n_next = 0, P = plane_normal.shape[0]
    cdef Py_ssize_t row, p, best_p, cap = children.shape[0]
    cdef bint one = org.shape[0] == 1
    cdef double ox, oy, oz, dx, dy, dz, t, tp, dn, nx, ny, nz, b, total, c, rx, ry, rz, twice
    cdef double px, py, pz, min_next = INFINITY
    cdef float fx, fy, fz, cosf
    cdef int s, ch, child, side
    cdef bint overflow = False
    cdef bint primitives = prim.shape[0] > 0  # the search's triangle and barycentrics, recorded
    cdef int64_t facet, hk
    cdef Py_ssize_t slot
    cdef double spec
    cdef Py_ssize_t n_reached = 0
    cdef const double* pn = &plane_normal[0, 0] if P > 0 else NULL
    for k in range(m):
        i = ray[k]
        row = 0 if one else k
        ox = org[row, 0]
        oy = org[row, 1]
        oz = org[row, 2]
        dx = dirs[k, 0]
        dy = dirs[k, 1]
        dz = dirs[k, 2]
        b = before[row]
        if hit_mesh[k] >= 0:
            t = hit_distance[k]
            s = hit_mesh[k] + <int>P
            nx = hit_normal[k, 0]
            ny = hit_normal[k, 1]
            nz = hit_normal[k, 2]
        else:
            t = INFINITY
            s = -1
            nx = 0.0
            ny = 0.0
            nz = 0.0
        best_p = -1
        for p in range(P):
            if not plane_active[p]:
                continue
            dn = dot3(pn, p, dx, dy, dz)
            if dn < 0:
                tp = (plane_offset[p] - dot3(pn, p, ox, oy, oz)) / dn
                if tp > 0 and tp < t and b + tp <= reach:
                    t = tp
                    best_p = p
        if best_p >= 0:
            s = <int>best_p
            nx = plane_normal[best_p, 0]
            ny = plane_normal[best_p, 1]
            nz = plane_normal[best_p, 2]
        total = b + t
        if s < 0 or not total <= reach:
            if first:
                dist[i] = INFINITY
                sid[i] = -1
                if primitives:
                    prim[i] = -1
                    uv[i, 0] = 0.0
                    uv[i, 1] = 0.0
            continue
        if first:
            # As the caster reports them: float32 points and incidence (the round trip
            # needs the build flag -fno-tree-slp-vectorize, see pyproject.toml).
            fx = <float>(ox + dx * t)
            fy = <float>(oy + dy * t)
            fz = <float>(oz + dz * t)
            px = fx
            py = fy
            pz = fz
            cosf = fabsf(<float>nx * <float>dx + <float>ny * <float>dy + <float>nz * <float>dz)
            c = cosf
        else:
            px = ox + dx * t
            py = oy + dy * t
            pz = oz + dz * t
            c = fabs(nx * dx + ny * dy + nz * dz)
        ch = chain[row]
        dist[i] = total
        sid[i] = s
        point[i, 0] = px
        point[i, 1] = py
        point[i, 2] = pz
        # float32: an object's normal is the caster's (exact); a plane's is rounded, and serves
        # only the continuity test (a chord within 30 degrees of the surface), not the mirror.
        normal[i, 0] = <float>nx
        normal[i, 1] = <float>ny
        normal[i, 2] = <float>nz
        cosine[i] = c
        if hit_texel != NULL and s >= P:  # the texture's factor where a textured object scatters
            texel[i] = hit_texel[k]
        if primitives:
            if s >= P:  # an object's triangle and where on it (Embree's u, v)
                prim[i] = hit_prim[k]
                uv[i, 0] = hit_uv[k, 0]
                uv[i, 1] = hit_uv[k, 1]
            else:  # a plane: sid names it
                prim[i] = -1
                uv[i, 0] = 0.0
                uv[i, 1] = 0.0
        if not first:  # the first generation: no reflection yet, chain 0, key = sid
            atten_out[i] = atten[row]
            chain_out[i] = ch
            key[i] = ch * n_surfaces + s
        live[n_reached] = i
        n_reached += 1
        facet = -1
        if mt != NULL and s >= P:  # a mesh mirror's triangle, met on a side it mirrors on
            facet = facet_of(mt, s - P, hit_prim[k])
            if facet >= 0:
                side = mt.obj_side[s - P]
                if side != 0 and not side * (dx * mt.facet_normal[3 * facet] + dy * mt.facet_normal[3 * facet + 1]
                                             + dz * mt.facet_normal[3 * facet + 2]) < 0:
                    facet = -1
        if facet >= 0:
            if not (reflect and total < reach):
                continue
            nx = mt.facet_normal[3 * facet]
            ny = mt.facet_normal[3 * facet + 1]
            nz = mt.facet_normal[3 * facet + 2]
            if mt.obj_smooth[s - P]:
                smooth_normal(mt.corner_normals + 9 * facet, hit_uv[k, 0], hit_uv[k, 1], dx, dy, dz, &nx, &ny, &nz)
            spec = mt.obj_specular[s - P]
            if rf != NULL:  # at the incidence on the normal it mirrors about
                spec = reflect_at(rf, s + 1, fabs(dx * nx + dy * ny + dz * nz))
            hk = <int64_t>ch * mt.n_mirrors + mt.facet_mirror[facet]
            slot = hash_slot(hkeys, hmask, hk)
            if hkeys[slot] == hk:
                child = hvals[slot]
            else:
                if n_chains >= cap:
                    overflow = True
                    continue
                child = n_chains
                hkeys[slot] = hk
                hvals[slot] = child
                n_chains += 1
                if parent != NULL:
                    parent[child] = ch
                    last_mirror[child] = <int>(P + mt.facet_mirror[facet])
        else:
            if not (reflect and s < P and total < reach and plane_specular[s] > 0):
                continue
            spec = plane_specular[s] if rf == NULL else reflect_at(rf, s + 1, c)
            child = children[ch, s]
            if child < 0:
                if n_chains >= cap:
                    overflow = True
                    continue
                child = n_chains
                children[ch, s] = child
                n_chains += 1
                if parent != NULL:
                    parent[child] = ch
                    last_mirror[child] = s
        twice = 2.0 * (dx * nx + dy * ny + dz * nz)
        rx = dx - twice * nx
        ry = dy - twice * ny
        rz = dz - twice * nz
        fx = <float>px
        fy = <float>py
        fz = <float>pz
        nx_ray[n_next] = i
        nx_org[n_next, 0] = fx + SURFACE_OFFSET_M * rx
        nx_org[n_next, 1] = fy + SURFACE_OFFSET_M * ry
        nx_org[n_next, 2] = fz + SURFACE_OFFSET_M * rz
        nx_org32[n_next, 0] = <float>nx_org[n_next, 0]
        nx_org32[n_next, 1] = <float>nx_org[n_next, 1]
        nx_org32[n_next, 2] = <float>nx_org[n_next, 2]
        nx_dir[n_next, 0] = rx
        nx_dir[n_next, 1] = ry
        nx_dir[n_next, 2] = rz
        nx_dir32[n_next, 0] = <float>rx
        nx_dir32[n_next, 1] = <float>ry
        nx_dir32[n_next, 2] = <float>rz
        nx_before[n_next] = total + SURFACE_OFFSET_M
        nx_atten[n_next] = atten[row] * spec
        nx_chain[n_next] = child
        if total + SURFACE_OFFSET_M < min_next:
            min_next = total + SURFACE_OFFSET_M
        n_next += 1
    return n_next, n_chains, min_next, overflow, n_reached


def trace_leg(const Py_ssize_t[::1] ray, const float[::1] hit_distance, const int[::1] hit_mesh,
              const float[:, ::1] hit_normal, const double[:, ::1] org, const double[:, ::1] dirs,
              const double[::1] before, const double[::1] atten, const int[::1] chain,
              const double[:, ::1] plane_normal, const double[::1] plane_offset,
              const unsigned char[::1] plane_active, const double[::1] plane_specular,
              double reach, const double[::1] albedo_by_id, const double[::1] weight, bint tvg,
              bint first, bint reflect, int[:, ::1] children, int n_chains,
              double[::1] dist, int[::1] sid, double[:, ::1] point,
              float[:, ::1] normal, double[::1] intensity, double[::1] atten_out, int[::1] chain_out,
              int[::1] key, Py_ssize_t[::1] live, int n_surfaces,
              Py_ssize_t[::1] nx_ray, double[:, ::1] nx_org, float[:, ::1] nx_org32,
              double[:, ::1] nx_dir, float[:, ::1] nx_dir32, double[::1] nx_before,
              double[::1] nx_atten, int[::1] nx_chain, law_by_id=None, lobe_by_id=None, hit_texel=None,
              hit_prim=None, hit_uv=None, prim=None, uv=None, cosine=None, texel=None, Mirrors mirrors=None,
              int64_t[::1] mirror_keys=None, int[::1] mirror_children=None, int[::1] parent=None,
              int[::1] last_mirror=None, ReflectanceTable reflectance=None):
    """One generation of receive legs: the search (closest of objects and active planes, and
    the specular reflection of the rays that meet a plane), then the weighing of what it
    recorded (twin: ``engine.trace_generation``, ``engine.weigh_leg``).

    Rows ``k`` are rays ``ray[k]`` of the fan; ``org``, ``before``, ``atten``, ``chain`` may
    have one row for all (the first generation). Dense outputs (indexed by fan ray) must come
    filled with "nothing" (``dist`` inf, ``sid`` and ``key`` -1), except in the first
    generation, which visits every ray and writes "nothing" itself; only reached rays are set
    otherwise. ``key`` is ``chain * n_surfaces + sid`` (rays on one surface via one chain: the
    continuity of range splatting). The first generation does not write ``atten_out``,
    ``chain_out`` and ``key``: they are 1, 0 and ``sid`` there. ``live`` lists, in row order, the rays that scatter some
    energy. ``children[c, p]`` is the chain ``c + (p,)`` (-1: new, numbered from ``n_chains``).
    ``law_by_id``, ``lobe_by_id``: the surfaces' law codes and lobes (``SurfaceLaws``; None: all
    Lambertian); ``hit_texel`` (per row): the objects' texture factor at each hit (None: none).
    With ``hit_prim`` (rows) and ``hit_uv`` (rows x 2), the caster's triangle and barycentric
    ``(u, v)``, the discrete search is recorded in ``prim`` and ``uv`` (dense): the triangle
    and ``(u, v)`` where an object scatters, -1 and 0 where a plane does (and, in the first
    generation, where nothing does). The search writes each reached ray's incidence
    ``|cos(alpha)|`` in ``cosine`` and, with ``hit_texel``, the texture's factor where an object
    scatters in ``texel`` (dense; allocated here where not given); the weighing reads those,
    ``sid`` and ``dist`` and writes ``intensity``.

    With ``mirrors`` (:class:`Mirrors`; the search's triangles must be given), a ray that meets
    a facet also reflects, into chain mirror ``P + m``: ``mirror_keys`` (-1 free) and
    ``mirror_children`` are the open-addressing table of those chains (a power of 2 of slots,
    at least twice ``children``'s rows; key ``chain * M + m``). ``parent`` and ``last_mirror``
    (as many as ``children``'s rows, optional) receive each new chain's parent and last mirror.
    ``reflectance`` (:class:`ReflectanceTable`, a row per surface + 1): the mirrors'
    reflectance against incidence instead of the constants.

    Returns
    -------
    (n_next, n_chains, min_before_next, overflow, n_live)
    """
    cdef _Laws laws = _Laws(law_by_id, lobe_by_id, hit_texel, albedo_by_id.shape[0], ray.shape[0])
    cdef (Py_ssize_t, int, double, bint, Py_ssize_t) r
    cdef double[::1] cos_out = np.empty(dist.shape[0]) if cosine is None else cosine
    cdef float[::1] tex_out = (np.ones(dist.shape[0], np.float32) if texel is None else texel) if hit_texel is not None else _NO_TEXEL
    cdef Py_ssize_t n_live
    if cos_out.shape[0] != dist.shape[0] or (hit_texel is not None and tex_out.shape[0] != dist.shape[0]):
        raise ValueError("cosine and texel are dense over the fan, as dist is")
    cdef const int[::1] hp = _NO_INT if hit_prim is None else hit_prim
    cdef const float[:, ::1] huv = _NO_UV if hit_uv is None else hit_uv
    cdef int[::1] po = _NO_INT_OUT if prim is None else prim
    cdef float[:, ::1] uo = _NO_UV_OUT if uv is None else uv
    if (hit_prim is None) != (prim is None) or (hit_prim is None) != (uv is None) or (hit_uv is None) != (uv is None):
        raise ValueError("hit_prim, hit_uv, prim and uv go together")
    if prim is not None and (hp.shape[0] != ray.shape[0] or huv.shape[0] != ray.shape[0] or huv.shape[1] != 2
                             or po.shape[0] != dist.shape[0] or uo.shape[0] != dist.shape[0] or uo.shape[1] != 2):
        raise ValueError("hit_prim, hit_uv (rows) and prim, uv (dense) of the wrong shapes")
    cdef const MirrorTables* mt = NULL
    cdef int64_t* hkeys = NULL
    cdef int* hvals = NULL
    cdef int* par = NULL
    cdef int* lst = NULL
    cdef Py_ssize_t hmask = 0
    if children.shape[0] < 1 or not 1 <= n_chains <= children.shape[0]:
        raise ValueError(f"{n_chains} chains in a chain table of {children.shape[0]} rows (at least the empty chain)")
    if ray.shape[0] and (np.min(chain) < 0 or np.max(chain) >= n_chains):
        raise ValueError(f"the rays' chains are not among the {n_chains} of the table")
    if mirrors is not None:
        if hit_prim is None:
            raise ValueError("mirrors need the search's triangles (hit_prim, hit_uv, prim, uv)")
        if (mirror_keys is None or mirror_children is None or mirror_keys.shape[0] != mirror_children.shape[0]
                or mirror_keys.shape[0] < 2 * children.shape[0] or mirror_keys.shape[0] & (mirror_keys.shape[0] - 1)):
            raise ValueError("mirror_keys and mirror_children: a power of 2 of slots, twice the chain table's rows")
        if 2 * np.count_nonzero(np.asarray(mirror_keys) != -1) > mirror_keys.shape[0]:
            raise ValueError("mirror_keys more than half full (a table of this frame's chains: -1 free)")
        mt = &mirrors.t
        hkeys, hvals, hmask = &mirror_keys[0], &mirror_children[0], mirror_keys.shape[0] - 1
    if (parent is None) != (last_mirror is None):
        raise ValueError("parent and last_mirror go together")
    if parent is not None:
        if parent.shape[0] < children.shape[0] or last_mirror.shape[0] < children.shape[0]:
            raise ValueError("parent and last_mirror: a row per chain table row")
        par, lst = &parent[0], &last_mirror[0]
    cdef const Reflectance* rf = NULL
    if reflectance is not None:
        if reflectance.t.rows < n_surfaces + 1:
            raise ValueError(f"a reflectance table of {reflectance.t.rows} rows for {n_surfaces} surfaces (+ 1)")
        rf = &reflectance.t
    with nogil:
        r = trace_leg_impl(ray, hit_distance, hit_mesh, hit_normal, org, dirs, before, atten, chain, plane_normal,
                           plane_offset, plane_active, plane_specular, reach, first, reflect, children, n_chains,
                           dist, sid, point, normal, cos_out, atten_out, chain_out, key, live, n_surfaces, nx_ray,
                           nx_org, nx_org32, nx_dir, nx_dir32, nx_before, nx_atten, nx_chain, laws.texel, tex_out,
                           hp, huv, po, uo, mt, hkeys, hvals, hmask, par, lst, rf)
        n_live = weigh_impl(live, r[4], sid, cos_out, dist, tex_out, laws.texel != NULL, <int>plane_normal.shape[0],
                            albedo_by_id, weight, tvg, laws, intensity)
    return r[0], r[1], r[2], r[3], n_live


# Empty arrays: trace_leg without the search's triangles recorded.
_NO_INT = np.zeros(0, np.int32)
_NO_INT_OUT = np.zeros(0, np.int32)
_NO_UV = np.zeros((0, 2), np.float32)
_NO_UV_OUT = np.zeros((0, 2), np.float32)
_NO_TEXEL = np.zeros(0, np.float32)  # the legs' texel where no object is textured


cdef inline bint walk(double ax, double ay, double az, Py_ssize_t K, const int* tx_planes, const double* sources,
                      const double* pn, const double* plane_offset, const unsigned char* plane_active, Py_ssize_t P,
                      int n_planes, const MirrorTables* mt) noexcept nogil:
    """A transmit leg from the sonar to ``A`` along a chain of K mirrors (``tx_planes``, the
    planes', then mesh mirrors' normals ``pn`` and offsets) exists: walking back from A towards
    the sonar's images (``sources``, (K + 1) x 3), each reflection point lies on its mirror
    (a mesh mirror's: on one of its triangles, met from the side it mirrors on), between its
    neighbours, inside the water (the P planes' side where ``plane_active``)."""
    cdef double wx = ax, wy = ay, wz = az, tx_, ty, tz, denom, t, tol
    cdef Py_ssize_t j = K - 1, q
    cdef int side
    while j >= 0:
        q = tx_planes[j]
        if q >= n_planes:  # a closed object's facet is met from outside: the leg beyond it is there
            side = mt.obj_side[mt.mirror_obj[q - n_planes]]
            if side != 0 and not side * (dot3(pn, q, wx, wy, wz) - plane_offset[q]) > 0.0:
                return False
        tx_ = sources[3 * (j + 1)] - wx
        ty = sources[3 * (j + 1) + 1] - wy
        tz = sources[3 * (j + 1) + 2] - wz
        denom = dot3(pn, q, tx_, ty, tz)
        t = (plane_offset[q] - dot3(pn, q, wx, wy, wz)) / denom
        if not (t > 0.0 and t < 1.0):
            return False
        wx = wx + t * tx_
        wy = wy + t * ty
        wz = wz + t * tz
        tol = fabs(wx)
        if fabs(wy) > tol:
            tol = fabs(wy)
        if fabs(wz) > tol:
            tol = fabs(wz)
        tol = WATER_TOLERANCE_M * (tol if tol > 1.0 else 1.0)
        for q in range(P):
            if plane_active[q] and dot3(pn, q, wx, wy, wz) - plane_offset[q] < -tol:
                return False
        q = tx_planes[j]
        if q >= n_planes and not on_mirror(mt, q - n_planes, wx, wy, wz):
            return False  # on one of its triangles, not only their plane
        j -= 1
    return True


cdef void returns_impl(const Py_ssize_t* ray, const double* org, const double* dirs, const double* before,
                       const double* atten, const int* chain, Py_ssize_t m, const double* reached,
                       const double* origin, double radius2, double reach, double* back_length,
                       double* back_atten, double* back_dir, int* back_chain) noexcept nogil:
    """The specular returns among ``m`` rays reflected at the last generation's scatterers
    (twin: ``engine.returns_to_sonar``): a ray whose line passes within the disc of radius
    ``sqrt(radius2)`` round the sonar, ahead of it and before the surface it reaches
    (``reached``: the next generation's dense distances, inf: nothing) and within the reach,
    writes its length to the sonar's foot, its attenuation, direction and chain at its fan ray."""
    cdef Py_ssize_t k, i
    cdef double wx, wy, wz, dx, dy, dz, t, miss2
    for k in range(m):
        dx = dirs[3 * k]
        dy = dirs[3 * k + 1]
        dz = dirs[3 * k + 2]
        wx = origin[0] - org[3 * k]
        wy = origin[1] - org[3 * k + 1]
        wz = origin[2] - org[3 * k + 2]
        t = wx * dx + wy * dy + wz * dz
        miss2 = (wx * wx + wy * wy + wz * wz) - t * t
        i = ray[k]
        if t > 0.0 and t < reached[i] - before[k] and miss2 <= radius2 and before[k] + t <= reach:
            back_length[i] = before[k] + t
            back_atten[i] = atten[k]
            back_dir[3 * i] = dx
            back_dir[3 * i + 1] = dy
            back_dir[3 * i + 2] = dz
            back_chain[i] = chain[k]


def returns_to_sonar(const Py_ssize_t[::1] ray, const double[:, ::1] org, const double[:, ::1] dirs,
                     const double[::1] before, const double[::1] atten, const int[::1] chain,
                     const double[::1] reached, const double[::1] origin, double radius, double reach,
                     double[::1] back_length, double[::1] back_atten, double[:, ::1] back_dir, int[::1] back_chain):
    """The specular returns among rays (rows: fan ray ``ray[k]``, from ``org`` along ``dirs``,
    after ``before`` metres, with ``atten`` and ``chain``) reflected at the last generation's
    scatterers, ``reached`` the next generation's dense distances (twin:
    ``engine.returns_to_sonar``); written into the dense ``back_*`` arrays at their fan rays."""
    cdef Py_ssize_t m = ray.shape[0], n = reached.shape[0], k
    if (org.shape[0] != m or dirs.shape[0] != m or before.shape[0] != m or atten.shape[0] != m
            or chain.shape[0] != m or origin.shape[0] != 3 or back_length.shape[0] != n
            or back_atten.shape[0] != n or back_dir.shape[0] != n or back_chain.shape[0] != n):
        raise ValueError("returns: arrays of different lengths")
    if org.shape[1] != 3 or dirs.shape[1] != 3 or back_dir.shape[1] != 3:
        raise ValueError("returns: origins, directions and back_dir are (rows, 3)")
    for k in range(m):
        if not 0 <= ray[k] < n:
            raise ValueError(f"ray {ray[k]} of {n}")
    if m == 0:
        return
    with nogil:
        returns_impl(&ray[0], &org[0, 0], &dirs[0, 0], &before[0], &atten[0], &chain[0], m, &reached[0],
                     &origin[0], radius * radius, reach, &back_length[0], &back_atten[0], &back_dir[0, 0],
                     &back_chain[0])


cdef inline double transmit_reflectance(const Reflectance* rf, double ux, double uy, double uz, Py_ssize_t K,
                                       const int* tx_planes, const double* pn, Py_ssize_t n_planes,
                                       const MirrorTables* mt) noexcept nogil:
    """The product of the reflectances along a transmit leg of chain ``tx_planes`` (from the
    sonar): its first segment runs along ``u``, the unfolded line from the sonar to the
    scatterer's image; each reflection meets mirror ``p`` (a plane, or mesh mirror
    ``p - n_planes`` of its object) at ``|d . n_p|`` and turns ``d`` about ``n_p``."""
    cdef double norm = sqrt(ux * ux + uy * uy + uz * uz), dn, r = 1.0
    cdef Py_ssize_t j, p, row
    if not norm > 0.0:
        return 0.0
    ux /= norm
    uy /= norm
    uz /= norm
    for j in range(K):
        p = tx_planes[j]
        dn = dot3(pn, p, ux, uy, uz)
        row = p + 1 if p < n_planes else n_planes + mt.mirror_obj[p - n_planes] + 1
        r *= reflect_at(rf, row, fabs(dn))
        ux -= 2.0 * dn * pn[3 * p]
        uy -= 2.0 * dn * pn[3 * p + 1]
        uz -= 2.0 * dn * pn[3 * p + 2]
    return r


cdef Py_ssize_t path_events_impl(const Py_ssize_t[::1] live, const double[::1] dist, const int[::1] sid,
                const double[:, ::1] point, const double[::1] intensity, const double[::1] atten,
                const int[::1] chain, bint same, int tx, const double[:, ::1] unfold,
                const double[:, ::1] sources, const int[::1] tx_planes, double tx_specular,
                const int[::1] rank, int separate, int label, int n_planes, Py_ssize_t rays_per_beam,
                double ox, double oy, double oz, const double[:, ::1] rotation,
                const double[::1] edges, double half_elevation_deg, double range_min, double range_max,
                const double[:, ::1] plane_normal, const double[::1] plane_offset,
                const unsigned char[::1] plane_active,
                Py_ssize_t[::1] out_ray, double[::1] out_dist, double[::1] out_energy,
                int[::1] out_beam, int[::1] out_beam_tx, signed char[::1] out_label,
                const MirrorTables* mt, const int* leg_prim, double sin_half, const double* tan_edges,
                int only=-1, bint cone=False, const Reflectance* rf=NULL) noexcept nogil:
    """The loop of :func:`path_events` (also run by :class:`PathBlocks`). ``plane_normal`` and
    ``plane_offset`` hold the planes, then (with ``mt``) the mesh mirrors' planes; the water is
    bounded by the first ``plane_active.shape[0]`` (the planes). ``leg_prim``: the legs'
    triangles (dense; needed where a chain ends on a mesh mirror). ``only`` >= 0: only the rays
    whose receive chain is that one, each paired with the transmit chain whatever their ranks
    (a smooth mirror's reciprocal partners: ``engine.reciprocal_sets``). ``rf`` (NULL: the
    chain's constant product ``tx_specular``): the mirrors' reflectance at each reflection of
    the transmit leg, found along the unfolded line (:func:`transmit_reflectance`)."""

    cdef Py_ssize_t k, i, m = 0, n = live.shape[0], K = tx_planes.shape[0], j, q, P = plane_active.shape[0]
    cdef Py_ssize_t room = out_ray.shape[0]  # the outputs' length: nothing is written past it
    cdef int c, s, last = tx_planes[K - 1] if K > 0 else -1, rank_tx = rank[tx] if not same else 0
    cdef int64_t f
    cdef bint mirror_chain = False
    cdef double ax, ay, az_, ux, uy, uz, vx, vy, vz, length, tx_r
    cdef Py_ssize_t b
    # (the planes' and the mesh mirrors' normals: there may be mirrors and no plane)
    cdef const double* pn = &plane_normal[0, 0] if plane_normal.shape[0] > 0 else NULL
    cdef const double* po = &plane_offset[0] if plane_offset.shape[0] > 0 else NULL
    cdef const int* chain_of_tx = &tx_planes[0] if K > 0 else NULL
    for j in range(K):
        if tx_planes[j] >= n_planes:
            mirror_chain = True
    for k in range(n):
        i = live[k]
        s = sid[i]
        if same:
            if m >= room:
                return room + 1  # (more paths than room: the caller refuses the frame)
            out_ray[m] = i
            out_dist[m] = dist[i]
            out_energy[m] = atten[i] * atten[i] * intensity[i]
            out_beam[m] = <int>(i // rays_per_beam)
            out_beam_tx[m] = out_beam[m]
            out_label[m] = <signed char>((0 if s >= n_planes else 1) if label == 1 else label)
            m += 1
            continue
        c = chain[i]
        if only >= 0 and c != only:
            continue
        if c == tx:
            continue
        if last < n_planes:
            if s == last:
                continue
        elif s >= n_planes:  # a mesh mirror: not the one the scatterer lies on
            f = facet_of(mt, s - n_planes, leg_prim[i])
            if f >= 0 and mt.facet_mirror[f] == last - n_planes:
                continue
        if not separate and only < 0 and rank[c] <= rank_tx:
            continue
        ax = point[i, 0]
        ay = point[i, 1]
        az_ = point[i, 2]
        # A mesh mirror is small: its triangles refuse most transmit legs, at less cost than
        # the view (the same conditions, in another order: the same paths).
        if mirror_chain and not walk(ax, ay, az_, K, chain_of_tx, &sources[0, 0], pn, po,
                                     &plane_active[0] if P > 0 else NULL, P, n_planes, mt):
            continue
        ux = unfold[0, 0] * ax + unfold[0, 1] * ay + unfold[0, 2] * az_ + unfold[0, 3] - ox
        uy = unfold[1, 0] * ax + unfold[1, 1] * ay + unfold[1, 2] * az_ + unfold[1, 3] - oy
        uz = unfold[2, 0] * ax + unfold[2, 1] * ay + unfold[2, 2] * az_ + unfold[2, 3] - oz
        vx = rotation[0, 0] * ux + rotation[1, 0] * uy + rotation[2, 0] * uz
        vy = rotation[0, 1] * ux + rotation[1, 1] * uy + rotation[2, 1] * uz
        vz = rotation[0, 2] * ux + rotation[1, 2] * uy + rotation[2, 2] * uz
        b = beam_in_view(vx, vy, vz, range_min, range_max, half_elevation_deg, &edges[0], edges.shape[0], &length,
                         sin_half, tan_edges, cone)
        if b < 0:
            continue
        if not (mirror_chain or walk(ax, ay, az_, K, chain_of_tx, &sources[0, 0], pn, po,
                                     &plane_active[0] if P > 0 else NULL, P, n_planes, mt)):
            continue
        if m >= room:
            return room + 1
        tx_r = tx_specular
        if rf != NULL and K > 0:
            tx_r = transmit_reflectance(rf, ux, uy, uz, K, chain_of_tx, pn, n_planes, mt)
        out_ray[m] = i
        out_dist[m] = 0.5 * (dist[i] + length)
        out_energy[m] = atten[i] * tx_r * intensity[i]
        out_beam[m] = <int>(i // rays_per_beam)
        out_beam_tx[m] = <int>b
        if separate == PAIRS_COHERENT and b == out_beam[m]:
            # The pair arrives in one beam with one length: amplitudes add, 4x one path's
            # intensity over the two (engine.option_paths).
            out_energy[m] = 2.0 * out_energy[m]
        out_label[m] = <signed char>label
        m += 1
    return m


def probe_chains(const double[:, ::1] origins, const double[:, ::1] directions,
                 const double[:, ::1] plane_normal, const double[::1] plane_offset,
                 const unsigned char[::1] plane_active, const double[::1] plane_specular, double range_max,
                 Py_ssize_t max_length, int[:, ::1] children, int n_chains, const double[:, ::1] rotation=None):
    """The chains of planes that rays along the aperture's edges follow through the planes
    alone (twin: ``paths.engine.probe_chains``, which traces the same rays step for step):
    each ray goes to the nearest active plane it meets from the water side, reflects there
    while the plane has specular reflectance and the path so far is shorter than
    ``range_max``, at most ``max_length`` times; each step's chain is entered in ``children``
    (``children[c, p]``: the chain ``c + (p,)``, -1 new, numbered from ``n_chains``). With
    ``rotation`` (3 x 3), ``directions`` are in the sonar's frame, turned here as the twin
    turns them (``R d`` summed column by column), and ``origins`` is the sonar's one row.

    Returns
    -------
    (n_chains, overflow)
    """
    cdef Py_ssize_t m = directions.shape[0], P = plane_normal.shape[0], k, p, best, step
    cdef Py_ssize_t cap = children.shape[0]
    cdef double ox, oy, oz, dx, dy, dz, dn, t, best_t, travelled, twice, nx, ny, nz
    cdef int c, child
    cdef bint overflow = False
    cdef const double* pn = &plane_normal[0, 0] if P > 0 else NULL
    cdef bint turn = rotation is not None
    cdef double ex, ey, ez
    if (origins.shape[0] != (1 if turn else m) or plane_offset.shape[0] != P or plane_active.shape[0] != P
            or (turn and (rotation.shape[0] != 3 or rotation.shape[1] != 3))):
        raise ValueError("probe arrays of different lengths")
    with nogil:
        for k in range(m):
            ox = origins[0 if turn else k, 0]
            oy = origins[0 if turn else k, 1]
            oz = origins[0 if turn else k, 2]
            if turn:
                ex = directions[k, 0]
                ey = directions[k, 1]
                ez = directions[k, 2]
                dx = ex * rotation[0, 0] + ey * rotation[0, 1] + ez * rotation[0, 2]
                dy = ex * rotation[1, 0] + ey * rotation[1, 1] + ez * rotation[1, 2]
                dz = ex * rotation[2, 0] + ey * rotation[2, 1] + ez * rotation[2, 2]
            else:
                dx = directions[k, 0]
                dy = directions[k, 1]
                dz = directions[k, 2]
            c = 0
            travelled = 0.0
            for step in range(max_length):
                best = -1
                best_t = INFINITY
                for p in range(P):
                    if not plane_active[p]:
                        continue
                    dn = dot3(pn, p, dx, dy, dz)
                    if dn < 0:
                        t = (plane_offset[p] - dot3(pn, p, ox, oy, oz)) / dn
                        if t > 0 and t < best_t:
                            best_t = t
                            best = p
                if best < 0 or not travelled + best_t < range_max or not plane_specular[best] > 0:
                    break
                child = children[c, best]
                if child < 0:
                    if n_chains >= cap:
                        overflow = True
                        break
                    child = n_chains
                    children[c, best] = child
                    n_chains += 1
                c = child
                travelled = travelled + best_t
                nx = plane_normal[best, 0]
                ny = plane_normal[best, 1]
                nz = plane_normal[best, 2]
                ox = ox + dx * best_t
                oy = oy + dy * best_t
                oz = oz + dz * best_t
                twice = 2.0 * (dx * nx + dy * ny + dz * nz)
                dx = dx - twice * nx
                dy = dy - twice * ny
                dz = dz - twice * nz
                ox = ox + SURFACE_OFFSET_M * dx
                oy = oy + SURFACE_OFFSET_M * dy
                oz = oz + SURFACE_OFFSET_M * dz
    return n_chains, overflow


def path_events(const Py_ssize_t[::1] live, const double[::1] dist, const int[::1] sid,
                const double[:, ::1] point, const double[::1] intensity, const double[::1] atten,
                const int[::1] chain, bint same, int tx, const double[:, ::1] unfold,
                const double[:, ::1] sources, const int[::1] tx_planes, double tx_specular,
                const int[::1] rank, int separate, int label, int n_planes, Py_ssize_t rays_per_beam,
                double ox, double oy, double oz, const double[:, ::1] rotation,
                const double[::1] edges, double half_elevation_deg, double range_min, double range_max,
                const double[:, ::1] plane_normal, const double[::1] plane_offset,
                const unsigned char[::1] plane_active,
                Py_ssize_t[::1] out_ray, double[::1] out_dist, double[::1] out_energy,
                int[::1] out_beam, int[::1] out_beam_tx, signed char[::1] out_label, Mirrors mirrors=None,
                const int[::1] prim=None, int only=-1, bint cone=False, ReflectanceTable reflectance=None):
    """Paths of one generation's receive legs and one transmit option (twin:
    ``engine.option_paths``). ``cone``: the beams are cones (:func:`beam_in_view`).

    With ``mirrors`` (:class:`Mirrors`), ``plane_normal`` and ``plane_offset`` hold the P planes
    (``plane_active``'s length) and then the M mesh mirrors' planes, a chain's mirror ``P + m``
    is mesh mirror m, and ``prim`` (dense) holds the legs' triangles. ``only`` >= 0: only the
    rays whose receive chain is ``only``, whatever the ranks (a smooth mirror's partners).
    ``reflectance`` (:class:`ReflectanceTable`): the transmit leg's reflectances by incidence
    instead of ``tx_specular``.

    ``same``: the transmit leg is the receive leg reversed (order label ``label``; for the
    first generation the label is 0 on objects, 1 on planes). Otherwise the transmit leg
    follows chain ``tx`` (``unfold``: its 3 x 4 map, ``sources``: the sonar's images,
    ``tx_planes``: its planes from the sonar). Paths are written compactly, in ray order.

    Returns
    -------
    int : the number of paths written (the outputs hold every live ray: never more than their length).
    """
    cdef Py_ssize_t m, q
    cdef Py_ssize_t n_mirrors = 0 if mirrors is None else mirrors.n_mirrors
    cdef const MirrorTables* mt = NULL if mirrors is None else &mirrors.t
    cdef const int* pp = NULL
    views = view_tables(edges, half_elevation_deg)
    cdef double sin_half = views[0]
    tan_array = views[1]
    cdef const double[::1] tan_edges = tan_array
    cdef const double* tp = &tan_edges[0] if tan_array is not None else NULL
    q = out_ray.shape[0]
    if (q < live.shape[0] or out_dist.shape[0] != q or out_energy.shape[0] != q or out_beam.shape[0] != q
            or out_beam_tx.shape[0] != q or out_label.shape[0] != q):
        raise ValueError("path_events: outputs of one length, with room for every live ray")
    if (plane_active.shape[0] != n_planes or plane_normal.shape[0] != n_planes + n_mirrors
            or plane_offset.shape[0] != plane_normal.shape[0]):
        raise ValueError("plane_normal and plane_offset: the planes then the mesh mirrors; plane_active: the planes")
    for q in range(tx_planes.shape[0]):
        if not 0 <= tx_planes[q] < n_planes + n_mirrors:
            raise ValueError(f"mirror {tx_planes[q]} of {n_planes} planes and {n_mirrors} mesh mirrors")
    if mirrors is not None:
        if prim is None or prim.shape[0] != dist.shape[0]:
            raise ValueError("mirrors need the legs' triangles (prim, dense)")
        pp = &prim[0] if prim.shape[0] else NULL
    cdef const Reflectance* rf = NULL
    if reflectance is not None:
        if reflectance.t.rows < n_planes + 1 + (mirrors.t.n_objects if mirrors is not None else 0):
            raise ValueError(f"a reflectance table of {reflectance.t.rows} rows for the planes and objects (+ 1)")
        rf = &reflectance.t
    with nogil:
        m = path_events_impl(live, dist, sid, point, intensity, atten, chain, same, tx, unfold, sources, tx_planes, tx_specular, rank, separate, label, n_planes, rays_per_beam, ox, oy, oz, rotation, edges, half_elevation_deg, range_min, range_max, plane_normal, plane_offset, plane_active, out_ray, out_dist, out_energy, out_beam, out_beam_tx, out_label, mt, pp, sin_half, tp, only, cone, rf)
    return m


cdef void splat_events_impl(const double[:, ::1] points, const float[:, ::1] normals, const int[::1] key,
                 const Py_ssize_t[::1] ray, const double[::1] distance, const double[::1] energy,
                 const int[::1] beam, const signed char[::1] label, double scale,
                 bint spread, Py_ssize_t n_elevation, double range_min, double dr,
                 Py_ssize_t n_range_bins, Py_ssize_t n_beams, float[::1] out) noexcept nogil:
    """The loop of :func:`splat_events` (also run by :class:`PathBlocks`)."""

    cdef Py_ssize_t k, m = ray.shape[0]
    cdef bint c_dn = False, c_up
    cdef double x, x_dn = 0.0, x_up
    cdef double nb = <double>n_range_bins
    cdef float* base = &out[0]
    if m == 0:
        return
    cdef const double* pts = &points[0, 0]
    cdef const float* nrm = &normals[0, 0]
    cdef const int* kp = &key[0]
    cdef const Py_ssize_t* rp = &ray[0]
    cdef const double* ep = &energy[0]
    for k in range(m):
        c_up = spread and neighbours(pts, nrm, kp, rp, ep, m, k, n_elevation)
        x = (distance[k] - range_min) / dr
        x_up = (distance[k + 1] - range_min) / dr if c_up else 0.0
        deposit(x, x_dn, x_up, c_dn, c_up, scale * energy[k],
                base + <Py_ssize_t>label[k] * n_range_bins * n_beams + beam[k], n_beams, nb)
        c_dn = c_up
        x_dn = x


def splat_events(const double[:, ::1] points, const float[:, ::1] normals, const int[::1] key,
                 const Py_ssize_t[::1] ray, const double[::1] distance, const double[::1] energy,
                 const int[::1] beam, const signed char[::1] label, double scale,
                 bint spread, Py_ssize_t n_elevation, double range_min, double dr,
                 Py_ssize_t n_range_bins, Py_ssize_t n_beams, float[::1] out):
    """Continuity + range cells + accumulation of one compact path set (twin:
    ``engine.splat_set``, the set made dense and given to ``renderer.formation.accumulate``).

    Paths are in ray order; two are neighbours when their rays are neighbours in elevation
    (same ray column) with equal ``key`` (same surface via the same chain) and the chord
    between their scatterers lies within the continuity angle of both normals. Each path's
    energy is ``scale * energy``.
    """
    with nogil:
        splat_events_impl(points, normals, key, ray, distance, energy, beam, label, scale, spread, n_elevation, range_min, dr, n_range_bins, n_beams, out)


ctypedef struct MapCell:
    # One cell of a dominance map (see add_to_map): -1, an id, or -2 - slot; the one id's sum.
    int state
    float first

ctypedef struct CellMoments:
    # The total's energy, energy x elevation (degrees), least and greatest elevation in a cell.
    double weight
    double weighted
    float lo
    float hi


cdef inline bint add_to_map(MapCell* cell, float* table, Py_ssize_t n_ids, Py_ssize_t slot_base,
                            Py_ssize_t* n_slots, Py_ssize_t* n_reached, int ident, float part) noexcept nogil:
    """Add ``part`` of id ``ident`` to one cell of a dominance map; True when it is the cell's
    first deposit.

    A cell holds -1 (nothing yet), the one id that has deposited in it so far (with that id's
    sum in ``first``), or ``-2 - slot`` once a second id deposits: from then on row ``slot`` of
    ``table`` (slots x ids) holds every id's sum. Each id's sum is the one a dense float32
    (ids x cells) stack would hold -- the same float32 additions in the same order from 0 --
    so the dominant id is the same, ties included, without forming the stack. A cell's first
    deposit counts in ``n_reached``. A block of beams takes its new slots from ``slot_base``
    on (its own rows of the table: blocks run at once).
    """
    cdef int s = cell.state
    cdef float* row_sums
    cdef Py_ssize_t j, slot
    if s == ident:
        cell.first += part
        return False
    if s == -1:
        cell.state = ident
        cell.first = part
        n_reached[0] += 1
        return True
    if s >= 0:  # a second id: the cell is mixed
        slot = slot_base + n_slots[0]
        row_sums = table + slot * n_ids
        for j in range(n_ids):
            row_sums[j] = 0.0
        row_sums[s] = cell.first
        row_sums[ident] = part
        cell.state = <int>(-2 - slot)
        n_slots[0] += 1
    else:
        table[(-2 - <Py_ssize_t>s) * n_ids + ident] += part
    return False


cdef inline void add_to_box(int* box, int first_row, int last_row, int beam) noexcept nogil:
    """Widen an id's inclusive ``[row, beam, row, beam]`` box (-1: none yet) to rows
    ``first_row .. last_row`` of ``beam``."""
    if box[0] < 0:
        box[0] = first_row
        box[1] = beam
        box[2] = last_row
        box[3] = beam
        return
    box[0] = first_row if first_row < box[0] else box[0]
    box[1] = beam if beam < box[1] else box[1]
    box[2] = last_row if last_row > box[2] else box[2]
    box[3] = beam if beam > box[3] else box[3]


cdef inline int strongest(const float* row, Py_ssize_t begin, Py_ssize_t end, float* top) noexcept nogil:
    """Index in ``[begin, end)`` of the largest positive ``row`` entry (ties: the lower), -1 none."""
    cdef Py_ssize_t k
    cdef int best = -1
    cdef float t = 0.0
    for k in range(begin, end):
        if row[k] > t:  # strict: zero never wins, a tie keeps the lower id
            t = row[k]
            best = <int>k
    top[0] = t
    return best


cdef class LabelMaps:
    """Instance maps, elevation moments and points of one frame, deposited path set by path set
    -- by :class:`PathBlocks` in the frame's own pass, each block as it splats its paths into
    the image (the same range cells, the same float32 parts), or by :meth:`add` from path sets
    formed after the frame (twin: ``renderer.ground_truth._frame_truth``: dense stacks,
    ``splat_truth`` and ``dominant``).

    The beams are cut into blocks (``blocks``); a block deposits only into its own beams' cells,
    its own share of ``table`` and its own points, and :meth:`finish` resolves its cells (every
    cell of its beams' columns of the outputs), so blocks run at once.

    The dominance state and the moments are kept beam-major (cell ``beam * n_range_bins +
    bin``): a path's range cell is a run of consecutive bins of one beam, and the paths of a
    beam arrive in elevation order, near each other in range, so a deposit touches a cache
    line or two where the image's bin-major layout takes one per bin.

    Parameters
    ----------
    instance : (n_maps, n_range_bins, n_beams) int32, uninitialised
        Receive the frame's instance maps (:meth:`finish`): the orders
        1 .. n_maps - 1, then the total (or the total alone).
    objects, planes : (n_range_bins, n_beams) int32, uninitialised, or (0, n_beams): not formed
        Receive the first order's dominant object and dominant plane.
    elevation : (3, n_range_bins, n_beams) float32, uninitialised
        Receives the mean, least and greatest arrival elevation of the total's paths, degrees
        (NaN where none).
    boxes : (n_blocks, n_ids, 4) int32, -1 filled
        Receives each block's boxes of the ids in the total.
    cells : (n_maps, n_range_bins * n_beams * 2) int32, state -1 in every cell
        The maps' dominance state (``MapCell``, beam-major). The state MUST be -1 in every cell
        (not checked: a scan would cost a few per cent of a frame; any other value is read as
        an id or a table row): fill a new array with -1. :meth:`resolve` sets every cell it
        resolves back to -1, so a frame whose blocks all resolved leaves it ready for the next
        (``compiled.LabelScratch`` keeps it between frames on that condition).
    touched : (n_maps, n_beams * tiles_of(n_range_bins)) uint8, 0 everywhere
        Whether a path reached a cell of each beam's tile of :data:`RESOLVE_TILE` range rows
        (set where a cell is first reached; :meth:`resolve` reads only those tiles' cells and
        sets them back to 0, as it does the state).
    table : (capacity, n_ids) float32, uninitialised
        A row for every cell of every map (each becomes mixed at most once; block k's rows
        from ``n_maps * n_range_bins * b0`` on); only the rows of mixed cells are touched.
    moments : (n_range_bins * n_beams * 3) float64, uninitialised
        The total's moments per cell (``CellMoments``, beam-major), written where a cell is
        first reached (read only there).
    lut : (n_surfaces,) int32
        Label id (``0 .. n_ids - 1``) of each surface id.
    elevation_rows : (n_elevation,) float64
        Arrival elevation of each elevation row of the fan, degrees.
    spread : bool
    range_min, dr : float
        The image's first range, metres, and the bin size, metres.
    blocks : (n_blocks + 1,) intp
        The blocks' first beams, then ``n_beams``.
    n_objects : int
        Label ids below it are objects, the others planes.
    p_world, p_object, p_component, p_cell : (n, 3) float32, (n,) int32, (n,) int8, (n, 2) int32
        Receive the points; ``n`` at least the number of paths of the frame.
    """
    cdef int[:, :, ::1] instance
    cdef int[:, ::1] objects, planes
    cdef float[:, :, ::1] elevation
    cdef int[:, :, ::1] boxes
    cdef int[:, ::1] cells
    cdef Py_ssize_t[:, ::1] n_reached
    cdef unsigned char[:, ::1] touched
    cdef Py_ssize_t n_tiles
    cdef float[:, ::1] table
    cdef double[::1] moments
    cdef const int[::1] lut
    cdef const double[::1] elevation_rows
    cdef const Py_ssize_t[::1] blocks
    cdef Py_ssize_t[::1] n_slots, seg_count
    cdef unsigned char[::1] finished
    cdef float[:, ::1] p_world
    cdef int[::1] p_object
    cdef signed char[::1] p_component
    cdef int[:, ::1] p_cell
    cdef double range_min, dr
    cdef Py_ssize_t n_maps, n_rows, n_beams, n_elevation, n_ids, n_blocks
    cdef int n_objects
    cdef bint spread, split
    cdef int bad_surface
    cdef readonly Py_ssize_t n_points

    def __init__(self, int[:, :, ::1] instance, int[:, ::1] objects, int[:, ::1] planes,
                 float[:, :, ::1] elevation, int[:, :, ::1] boxes, int[:, ::1] cells, unsigned char[:, ::1] touched,
                 float[:, ::1] table, double[::1] moments, const int[::1] lut, const double[::1] elevation_rows,
                 bint spread, double range_min, double dr, const Py_ssize_t[::1] blocks, int n_objects,
                 float[:, ::1] p_world, int[::1] p_object, signed char[::1] p_component, int[:, ::1] p_cell):
        cdef Py_ssize_t k, n_cells
        self.n_maps, self.n_rows, self.n_beams = instance.shape[0], instance.shape[1], instance.shape[2]
        n_cells = self.n_rows * self.n_beams
        self.n_ids = table.shape[1]
        if self.n_maps < 1:
            raise ValueError("no map of the total")
        self.split = objects.shape[0] > 0
        if (self.split and (objects.shape[0] != self.n_rows or planes.shape[0] != self.n_rows
                            or objects.shape[1] != self.n_beams or planes.shape[1] != self.n_beams)
                or elevation.shape[0] != 3 or elevation.shape[1] != self.n_rows or elevation.shape[2] != self.n_beams
                or cells.shape[0] < self.n_maps or cells.shape[1] != 2 * n_cells
                or moments.shape[0] != 3 * n_cells or touched.shape[0] < self.n_maps
                or touched.shape[1] != self.n_beams * tiles_of(self.n_rows)):
            raise ValueError("label maps of different shapes")
        if table.shape[0] < self.n_maps * n_cells:
            raise ValueError(f"a table of {table.shape[0]} rows for {self.n_maps * n_cells} cells")
        for k in range(lut.shape[0]):
            if not 0 <= lut[k] < self.n_ids:
                raise ValueError(f"label id {lut[k]} of surface {k} is not one of the table's {self.n_ids}")
        if elevation_rows.shape[0] == 0:
            raise ValueError("no elevation rows")
        if blocks.shape[0] < 2 or blocks[0] != 0 or blocks[blocks.shape[0] - 1] != self.n_beams:
            raise ValueError(f"blocks of beams {np.asarray(blocks).tolist()} do not cut 0:{self.n_beams}")
        for k in range(blocks.shape[0] - 1):
            if blocks[k + 1] < blocks[k]:
                raise ValueError(f"blocks of beams {np.asarray(blocks).tolist()} are not ascending")
        if boxes.shape[0] != blocks.shape[0] - 1 or boxes.shape[1] != self.n_ids or boxes.shape[2] != 4:
            raise ValueError("boxes of the wrong shape")
        if not 0 <= n_objects <= self.n_ids:
            raise ValueError(f"{n_objects} objects of {self.n_ids} ids")
        if (p_world.shape[1] != 3 or p_cell.shape[1] != 2 or p_world.shape[0] != p_object.shape[0]
                or p_component.shape[0] != p_object.shape[0] or p_cell.shape[0] != p_object.shape[0]):
            raise ValueError("point buffers of different lengths")
        self.instance, self.objects, self.planes, self.elevation, self.boxes = instance, objects, planes, elevation, boxes
        self.cells, self.table, self.moments = cells, table, moments
        self.touched, self.n_tiles = touched, tiles_of(self.n_rows)
        self.n_blocks = blocks.shape[0] - 1
        self.blocks = blocks
        self.n_objects = n_objects
        self.n_reached = np.zeros((self.n_blocks, self.n_maps), np.intp)
        self.n_slots = np.zeros(self.n_blocks, np.intp)
        self.finished = np.zeros(self.n_blocks, np.uint8)
        self.seg_count = np.zeros(0, np.intp)
        self.lut, self.elevation_rows = lut, elevation_rows
        self.n_elevation = elevation_rows.shape[0]
        self.spread, self.range_min, self.dr = spread, range_min, dr
        self.p_world, self.p_object, self.p_component, self.p_cell = p_world, p_object, p_component, p_cell
        self.n_points = 0
        self.bad_surface = -1

    cdef Py_ssize_t deposit(self, Py_ssize_t blk, const double* points, const float* normals, const int* key,
                            const int* sid, const Py_ssize_t* ray, const double* distance, const double* energy,
                            const int* beam, const signed char* label, Py_ssize_t m, Py_ssize_t order_map,
                            bint moments, float* image, Py_ssize_t pt_start) noexcept nogil:
        """One compact path set of block ``blk`` (rays ascending; the receive leg ``points``,
        ``normals``, ``key``, ``sid`` dense over the fan): its energy to map ``order_map`` (-1:
        none) and, with ``moments``, to the total's map and the elevation moments; its points
        (the paths with energy whose half length lies in the image) to the point buffers from
        ``pt_start`` on. With ``image`` (the flat stack), also splats the set there as
        ``splat_events`` does: one range cell per path for both. Returns the points written;
        a path on a surface outside ``lut`` stops it (``bad_surface``)."""
        cdef Py_ssize_t k, b, b_end, i, n_lut = self.lut.shape[0], b0 = self.blocks[blk]
        cdef Py_ssize_t n_ids = self.n_ids, n_beams = self.n_beams, n_el = self.n_elevation
        cdef Py_ssize_t n_pts = pt_start, column = 0, column_end = 0, n_rows = self.n_rows
        cdef Py_ssize_t slot_base = self.n_maps * n_rows * b0, run
        cdef bint c_dn = False, c_up, by_order = order_map >= 0, spread = self.spread, cells
        cdef double x, x_dn = 0.0, x_up, lo, hi, density, part, el, v
        cdef double nb = <double>n_rows, range_min = self.range_min, dr = self.dr
        cdef float pf, elf
        cdef int ident = 0, surface = 0, index
        cdef MapCell* order_cells = NULL
        cdef Py_ssize_t* n_order = NULL
        cdef MapCell* total_cells = NULL
        cdef unsigned char* order_touched = NULL
        cdef unsigned char* total_touched = NULL
        cdef Py_ssize_t tile_column = 0
        cdef Py_ssize_t n_tiles = self.n_tiles
        cdef Py_ssize_t* n_total = NULL
        cdef CellMoments* mom = NULL
        cdef CellMoments* cm
        # The counters in locals while the loop runs (through their own pointers the compiler
        # would reload them after every store).
        cdef Py_ssize_t slots = self.n_slots[blk], n_ord = 0, n_tot = 0
        cdef Py_ssize_t* n_slots = &slots
        cdef float* table = &self.table[0, 0] if self.table.shape[0] > 0 and n_ids > 0 else NULL
        cdef float* column_out
        cdef const int* lut = &self.lut[0] if n_lut > 0 else NULL
        cdef const double* el_rows = &self.elevation_rows[0]
        if n_rows * n_beams == 0:  # an empty image: no deposit
            by_order = moments = False
        if by_order:
            order_cells = <MapCell*>&self.cells[order_map, 0]
            order_touched = &self.touched[order_map, 0]
            n_ord = self.n_reached[blk, order_map]
            n_order = &n_ord
        if moments:
            total_cells = <MapCell*>&self.cells[self.n_maps - 1, 0]
            total_touched = &self.touched[self.n_maps - 1, 0]
            n_tot = self.n_reached[blk, self.n_maps - 1]
            n_total = &n_tot
            mom = <CellMoments*>&self.moments[0]
        cells = by_order or moments or image != NULL
        for k in range(m):
            i = ray[k]
            surface = sid[i]
            if not 0 <= surface < n_lut:
                self.bad_surface = surface
                break
            ident = lut[surface]
            if cells:
                c_up = spread and neighbours(points, normals, key, ray, energy, m, k, n_el)
                x = (distance[k] - range_min) / dr
                x_up = (distance[k + 1] - range_min) / dr if c_up else 0.0
                # A path without energy lands nowhere (as in the twin's range cells): it
                # would start a cell's elevation extremes without being part of its echo.
                if energy[k] != 0 and range_cell(x, x_dn, x_up, c_dn, c_up, energy[k], nb, &lo, &hi, &density):
                    if i >= column_end:  # rays ascend: one division per column of the fan
                        column = i - i % n_el
                        column_end = column + n_el
                    el = el_rows[i - column]
                    elf = <float>el  # the outputs are float32: the extremes of the rounded values
                    b_end = bin_end(hi)
                    column_out = image + <Py_ssize_t>label[k] * n_rows * n_beams + beam[k] if image != NULL else NULL
                    run = beam[k] * n_rows  # the beam's cells, beam-major
                    tile_column = beam[k] * n_tiles  # the beam's tiles
                    for b in range(<Py_ssize_t>lo, b_end):
                        part = density * ((hi if hi < b + 1.0 else b + 1.0) - (lo if lo > b else <double>b))
                        pf = <float>part
                        if column_out != NULL:
                            column_out[b * n_beams] += pf
                        index = <int>(run + b)
                        if by_order:
                            if add_to_map(order_cells + index, table, n_ids, slot_base, n_slots, n_order, ident, pf):
                                order_touched[tile_column + b // RESOLVE_TILE] = 1
                        if moments:
                            cm = mom + index
                            if add_to_map(total_cells + index, table, n_ids, slot_base, n_slots, n_total, ident, pf):
                                total_touched[tile_column + b // RESOLVE_TILE] = 1
                                cm.weight = part  # first reached: the moments start here
                                cm.weighted = part * el
                                cm.lo = elf
                                cm.hi = elf
                            else:
                                cm.weight += part
                                cm.weighted += part * el
                                # Equal values are equal bits (one elevation per fan row).
                                cm.lo = cm.lo if cm.lo < elf else elf
                                cm.hi = cm.hi if cm.hi > elf else elf
                c_dn = c_up
                x_dn = x
            # The bin floor((d - min) / dr) is in [0, n) exactly when v is: no floor() call.
            v = (distance[k] - range_min) / dr
            if v >= 0.0 and v < nb and energy[k] != 0:
                self.p_world[n_pts, 0] = <float>points[3 * i]
                self.p_world[n_pts, 1] = <float>points[3 * i + 1]
                self.p_world[n_pts, 2] = <float>points[3 * i + 2]
                self.p_object[n_pts] = ident
                self.p_component[n_pts] = label[k]
                self.p_cell[n_pts, 0] = <int>v
                self.p_cell[n_pts, 1] = beam[k]
                n_pts += 1
        self.n_slots[blk] = slots
        if by_order:
            self.n_reached[blk, order_map] = n_ord
        if moments:
            self.n_reached[blk, self.n_maps - 1] = n_tot
        return n_pts - pt_start

    def add(self, const double[:, ::1] points, const float[:, ::1] normals, const int[::1] key,
            const int[::1] sid, const Py_ssize_t[::1] ray, const double[::1] distance, const double[::1] energy,
            const int[::1] beam, const signed char[::1] label, Py_ssize_t order_map, bint moments):
        """One compact path set formed after the frame (one block of every beam only): its
        energy to map ``order_map`` (-1: none) and, with ``moments``, to the total's map and
        the elevation moments; its points after those already kept.

        ``points``, ``normals``, ``key``, ``sid``: the receive leg, dense over the fan; ``ray``,
        ``distance``, ``energy``, ``beam``, ``label``: the set, rays ascending.
        """
        cdef Py_ssize_t m = ray.shape[0], n_fan = sid.shape[0], k
        if self.n_blocks != 1:
            raise ValueError("add() deposits into one block of every beam")
        if self.finished[0]:
            raise ValueError("the label maps are already resolved")
        if label.shape[0] != m or distance.shape[0] != m or energy.shape[0] != m or beam.shape[0] != m:
            raise ValueError("path set arrays of different lengths")
        if (points.shape[0] != n_fan or normals.shape[0] != n_fan or key.shape[0] != n_fan
                or points.shape[1] != 3 or normals.shape[1] != 3):
            raise ValueError("receive leg arrays of different lengths")
        if self.n_points + m > self.p_object.shape[0]:
            raise ValueError("more paths than the point buffers hold")
        if not -1 <= order_map < self.n_maps - 1:
            raise ValueError(f"order map {order_map} of {self.n_maps - 1}")
        for k in range(m):
            if not 0 <= ray[k] < n_fan or not 0 <= beam[k] < self.n_beams or (k and ray[k] <= ray[k - 1]):
                raise ValueError(f"path {k}: ray {ray[k]} of {n_fan} (ascending), beam {beam[k]} of {self.n_beams}")
        if m == 0:
            return
        with nogil:
            self.n_points += self.deposit(0, &points[0, 0], &normals[0, 0], &key[0], &sid[0], &ray[0], &distance[0],
                                          &energy[0], &beam[0], &label[0], m, order_map, moments, NULL,
                                          self.n_points)
        self.check()

    def unused(self):
        """Whether nothing was deposited or resolved yet (a LabelMaps serves one frame)."""
        cdef Py_ssize_t k, mp
        if self.n_points:
            return False
        for k in range(self.n_blocks):
            if self.finished[k] or self.n_slots[k]:
                return False
            for mp in range(self.n_maps):
                if self.n_reached[k, mp]:
                    return False
        return True

    def check(self):
        """Raise where a deposit met a path on a surface outside ``lut``."""
        if self.bad_surface >= 0:
            raise ValueError(f"a path on surface {self.bad_surface}, not one of the {self.lut.shape[0]}")

    def compact(self, const Py_ssize_t[::1] offset):
        """Gather the points that :class:`PathBlocks` wrote segment by segment (segment s from
        ``offset[s]`` on, ``seg_count[s]`` of them) into one run, in segment order (the path
        buffer's: option-major, block after block). Sets :attr:`n_points`."""
        cdef Py_ssize_t s, n, o, j = 0
        if offset.shape[0] != self.seg_count.shape[0]:
            raise ValueError(f"{offset.shape[0]} segments for {self.seg_count.shape[0]} counts")
        for s in range(offset.shape[0]):
            o, n = offset[s], self.seg_count[s]
            if n < 0 or o < j or o + n > self.p_object.shape[0]:
                raise ValueError(f"point segment {s} ({o}, {n}) overlaps or leaves the buffers")
            j = o + n  # (segments ascend: each moves down, never over one not yet moved)
        j = 0
        with nogil:
            for s in range(offset.shape[0]):
                o, n = offset[s], self.seg_count[s]
                if n and o != j:
                    memmove(&self.p_world[j, 0], &self.p_world[o, 0], n * 3 * sizeof(float))
                    memmove(&self.p_object[j], &self.p_object[o], n * sizeof(int))
                    memmove(&self.p_component[j], &self.p_component[o], n * sizeof(signed char))
                    memmove(&self.p_cell[j, 0], &self.p_cell[o, 0], n * 2 * sizeof(int))
                j += n
        self.n_points = j

    cdef void fill_rows_of(self, Py_ssize_t b0, Py_ssize_t b1, Py_ssize_t r0, Py_ssize_t r1) noexcept nogil:
        """Rows ``r0:r1`` of beams ``b0:b1`` of the outputs set to "nothing"."""
        cdef Py_ssize_t mp, i, r
        cdef Py_ssize_t w = b1 - b0
        cdef float* el
        if w <= 0:
            return
        for r in range(r0, r1):
            for mp in range(self.n_maps):
                memset(&self.instance[mp, r, b0], 0xFF, w * sizeof(int))  # all bits set: -1
            if self.split:
                memset(&self.objects[r, b0], 0xFF, w * sizeof(int))
                memset(&self.planes[r, b0], 0xFF, w * sizeof(int))
            for mp in range(3):
                el = &self.elevation[mp, r, b0]
                for i in range(w):
                    el[i] = NAN

    def finish(self, Py_ssize_t blk):
        """:meth:`resolve` block ``blk`` (for :meth:`add`'s route: :class:`PathBlocks` resolves
        each block right after its paths)."""
        self.check()
        if not 0 <= blk < self.n_blocks or self.finished[blk]:
            raise ValueError(f"block {blk} of {self.n_blocks} (each resolved once)")
        with nogil:
            self.resolve(blk)

    cdef void resolve(self, Py_ssize_t blk) noexcept nogil:
        """Resolve block ``blk``'s cells into the outputs, every cell of its beams' columns,
        and set the state of those it reached back to -1. Only block ``blk`` deposits into its
        cells, so it resolves them as soon as its own paths are in, on its own thread.

        Each cell takes its dominant id (ties: the lower id; -1 where no id brought energy or
        no path reached it). With ``objects`` / ``planes``, map 0 (the first order) also gives
        the dominant object and the dominant plane of each cell, and its own value is the
        stronger of the two (a tie: the object). The elevation's mean is weighted / weight
        where the total has paths (0 / 0: NaN, no weight), NaN (and the least and greatest
        too) where it has none; ``boxes[blk]`` the inclusive ``[row, beam, row, beam]`` extent
        of each id's cells in the total.

        The state is beam-major (a path's bins are contiguous) and the outputs row-major: the
        cells are visited in tiles of :data:`RESOLVE_TILE` rows across the block's beams, so
        that both the state read and the outputs written stay in cache (writing each reached
        cell where it lies, after filling the whole block, cost twice as much).
        """
        cdef Py_ssize_t mp, j, n_r = self.n_rows, n_b = self.n_beams, n_ids = self.n_ids, at, plane
        cdef Py_ssize_t r0, r1, b0 = self.blocks[blk], b1 = self.blocks[blk + 1], index
        cdef int s, best, obj, gnd, r, c, n_obj = self.n_objects
        cdef float to, tg
        cdef bint both, last
        cdef MapCell* st
        cdef MapCell* cell
        cdef int* out
        cdef int* o_out = NULL
        cdef int* g_out = NULL
        cdef float* el = NULL
        cdef const float* row
        cdef const float* table = &self.table[0, 0] if self.table.shape[0] > 0 and n_ids > 0 else NULL
        cdef const CellMoments* mom = <CellMoments*>&self.moments[0] if self.moments.shape[0] > 0 else NULL
        cdef const CellMoments* cm
        cdef int* box = &self.boxes[blk, 0, 0] if n_ids > 0 else NULL
        cdef unsigned char* flags
        cdef int run_id = -1, run_first = 0, run_last = 0
        self.finished[blk] = 1
        if n_r * n_b == 0 or b1 <= b0 or self.bad_surface >= 0:
            return
        plane = n_r * n_b
        el = &self.elevation[0, 0, 0]
        if self.split:
            o_out = &self.objects[0, 0]
            g_out = &self.planes[0, 0]
        cdef Py_ssize_t tile
        for tile in range((n_r + RESOLVE_TILE - 1) // RESOLVE_TILE):
            r0 = tile * RESOLVE_TILE
            r1 = r0 + RESOLVE_TILE if r0 + RESOLVE_TILE < n_r else n_r
            self.fill_rows_of(b0, b1, r0, r1)  # "nothing", in cache for the reached cells' values
            for mp in range(self.n_maps):
                st = <MapCell*>&self.cells[mp, 0]
                out = &self.instance[mp, 0, 0]
                both = self.split and mp == 0
                last = mp == self.n_maps - 1
                flags = &self.touched[mp, 0]
                for c in range(<int>b0, <int>b1):
                    if not flags[c * self.n_tiles + tile]:  # no path reached the beam's tile: as filled
                        continue
                    flags[c * self.n_tiles + tile] = 0
                    run_id = -1
                    for r in range(<int>r0, <int>r1):
                        index = <Py_ssize_t>c * n_r + r
                        at = r * n_b + c
                        cell = st + index
                        s = cell.state
                        if s == -1:  # no path reached the cell: as filled
                            continue
                        if s >= 0:
                            best = s if cell.first > 0 else -1
                            obj = best if best < n_obj else -1
                            gnd = best if best >= n_obj else -1
                        else:
                            row = table + (-2 - <Py_ssize_t>s) * n_ids
                            if both:
                                obj = strongest(row, 0, n_obj, &to)
                                gnd = strongest(row, n_obj, n_ids, &tg)
                                best = gnd if tg > to else obj
                            else:
                                best = strongest(row, 0, n_ids, &to)
                        cell.state = -1  # ready for the next frame
                        out[at] = best
                        if both:
                            o_out[at] = obj
                            g_out[at] = gnd
                        if last:
                            cm = mom + index
                            el[at] = <float>(cm.weighted / cm.weight)
                            el[plane + at] = cm.lo
                            el[2 * plane + at] = cm.hi
                            # An id's cells come in runs down a beam (rows ascend): its box
                            # takes a run's first and last row once, not every cell's.
                            if best != run_id:
                                if run_id >= 0:
                                    add_to_box(box + 4 * run_id, run_first, run_last, c)
                                run_id = best
                                run_first = r
                            run_last = r
                    if run_id >= 0:
                        add_to_box(box + 4 * run_id, run_first, run_last, c)

    def resolved(self):
        """Whether every block was resolved (:meth:`resolve` or :meth:`finish`)."""
        cdef Py_ssize_t k
        for k in range(self.n_blocks):
            if not self.finished[k]:
                return False
        return True

    def united_boxes(self, int[:, ::1] out):
        """The blocks' boxes of each id united into ``out`` (n_ids, 4) (-1: in no block)."""
        cdef Py_ssize_t k, i, n_ids = self.n_ids
        cdef int* b
        if out.shape[0] != n_ids or out.shape[1] != 4:
            raise ValueError("boxes of the wrong shape")
        for i in range(n_ids):
            out[i, 0] = out[i, 1] = out[i, 2] = out[i, 3] = -1
            for k in range(self.n_blocks):
                b = &self.boxes[k, i, 0]
                if b[0] < 0:
                    continue
                if out[i, 0] < 0:
                    out[i, 0], out[i, 1], out[i, 2], out[i, 3] = b[0], b[1], b[2], b[3]
                else:
                    out[i, 0] = min(out[i, 0], b[0])
                    out[i, 1] = min(out[i, 1], b[1])
                    out[i, 2] = max(out[i, 2], b[2])
                    out[i, 3] = max(out[i, 3], b[3])


cdef class PathBlocks:
    """The general path engine for a block of beams in one call: rotate the block's rays, cast
    them, trace their receive legs generation by generation (casting each generation's
    reflected rays), and then -- once the frame's chains are known (:meth:`paths`) -- form its
    paths into the path buffer and splat them into the block's own image columns. Twin of the
    stage-by-stage NumPy engine (``sonarsim.paths.engine``), kernel for kernel.

    A block writes only its own rays' entries, its own rows of the ray buffers, its own chain
    table and (splatting) its own beams' columns, so blocks run on any thread at once (the GIL
    is released) and the frame is the same bits whichever thread took which block, and however
    the beams are cut into blocks: chains are numbered per block while tracing and renumbered
    to the frame's canonical ids (``ChainTable.canonical``) before the paths are formed.

    Casting goes through the Embree 4 binding's packet loop where the caster lends it (``cast``
    of :meth:`trace`); elsewhere (embreex, the NumPy caster, textures) Python casts between
    :meth:`begin` / :meth:`step`, which run the very same code on the hits it passes.

    Parameters
    ----------
    work : renderer.compiled.Workspace
        The per-ray buffers (``d64``, ``d32``, ``o32``, ``h_*``, the ray buffers ``r_*``, ``ray0``).
    directions : (n, 3) float64, the fan's rays in the sonar frame
    weight : (n,) float64
    albedo_by_id, law_by_id, lobe_by_id : the surfaces' laws (as :func:`trace_leg`)
    plane_normal, plane_offset, plane_specular : the planes (``PlaneSet``)
    n_blocks, capacity : int
        Blocks of a frame, and the rows of each block's chain table.
    scene, scene_address, cast_address, ids, coherent : optional
        The binding's packet loop (``Embree4Caster.packet_loop()``); None: Python casts.
    """

    cdef object keep
    cdef void* scene
    cdef cast_rays_t cast
    cdef const int[::1] ids
    cdef bint coherent
    cdef readonly bint fused
    cdef _Laws laws
    cdef const double[:, ::1] fan_dirs
    cdef const double[::1] weight, albedo
    cdef const double[:, ::1] plane_normal
    cdef const double[::1] plane_offset, plane_specular
    cdef double[:, ::1] d64
    cdef float[:, ::1] d32, o32, h_normal
    cdef float[::1] h_dist
    cdef int[::1] h_mesh, h_prim
    cdef float[:, ::1] h_uv
    cdef const Py_ssize_t[::1] ray0
    cdef const double[::1] ones
    cdef const int[::1] zeros
    cdef Py_ssize_t[:, ::1] r_ray
    cdef double[:, :, ::1] r_org, r_dir
    cdef float[:, :, ::1] r_org32, r_dir32
    cdef double[:, ::1] r_before, r_atten
    cdef int[:, ::1] r_chain
    cdef readonly object children_array
    cdef int[:, :, ::1] children
    # Mesh mirrors (set_mirrors): their tables, the planes then their planes, and each block's
    # open-addressing table of the chains that end on one; every block's chains' parents.
    cdef Mirrors mirrors
    cdef const MirrorTables* mt
    cdef const double[:, ::1] surf_normal
    cdef const double[::1] surf_offset
    cdef int64_t[:, ::1] hkeys
    cdef int[:, ::1] hvals
    cdef int[:, ::1] parent, last_mirror
    cdef readonly object parent_array, last_array
    cdef int[::1] n_local
    cdef unsigned char[::1] overflow
    cdef Py_ssize_t[::1] blk_cur, blk_m, blk_gen
    cdef double[::1] blk_min
    cdef readonly Py_ssize_t n_blocks
    # Per frame.
    cdef double[:, ::1] dist, intensity, atten, cosine
    # The specular returns (frame(glint_radius=...)): each generation's rays that, reflected at
    # its scatterer, come back to the sonar (engine.returns_to_sonar); glint_r2 <= 0: not traced.
    cdef double[:, ::1] back_length, back_atten
    cdef double[:, :, ::1] back_dir
    cdef int[:, ::1] back_chain
    cdef double glint_r2
    cdef float[:, ::1] texel
    cdef int[:, ::1] sid, chain, key, prim
    cdef double[:, :, ::1] point
    cdef float[:, :, ::1] normal
    cdef float[:, :, ::1] uv
    cdef bint primitives
    cdef int[::1] no_prim
    cdef float[:, ::1] no_uv
    cdef Py_ssize_t[:, ::1] live, n_live, n_cast
    cdef const unsigned char[::1] active
    cdef const double[:, ::1] rotation
    cdef const double[::1] edges
    cdef const double[::1] tan_edges
    cdef double sin_half
    cdef double origin[3]
    cdef const double[:, ::1] origin2
    cdef const double[::1] before1
    cdef float origin32[3]
    # Several poses in one frame (frame()'s pose_rotation, pose_origin): each pose's rays are
    # rays_per_pose consecutive rays, rotated and placed by their own pose (direct paths only).
    cdef bint multi
    cdef const double[:, :, ::1] pose_rot
    cdef const double[:, ::1] pose_org
    cdef double[:, ::1] o64
    cdef double[::1] before_n
    cdef Py_ssize_t rays_per_pose
    cdef double reach, range_min, range_max, dr, half_el
    cdef bint tvg, spread, cone
    cdef int separate  # PAIRS_ONCE, PAIRS_SEPARATE or PAIRS_COHERENT
    cdef Py_ssize_t n_gen, n_el, n_bins, n_beams, rays_per_beam, n_surfaces, n_planes
    cdef bint ready
    # Per frame, after tracing (options()).
    cdef const int[::1] opt_gen, opt_tx, opt_same, opt_label, opt_len, rank, opt_only
    cdef const double[:, :, ::1] opt_unfold, opt_sources
    cdef const int[:, ::1] opt_planes
    cdef const double[::1] opt_specular
    cdef const int[:, ::1] remap
    cdef Py_ssize_t[::1] p_offset, p_count
    # Each block's live rays of a generation whose chain outranks the last transmit option's
    # (paths()), in its own rows.
    cdef Py_ssize_t[::1] subset
    # The counting pass (options(counting=True)): its scratch, and each option's room after it.
    cdef Py_ssize_t[::1] scratch_ray
    cdef double[::1] scratch_dist, scratch_energy
    cdef int[::1] scratch_beam, scratch_beam_tx
    cdef signed char[::1] scratch_label
    cdef const Py_ssize_t[::1] capacity
    cdef bint counting
    cdef unsigned char[::1] remapped
    cdef unsigned char[::1] miscounted  # a block formed other than the counting pass counted
    cdef Py_ssize_t[::1] p_ray
    cdef double[::1] p_dist, p_energy
    cdef int[::1] p_beam, p_beam_tx
    cdef signed char[::1] p_label
    cdef float[::1] out, total
    cdef LabelMaps labels
    cdef const int[::1] opt_map
    cdef const unsigned char[::1] opt_moments
    cdef bint has_labels
    cdef int total_rows[16]
    cdef int n_total_rows
    cdef bint paths_ready, splat
    cdef const Reflectance* rf  # NULL: the mirrors' constant reflectances
    cdef ReflectanceTable reflectance

    def __init__(self, work, const double[:, ::1] directions, const double[::1] weight,
                 const double[::1] albedo_by_id, law_by_id, lobe_by_id, const double[:, ::1] plane_normal,
                 const double[::1] plane_offset, const double[::1] plane_specular, Py_ssize_t n_blocks,
                 Py_ssize_t capacity, scene=None, size_t scene_address=0, size_t cast_address=0, ids=None,
                 bint coherent=False, Mirrors mirrors=None, ReflectanceTable reflectance=None):
        w = work
        if w.n != directions.shape[0] or weight.shape[0] != w.n:
            raise ValueError(f"a workspace of {w.n} rays for {directions.shape[0]} directions and {weight.shape[0]} weights")
        if plane_offset.shape[0] != plane_normal.shape[0] or plane_specular.shape[0] != plane_normal.shape[0]:
            raise ValueError("plane arrays of different lengths")
        if n_blocks < 1 or capacity < 1:
            raise ValueError("at least one block and one chain")
        self.fused = scene is not None
        if self.fused and (scene_address == 0 or cast_address == 0):
            raise ValueError("no Embree scene or packet loop")
        self.keep = (scene, ids, directions, weight, albedo_by_id, law_by_id, lobe_by_id, plane_normal, plane_offset,
                     plane_specular)
        self.scene = <void*>scene_address
        self.cast = <cast_rays_t>cast_address
        if ids is not None:
            self.ids = ids
        self.coherent = coherent
        self.laws = _Laws(law_by_id, lobe_by_id, None, albedo_by_id.shape[0], 0)
        self.fan_dirs, self.weight, self.albedo = directions, weight, albedo_by_id
        self.plane_normal, self.plane_offset, self.plane_specular = plane_normal, plane_offset, plane_specular
        self.n_planes = plane_normal.shape[0]
        self.mirrors = mirrors
        self.reflectance = reflectance
        self.rf = NULL
        if reflectance is not None:
            if reflectance.t.rows != albedo_by_id.shape[0]:
                raise ValueError(f"a reflectance table of {reflectance.t.rows} rows for {albedo_by_id.shape[0]} "
                                 f"surfaces (+ 1)")
            self.rf = &reflectance.t
        self.mt = NULL
        self.surf_normal, self.surf_offset = plane_normal, plane_offset
        if mirrors is not None and mirrors.n_mirrors:
            self.mt = &mirrors.t
            self.surf_normal = np.concatenate([np.asarray(plane_normal).reshape(-1, 3),
                                               mirrors.arrays["mirror_normal"]])
            self.surf_offset = np.concatenate([np.asarray(plane_offset), mirrors.arrays["mirror_offset"]])
        self.d64, self.d32, self.o32 = w.d64, w.d32, w.o32
        self.h_dist, self.h_mesh, self.h_normal = w.h_dist, w.h_mesh, w.h_normal
        self.h_prim, self.h_uv = w.h_prim, w.h_uv
        self.no_prim, self.no_uv = np.zeros(0, np.int32), np.zeros((0, 2), np.float32)
        self.ray0, self.ones, self.zeros = w.ray0, w.ones, w.zeros_i32
        self.r_ray, self.r_org, self.r_dir, self.r_org32, self.r_dir32 = w.r_ray, w.r_org, w.r_dir, w.r_org32, w.r_dir32
        self.r_before, self.r_atten, self.r_chain = w.r_before, w.r_atten, w.r_chain
        self.n_blocks = n_blocks
        self.n_local = np.zeros(n_blocks, np.int32)
        self.grow(capacity)
        self.subset = np.empty(w.n, np.intp)
        self.scratch_ray = np.empty(0, np.intp)
        self.remapped = np.zeros(n_blocks, np.uint8)
        self.miscounted = np.zeros(n_blocks, np.uint8)
        self.overflow = np.zeros(n_blocks, np.uint8)
        self.blk_cur = np.zeros(n_blocks, np.intp)
        self.blk_m = np.zeros(n_blocks, np.intp)
        self.blk_gen = np.full(n_blocks, -1, np.intp)  # each block's next generation (-1: not begun)
        self.blk_min = np.zeros(n_blocks)
        self.before1 = np.zeros(1)
        self.ready = False
        self.paths_ready = False

    def grow(self, Py_ssize_t capacity):
        """Give each block a chain table of ``capacity`` rows (after an overflow)."""
        if capacity < 1 or capacity < np.max(self.n_local):
            raise ValueError(f"a chain table of {capacity} rows for blocks that hold {np.max(self.n_local)} chains")
        self.children_array = np.full((self.n_blocks, capacity, max(self.n_planes, 1)), -1, np.int32)
        self.children = self.children_array
        self.parent_array = np.zeros((self.n_blocks, capacity), np.int32)
        self.last_array = np.zeros((self.n_blocks, capacity), np.int32)
        self.parent, self.last_mirror = self.parent_array, self.last_array
        slots = 1 << (2 * capacity - 1).bit_length() if self.mt != NULL else 1
        self.hkeys = np.full((self.n_blocks, slots), -1, np.int64)
        self.hvals = np.zeros((self.n_blocks, slots), np.int32)

    def chain_parents(self):
        """Every block's chains as it numbered them: ``(parent, last, n_chains)``, (n_blocks,
        capacity) int32 twice and (n_blocks,) int32 (block k's chain c, 0 < c < n_chains[k], is
        its chain ``parent[k, c]`` followed by mirror ``last[k, c]``; chain 0 is empty)."""
        return self.parent_array, self.last_array, np.asarray(self.n_local)

    def chain_tables(self):
        """Every block's chain table: ``(children, n_chains)``, (n_blocks, capacity, P) int32 and
        (n_blocks,) int32 (``children[k, c, p]``: block k's chain ``c + (p,)``)."""
        return self.children_array, np.asarray(self.n_local)

    def frame(self, legs, const unsigned char[::1] active, const double[:, ::1] rotation, const double[::1] origin,
              double reach, bint tvg, Py_ssize_t n_gen, Py_ssize_t n_el, double range_min, double dr,
              Py_ssize_t n_bins, Py_ssize_t n_beams, double range_max, double half_el, const double[::1] edges,
              bint spread, int separate, Py_ssize_t n_surfaces, float[::1] out=None, bint primitives=False,
              double glint_radius=0.0, pose_rotation=None, pose_origin=None, bint cone=False):
        """Set the frame (``cone``: the beams are cones, :func:`beam_in_view`): ``out`` (optional: the flat image stack the blocks will splat into;
        block k zeroes its k-th share of the range bins while it traces, whole rows at a time,
        contiguous), ``legs`` (``dist``, ``sid``, ``point``, ``normal``, ``cosine``,
        ``intensity``, ``atten``, ``chain``, ``key``, ``live``: the (n_gen, n, ...) receive legs,
        written by the blocks; ``texel``, (n_gen, n) float32 where objects are textured, else
        None; ``n_live``, ``n_cast``: (n_blocks, n_gen) counts; with ``primitives``, also
        ``prim`` and ``uv``, the search's triangles and barycentrics), the planes the sonar
        faces, the pose, the settings. Everything is checked before anything is kept (the
        kernels read without bounds checks).

        ``pose_rotation`` (P, 3, 3) and ``pose_origin`` (P, 3), float64: P poses in one frame,
        pose p's rays the fan's rays ``p n / P`` to ``(p + 1) n / P`` (the fan is P copies of
        one pose's rays), each rotated and cast from its own pose instead of ``rotation`` and
        ``origin``: pings of an instrument batched (``Simulator.trace``'s ``poses``). Direct
        paths only (one generation, no specular returns): a transmit leg by an image source
        needs the frame's one origin."""
        cdef Py_ssize_t n = self.fan_dirs.shape[0]
        self.ready = False
        self.paths_ready = False
        if active.shape[0] != self.n_planes:
            raise ValueError(f"{active.shape[0]} active flags for {self.n_planes} planes")
        if self.mt != NULL and not primitives:
            raise ValueError("mesh mirrors need the search's triangles (primitives)")
        if glint_radius > 0.0:  # the specular returns: each generation's back_* arrays
            for name in ("back_length", "back_atten", "back_chain", "back_dir"):
                a = getattr(legs, name, None)
                if a is None or a.shape[0] < n_gen or a.shape[1] != n or (name == "back_dir" and a.shape[2] != 3):
                    raise ValueError(f"legs.{name} missing or of the wrong shape for the specular returns")
        if rotation.shape[0] != 3 or rotation.shape[1] != 3 or origin.shape[0] != 3:
            raise ValueError("the rotation is not 3 x 3 or the origin not 3 numbers")
        self.multi = pose_rotation is not None or pose_origin is not None
        if self.multi:
            rot_p = np.ascontiguousarray(pose_rotation, dtype=np.float64)
            org_p = np.ascontiguousarray(pose_origin, dtype=np.float64)
            if (rot_p.ndim != 3 or rot_p.shape[1:] != (3, 3) or org_p.shape != (rot_p.shape[0], 3)
                    or rot_p.shape[0] < 1 or n % rot_p.shape[0] != 0):
                raise ValueError("pose_rotation is not (P, 3, 3), pose_origin not (P, 3), or P does not divide the rays")
            if n_gen != 1 or glint_radius > 0.0:
                raise ValueError("several poses in one frame trace direct paths only (one generation, no glints)")
            self.pose_rot, self.pose_org = rot_p, org_p
            self.rays_per_pose = n // rot_p.shape[0]
            if self.o64 is None or self.o64.shape[0] != n:
                self.o64 = np.empty((n, 3))
                self.before_n = np.zeros(n)
        if n_gen < 1 or n_beams < 1 or n_el < 1 or n % (n_beams * n_el) != 0 or edges.shape[0] != n_beams + 1:
            raise ValueError("the fan's shape does not match the workspace (its beams, rays per beam or edges)")
        for name in ("dist", "cosine", "intensity", "atten", "sid", "chain", "key", "live", "point", "normal") + (
                ("prim", "uv") if primitives else ()) + (("texel",) if legs.texel is not None else ()):
            a = getattr(legs, name)
            if a.ndim < 2 or a.shape[0] < n_gen or a.shape[1] != n or (a.ndim == 3 and a.shape[2] != (2 if name == "uv" else 3)):
                raise ValueError(f"legs.{name} of shape {a.shape} for {n_gen} generations of {n} rays")
        for name in ("n_live", "n_cast"):
            a = getattr(legs, name)
            if a.shape[0] != self.n_blocks or a.shape[1] < n_gen:
                raise ValueError(f"legs.{name} of shape {a.shape} for {self.n_blocks} blocks, {n_gen} generations")
        if out is not None and out.shape[0] % (n_bins * n_beams) != 0:
            raise ValueError("the output stack is not (rows, n_range_bins, n_beams)")
        self.dist, self.sid, self.point, self.normal = legs.dist, legs.sid, legs.point, legs.normal
        self.intensity, self.atten, self.chain, self.key = legs.intensity, legs.atten, legs.chain, legs.key
        self.cosine = legs.cosine
        self.glint_r2 = glint_radius * glint_radius if glint_radius > 0.0 else 0.0
        if self.glint_r2 > 0.0:
            self.back_length, self.back_atten = legs.back_length, legs.back_atten
            self.back_dir, self.back_chain = legs.back_dir, legs.back_chain
        self.texel = legs.texel if legs.texel is not None else np.zeros((n_gen, 0), np.float32)
        self.live, self.n_live, self.n_cast = legs.live, legs.n_live, legs.n_cast
        self.primitives = primitives
        if primitives:
            self.prim, self.uv = legs.prim, legs.uv
        self.active, self.rotation, self.edges = active, rotation, edges
        self.cone = cone
        self.sin_half, self.tan_edges = view_tables(edges, half_el)
        self.remapped[:] = 0
        self.origin2 = np.asarray(origin, dtype=np.float64).reshape(1, 3).copy()
        for k in range(3):
            self.origin[k] = origin[k]
            self.origin32[k] = <float>origin[k]
        self.reach, self.tvg, self.n_gen, self.n_el = reach, tvg, n_gen, n_el
        self.range_min, self.dr, self.n_bins, self.n_beams = range_min, dr, n_bins, n_beams
        self.range_max, self.half_el, self.spread, self.separate = range_max, half_el, spread, separate
        self.rays_per_beam = self.fan_dirs.shape[0] // n_beams
        self.n_surfaces = n_surfaces
        self.out = out
        self.ready = True

    def release(self):
        """Let go of the frame's arrays (the legs, the path buffer, the stack): the caller
        reuses them for a later frame once nothing else holds them."""
        self.dist = self.intensity = self.atten = self.cosine = None
        self.back_length = self.back_atten = None
        self.back_dir = None
        self.back_chain = None
        self.glint_r2 = 0.0
        self.texel = None
        self.sid = self.chain = self.key = None
        self.point = self.normal = None
        self.prim = None
        self.uv = None
        self.live = self.n_live = self.n_cast = None
        self.p_offset = self.p_count = self.p_ray = None
        self.p_dist = self.p_energy = None
        self.p_beam = self.p_beam_tx = None
        self.p_label = None
        self.out = self.total = None
        self.labels = None
        self.opt_map = None
        self.opt_moments = None
        self.opt_only = None
        self.has_labels = False
        self.ready = False
        self.paths_ready = False

    cdef int _check(self, Py_ssize_t k, Py_ssize_t b0, Py_ssize_t b1) except -1:
        if not self.ready:
            raise ValueError("call frame() first")
        if not (0 <= b0 <= b1 <= self.n_beams) or not 0 <= k < self.n_blocks:
            raise ValueError(f"block {k} of {self.n_blocks}, beams {b0}:{b1} of 0:{self.n_beams}")
        return 0

    cdef void _begin(self, Py_ssize_t k, Py_ssize_t a, Py_ssize_t b, bint origins) noexcept nogil:
        """Reset block ``k``'s chains, mark its later generations "nothing", rotate its rays."""
        cdef Py_ssize_t g, i, j, cap = self.children.shape[1], n_p = self.children.shape[2]
        cdef Py_ssize_t p, lo, hi
        cdef int* ch = &self.children[k, 0, 0]
        for j in range(cap * n_p):
            ch[j] = -1
        if self.mt != NULL:
            for j in range(self.hkeys.shape[1]):
                self.hkeys[k, j] = -1
        self.n_local[k] = 1
        self.overflow[k] = 0
        for g in range(self.n_gen):
            self.n_live[k, g] = 0
            self.n_cast[k, g] = 0
        if self.glint_r2 > 0.0:
            for g in range(self.n_gen):
                for i in range(a, b):
                    self.back_length[g, i] = INFINITY
                    self.back_chain[g, i] = -1
        for g in range(1, self.n_gen):
            for i in range(a, b):
                self.dist[g, i] = INFINITY
                self.sid[g, i] = -1
                self.key[g, i] = -1
                if self.primitives:
                    self.prim[g, i] = -1
                    self.uv[g, i, 0] = 0.0
                    self.uv[g, i, 1] = 0.0
        if self.multi:  # each pose's share of the block: its own rotation and origin
            p = a // self.rays_per_pose
            while p * self.rays_per_pose < b:
                lo = max(a, p * self.rays_per_pose)
                hi = min(b, (p + 1) * self.rays_per_pose)
                rotate_impl(self.fan_dirs, self.pose_rot[p], self.d64, self.d32, lo, hi)
                for i in range(lo, hi):
                    self.o64[i, 0] = self.pose_org[p, 0]
                    self.o64[i, 1] = self.pose_org[p, 1]
                    self.o64[i, 2] = self.pose_org[p, 2]
                    self.o32[i, 0] = <float>self.pose_org[p, 0]
                    self.o32[i, 1] = <float>self.pose_org[p, 1]
                    self.o32[i, 2] = <float>self.pose_org[p, 2]
                p += 1
        else:
            rotate_impl(self.fan_dirs, self.rotation, self.d64, self.d32, a, b)
        if origins and not self.multi:
            for i in range(a, b):
                self.o32[i, 0] = self.origin32[0]
                self.o32[i, 1] = self.origin32[1]
                self.o32[i, 2] = self.origin32[2]
        self.blk_m[k] = b - a
        self.blk_cur[k] = 0
        self.blk_gen[k] = 0
        if self.out is not None:
            self._zero(k)

    cdef (Py_ssize_t, Py_ssize_t) _share(self, Py_ssize_t k) noexcept nogil:
        """Block k's share of the range bins: whole image rows, contiguous in memory (a block's
        own beams are strided: zeroing or summing them reads the stack column by column)."""
        return k * self.n_bins // self.n_blocks, (k + 1) * self.n_bins // self.n_blocks

    cdef void _zero(self, Py_ssize_t k) noexcept nogil:
        cdef Py_ssize_t r, j0, j1, plane = self.n_bins * self.n_beams
        j0, j1 = self._share(k)
        for r in range(self.out.shape[0] // plane):
            memset(&self.out[r * plane + j0 * self.n_beams], 0, (j1 - j0) * self.n_beams * sizeof(float))

    cdef void _step(self, Py_ssize_t k, Py_ssize_t a, Py_ssize_t b, Py_ssize_t g, _Laws laws) noexcept nogil:
        """Generation ``g`` of block ``k`` from the hits in ``h_*[a:a + m]`` (m: its rays)."""
        cdef Py_ssize_t m = self.blk_m[k], cur = self.blk_cur[k], nxt = 1 - self.blk_cur[k]
        cdef (Py_ssize_t, int, double, bint, Py_ssize_t) r
        cdef bint reflect = g + 1 < self.n_gen
        self.n_cast[k, g] = m
        # The search (trace_leg_impl) lists the reached rays in live; the weighing reads what it
        # recorded there and keeps those with some energy.
        if g == 0:
            r = trace_leg_impl(self.ray0[a:b], self.h_dist[a:b], self.h_mesh[a:b], self.h_normal[a:b],
                               self.o64[a:b] if self.multi else self.origin2,
                               self.d64[a:b], self.before_n[a:b] if self.multi else self.before1,
                               self.ones[a:b] if self.multi else self.ones[:1],
                               self.zeros[a:b] if self.multi else self.zeros[:1], self.plane_normal,
                               self.plane_offset, self.active, self.plane_specular, self.reach,
                               True, reflect, self.children[k], self.n_local[k], self.dist[0],
                               self.sid[0], self.point[0], self.normal[0], self.cosine[0], self.atten[0],
                               self.chain[0], self.key[0], self.live[0, a:b], <int>self.n_surfaces,
                               self.r_ray[nxt, a:b], self.r_org[nxt, a:b], self.r_org32[nxt, a:b],
                               self.r_dir[nxt, a:b], self.r_dir32[nxt, a:b], self.r_before[nxt, a:b],
                               self.r_atten[nxt, a:b], self.r_chain[nxt, a:b], laws.texel, self.texel[0],
                               self.h_prim[a:b] if self.primitives else self.no_prim,
                               self.h_uv[a:b] if self.primitives else self.no_uv,
                               self.prim[0] if self.primitives else self.no_prim,
                               self.uv[0] if self.primitives else self.no_uv, self.mt, &self.hkeys[k, 0],
                               &self.hvals[k, 0], self.hkeys.shape[1] - 1, &self.parent[k, 0],
                               &self.last_mirror[k, 0], self.rf)
        else:
            r = trace_leg_impl(self.r_ray[cur, a:a + m], self.h_dist[a:a + m], self.h_mesh[a:a + m],
                               self.h_normal[a:a + m], self.r_org[cur, a:a + m], self.r_dir[cur, a:a + m],
                               self.r_before[cur, a:a + m], self.r_atten[cur, a:a + m], self.r_chain[cur, a:a + m],
                               self.plane_normal, self.plane_offset, self.active, self.plane_specular, self.reach,
                               False, reflect, self.children[k],
                               self.n_local[k], self.dist[g], self.sid[g], self.point[g], self.normal[g],
                               self.cosine[g], self.atten[g], self.chain[g], self.key[g], self.live[g, a:b],
                               <int>self.n_surfaces, self.r_ray[nxt, a:b], self.r_org[nxt, a:b],
                               self.r_org32[nxt, a:b], self.r_dir[nxt, a:b], self.r_dir32[nxt, a:b],
                               self.r_before[nxt, a:b], self.r_atten[nxt, a:b], self.r_chain[nxt, a:b], laws.texel,
                               self.texel[g], self.h_prim[a:a + m] if self.primitives else self.no_prim,
                               self.h_uv[a:a + m] if self.primitives else self.no_uv,
                               self.prim[g] if self.primitives else self.no_prim,
                               self.uv[g] if self.primitives else self.no_uv, self.mt, &self.hkeys[k, 0],
                               &self.hvals[k, 0], self.hkeys.shape[1] - 1, &self.parent[k, 0],
                               &self.last_mirror[k, 0], self.rf)
        if g > 0 and self.glint_r2 > 0.0:
            returns_impl(&self.r_ray[cur, a], &self.r_org[cur, a, 0], &self.r_dir[cur, a, 0], &self.r_before[cur, a],
                         &self.r_atten[cur, a], &self.r_chain[cur, a], m, &self.dist[g, 0], self.origin,
                         self.glint_r2, self.reach, &self.back_length[g - 1, 0], &self.back_atten[g - 1, 0],
                         &self.back_dir[g - 1, 0, 0], &self.back_chain[g - 1, 0])
        self.blk_m[k] = r[0] if reflect else 0
        self.n_local[k] = r[1]
        self.blk_min[k] = r[2]
        if r[3]:
            self.overflow[k] = 1
        self.n_live[k, g] = weigh_impl(self.live[g, a:b], r[4], self.sid[g], self.cosine[g], self.dist[g],
                                       self.texel[g], laws.texel != NULL, <int>self.n_planes, self.albedo,
                                       self.weight, self.tvg, laws, self.intensity[g])
        self.blk_cur[k] = nxt
        self.blk_gen[k] = g + 1

    def trace(self, Py_ssize_t k, Py_ssize_t b0, Py_ssize_t b1, unsigned char[::1] signal=None):
        """Block ``k`` (beams ``b0:b1``) cast and traced through every generation, casting
        through the packet loop. Returns False where its chain table overflowed (grow it and
        run the block again). ``signal[0]`` is set to 1 once the GIL is let go (the frame's
        other thread waits for that to take it, ``compiled.on_both_cores``)."""
        if not self.fused:
            raise ValueError("no packet loop: cast in Python between begin() and step()")
        self.keep[0].address()  # raises once the caster released the Embree scene (no cast into freed memory)
        cdef Py_ssize_t a, b, g, m, cur
        self._check(k, b0, b1)
        a, b = b0 * self.rays_per_beam, b1 * self.rays_per_beam
        cdef float limit = <float>self.reach
        cdef unsigned char* go = &signal[0] if signal is not None and signal.shape[0] > 0 else NULL
        with nogil:
            if go != NULL:
                ss_flag_store(go, 1)
            self._begin(k, a, b, False)
            if b > a:
                self.cast(self.scene, &self.o32[a, 0] if self.multi else self.origin32, 3 if self.multi else 0,
                          &self.d32[a, 0], &limit, 0, &self.ids[0], &self.h_dist[a],
                          &self.h_mesh[a], &self.h_normal[a, 0], &self.h_prim[a] if self.primitives else NULL,
                          &self.h_uv[a, 0] if self.primitives else NULL, b - a, self.coherent)
                self._step(k, a, b, 0, self.laws)
                for g in range(1, self.n_gen):
                    m = self.blk_m[k]
                    if m == 0 or self.overflow[k]:
                        break
                    cur = self.blk_cur[k]
                    limit = <float>(self.reach - self.blk_min[k])
                    self.cast(self.scene, &self.r_org32[cur, a, 0], 3, &self.r_dir32[cur, a, 0], &limit, 0,
                              &self.ids[0], &self.h_dist[a], &self.h_mesh[a], &self.h_normal[a, 0],
                              &self.h_prim[a] if self.primitives else NULL,
                              &self.h_uv[a, 0] if self.primitives else NULL, m, self.coherent)
                    self._step(k, a, b, g, self.laws)
        return not self.overflow[k]

    def begin(self, Py_ssize_t k, Py_ssize_t b0, Py_ssize_t b1):
        """Start block ``k`` for casting in Python: returns ``(buffer, m, limit)`` of the first
        generation (see :meth:`pending`)."""
        cdef Py_ssize_t a, b
        self._check(k, b0, b1)
        a, b = b0 * self.rays_per_beam, b1 * self.rays_per_beam
        with nogil:
            self._begin(k, a, b, True)
        return self.pending(k)

    def pending(self, Py_ssize_t k):
        """``(buffer, m, limit)``: the block's next rays to cast are rows ``a:a + m`` of
        ``o32``/``d32`` (buffer -1, the first generation) or of ``r_org32[buffer]`` /
        ``r_dir32[buffer]``, up to ``limit`` metres; m 0: none left."""
        self._check(k, 0, 0)
        return self.blk_cur[k] if self.n_cast[k, 0] else -1, self.blk_m[k], self.reach - (self.blk_min[k] if self.n_cast[k, 0] else 0.0)

    def step(self, Py_ssize_t k, Py_ssize_t b0, Py_ssize_t b1, Py_ssize_t g, law_by_id=None, lobe_by_id=None,
             hit_texel=None):
        """Generation ``g`` of block ``k`` from the hits Python cast into ``h_*[a:a + m]``.
        Returns False where the chain table overflowed."""
        cdef Py_ssize_t a, b
        self._check(k, b0, b1)
        a, b = b0 * self.rays_per_beam, b1 * self.rays_per_beam
        if not 0 <= g < self.n_gen:
            raise ValueError(f"generation {g} of {self.n_gen}")
        if g != self.blk_gen[k] or (g > 0 and self.blk_m[k] == 0):
            raise ValueError(f"block {k}: generation {g} next, but {self.blk_gen[k]} is (begin() first, then "
                             "each generation once, while it has rays)")
        cdef _Laws laws = _Laws(law_by_id, lobe_by_id, hit_texel, self.albedo.shape[0], self.blk_m[k])
        if laws.texel != NULL and self.texel.shape[1] == 0:
            raise ValueError("textured hits, but the frame's legs have no texel array")
        with nogil:
            self._step(k, a, b, g, laws)
        return not self.overflow[k]

    def layout(self, const int[::1] gen, const int[::1] same, const int[::1] length, const int[:, ::1] planes,
               double[:, :, ::1] sources, Py_ssize_t[::1] offset):
        """The frame's pose-dependent option arrays, after its blocks traced: ``sources[o]``,
        the sonar's images along option o's chain (each the last reflected across the chain's
        next plane, ``x - 2 (n.x - offset) n``, as ``ChainTable.sources`` forms them: the same
        bits; zeros for an option whose transmit leg is the receive leg reversed), and
        ``offset[o * n_blocks + k]``, where option o of block k starts in the path buffer
        (option-major; its capacity is the block's live rays of the option's generation).
        Returns the buffer's size. One call for what NumPy did in a dozen between the phases."""
        cdef Py_ssize_t n_opt = gen.shape[0], o, k, q, p, size = 0
        cdef double x0, x1, x2, n0, n1, n2, twice
        if not self.ready:
            raise ValueError("call frame() first")
        if (same.shape[0] != n_opt or length.shape[0] != n_opt or planes.shape[0] != n_opt
                or sources.shape[0] != n_opt or sources.shape[2] != 3 or offset.shape[0] != n_opt * self.n_blocks):
            raise ValueError("option arrays of different lengths or shapes")
        for o in range(n_opt):
            if not 0 <= gen[o] < self.n_gen or not 0 <= length[o] <= planes.shape[1] or sources.shape[1] < length[o] + 1:
                raise ValueError(f"transmit option {o} out of range")
            for q in range(length[o]):
                if not 0 <= planes[o, q] < self.surf_normal.shape[0]:
                    raise ValueError(f"transmit option {o}: mirror {planes[o, q]} of {self.surf_normal.shape[0]}")
        with nogil:
            for o in range(n_opt):
                for q in range(sources.shape[1]):
                    sources[o, q, 0] = 0.0
                    sources[o, q, 1] = 0.0
                    sources[o, q, 2] = 0.0
                if not same[o]:
                    x0, x1, x2 = self.origin[0], self.origin[1], self.origin[2]
                    sources[o, 0, 0], sources[o, 0, 1], sources[o, 0, 2] = x0, x1, x2
                    for q in range(length[o]):
                        p = planes[o, q]
                        n0, n1, n2 = self.surf_normal[p, 0], self.surf_normal[p, 1], self.surf_normal[p, 2]
                        twice = 2.0 * (((x0 * n0 + x1 * n1) + x2 * n2) - self.surf_offset[p])
                        x0 = x0 - twice * n0
                        x1 = x1 - twice * n1
                        x2 = x2 - twice * n2
                        sources[o, q + 1, 0], sources[o, q + 1, 1], sources[o, q + 1, 2] = x0, x1, x2
                for k in range(self.n_blocks):
                    offset[o * self.n_blocks + k] = size
                    size += self.n_live[k, gen[o]]
        return size

    def options(self, const int[:, ::1] remap, const int[::1] rank, const int[::1] gen, const int[::1] tx,
                const int[::1] same, const int[::1] label, const int[::1] length, const double[:, :, ::1] unfold,
                const double[:, :, ::1] sources, const int[:, ::1] planes, const double[::1] specular,
                Py_ssize_t[::1] offset, Py_ssize_t[::1] count, Py_ssize_t[::1] p_ray, double[::1] p_dist,
                double[::1] p_energy, int[::1] p_beam, int[::1] p_beam_tx, signed char[::1] p_label,
                bint splat=True, float[::1] total=None, tuple rows=(), LabelMaps labels=None,
                const int[::1] order_map=None, const unsigned char[::1] moments=None,
                const Py_ssize_t[::1] capacity=None, bint counting=False, const int[::1] only=None):
        """Set what :meth:`paths` forms: each block's chain ids to the frame's (``remap``,
        (n_blocks, capacity)), the chains' ranks, the transmit options in order (generation,
        chain, same, image row, chain length, its unfolding map, the sonar's images, its
        planes, its specular product), the path buffer (``offset[o * n_blocks + k]``: where
        option o of block k starts; ``count``: receives how many it wrote; a block's
        capacity for an option is its generation's live rays), whether to splat into the
        frame's stack, and where to sum its ``rows`` (the frame's ``total``, flat
        ``(n_range_bins, n_beams)``: each block adds its own columns' rows right after splatting
        them, while they are in cache, in float32 and in the given order, as
        ``components._sum_rows`` does) and, with ``labels``, the ground truth deposited in the
        same pass: each block's paths, as it splats them, into ``labels`` (its blocks the
        engine's), option o's energy into map ``order_map[o]`` (-1: none) and, where
        ``moments[o]``, into the total's map and its elevation moments; the points of option o
        of block k from its path buffer offset on (``LabelMaps.compact`` gathers them).

        ``capacity`` (per ``offset`` entry; default: the generation's live rays) is each block's
        room for an option: the counts of a ``counting`` pass, which forms the paths into the
        engine's own scratch and only counts them (``count``: no splat, labels or total; the
        path buffer arrays may be empty), so that a frame of many transmit options (mesh
        mirrors) lays out a path buffer of its paths, not of its candidates. ``only`` (per option,
        -1: none): the option pairs its transmit chain with the rays of that receive chain alone,
        whatever the ranks (a smooth mirror's reciprocal partners)."""
        if counting and (splat or total is not None or labels is not None):
            raise ValueError("a counting pass forms no image, total or labels")
        if counting and self.scratch_ray.shape[0] < self.fan_dirs.shape[0]:
            n = self.fan_dirs.shape[0]
            self.scratch_ray, self.scratch_dist, self.scratch_energy = np.empty(n, np.intp), np.empty(n), np.empty(n)
            self.scratch_beam, self.scratch_beam_tx = np.empty(n, np.int32), np.empty(n, np.int32)
            self.scratch_label = np.empty(n, np.int8)
        cdef float[::1] out = self.out if splat else None
        cdef Py_ssize_t n_opt = gen.shape[0], o, k, m = p_ray.shape[0], n_rows = 0, q
        self.paths_ready = False  # everything is checked before anything is kept
        if not self.ready:
            raise ValueError("call frame() first")
        if out is not None:
            n_rows = out.shape[0] // (self.n_bins * self.n_beams)
        if (remap.shape[0] != self.n_blocks or remap.shape[1] < self.children.shape[1]
                or offset.shape[0] != n_opt * self.n_blocks or count.shape[0] != offset.shape[0]):
            raise ValueError("remap, offsets or counts of the wrong shape")
        if capacity is not None and capacity.shape[0] != offset.shape[0]:
            raise ValueError("a capacity per option and block, as the offsets")
        for k in range(self.n_blocks):
            if self.n_local[k] > remap.shape[1]:
                raise ValueError(f"block {k} holds {self.n_local[k]} chains, remap {remap.shape[1]}")
            for o in range(self.n_local[k]):
                if not 0 <= remap[k, o] < rank.shape[0]:
                    raise ValueError(f"block {k}'s chain {o} maps to {remap[k, o]}, not one of {rank.shape[0]}")
        if (tx.shape[0] != n_opt or same.shape[0] != n_opt or label.shape[0] != n_opt or length.shape[0] != n_opt
                or unfold.shape[0] != n_opt or unfold.shape[1] != 3 or unfold.shape[2] != 4
                or sources.shape[0] != n_opt or sources.shape[2] != 3 or planes.shape[0] != n_opt
                or specular.shape[0] != n_opt):
            raise ValueError("transmit option arrays of different lengths or shapes")
        if (p_dist.shape[0] != m or p_energy.shape[0] != m or p_beam.shape[0] != m or p_beam_tx.shape[0] != m
                or p_label.shape[0] != m):
            raise ValueError("path buffer arrays of different lengths")
        for o in range(n_opt):
            if (not 0 <= gen[o] < self.n_gen or not 0 <= label[o] < 127 or not 0 <= length[o] <= planes.shape[1]
                    or sources.shape[1] < length[o] + 1 or (out is not None and label[o] >= n_rows)):
                raise ValueError(f"transmit option {o} out of range")
            if not same[o] and not 0 <= tx[o] < rank.shape[0]:
                raise ValueError(f"transmit option {o}: chain {tx[o]} of {rank.shape[0]}")
            for q in range(length[o]):
                if not 0 <= planes[o, q] < self.surf_normal.shape[0]:
                    raise ValueError(f"transmit option {o}: mirror {planes[o, q]} of {self.surf_normal.shape[0]}")
            for k in range(self.n_blocks):
                room = self.n_live[k, gen[o]] if capacity is None else capacity[o * self.n_blocks + k]
                if capacity is not None and not 0 <= room <= self.n_live[k, gen[o]]:
                    raise ValueError(f"transmit option {o} of block {k}: room for {room} of {self.n_live[k, gen[o]]} rays")
                if not counting and (offset[o * self.n_blocks + k] < 0 or offset[o * self.n_blocks + k] + room > m):
                    raise ValueError(f"transmit option {o} of block {k} does not fit in the path buffer")
        n_total = len(rows) if total is not None and out is not None else 0
        if n_total > 16:
            raise ValueError("at most 16 rows in the total")
        for o in range(n_total):
            if not 0 <= rows[o] < n_rows:
                raise ValueError(f"total row {rows[o]} outside the stack")
        if n_total and total.shape[0] != self.n_bins * self.n_beams:
            raise ValueError("the total is not (n_range_bins, n_beams)")
        if labels is not None:
            if labels.n_rows != self.n_bins or labels.n_beams != self.n_beams or labels.n_blocks != self.n_blocks:
                raise ValueError("label maps of another image or another cut into blocks")
            # They splat the image too: the same range cells as the frame's.
            if (labels.range_min != self.range_min or labels.dr != self.dr or labels.spread != self.spread
                    or labels.n_elevation != self.n_el):
                raise ValueError("label maps of another range grid, range splat or fan")
            if not labels.unused():
                raise ValueError("label maps already deposited into (one LabelMaps per frame)")
            if order_map is None or moments is None or order_map.shape[0] != n_opt or moments.shape[0] != n_opt:
                raise ValueError("an order map and a moments flag per transmit option")
            for o in range(n_opt):
                if not -1 <= order_map[o] < labels.n_maps - 1:
                    raise ValueError(f"transmit option {o}: order map {order_map[o]} of {labels.n_maps - 1}")
            if labels.p_object.shape[0] < m:
                raise ValueError(f"point buffers of {labels.p_object.shape[0]} for a path buffer of {m}")
            labels.seg_count = np.zeros(offset.shape[0], np.intp)
        self.remap, self.rank = remap, rank
        self.opt_gen, self.opt_tx, self.opt_same, self.opt_label, self.opt_len = gen, tx, same, label, length
        self.opt_unfold, self.opt_sources, self.opt_planes, self.opt_specular = unfold, sources, planes, specular
        self.p_offset, self.p_count = offset, count
        self.p_ray, self.p_dist, self.p_energy, self.p_beam, self.p_beam_tx, self.p_label = (
            p_ray, p_dist, p_energy, p_beam, p_beam_tx, p_label)
        self.splat = out is not None
        self.labels, self.opt_map, self.opt_moments = labels, order_map, moments
        self.has_labels = labels is not None
        self.total = total
        self.n_total_rows = n_total
        for o in range(n_total):
            self.total_rows[o] = rows[o]
        if only is not None:
            if only.shape[0] != n_opt:
                raise ValueError("an 'only' chain per transmit option")
            for o in range(n_opt):
                if not -1 <= only[o] < rank.shape[0] or (only[o] >= 0 and same[o]):
                    raise ValueError(f"transmit option {o}: only chain {only[o]} of {rank.shape[0]}")
        self.opt_only = only if only is not None else np.full(n_opt, -1, np.int32)
        self.capacity, self.counting = capacity, counting
        self.paths_ready = True

    def paths(self, Py_ssize_t k, Py_ssize_t b0, Py_ssize_t b1, unsigned char[::1] signal=None):
        """Block ``k``'s paths: chain ids made the frame's, every transmit option's paths into
        the path buffer and, with an output stack, splatted into the block's own columns.
        ``signal``: as :meth:`trace`'s."""
        if not self.paths_ready:
            raise ValueError("call options() first")
        cdef Py_ssize_t a, b, g, i, o, off, n, cnt, K, j, q, row, n_kept = 0, kept_gen = -1
        cdef int r_tx, kept_rank = -1
        cdef const Py_ssize_t[::1] rays
        cdef Py_ssize_t n_opt = self.opt_gen.shape[0], plane = self.n_bins * self.n_beams
        cdef int c
        cdef bint splat = self.splat, has_labels = self.has_labels, counting = self.counting
        cdef LabelMaps labels = self.labels
        cdef float* tot
        cdef const float* src
        self._check(k, b0, b1)
        if has_labels and (labels.blocks[k] != b0 or labels.blocks[k + 1] != b1):
            raise ValueError(f"block {k}: beams {b0}:{b1} here, {labels.blocks[k]}:{labels.blocks[k + 1]} in the labels")
        if has_labels and labels.finished[k]:
            raise ValueError(f"block {k}'s labels are already resolved (each block's paths are formed once)")
        a, b = b0 * self.rays_per_beam, b1 * self.rays_per_beam
        cdef unsigned char* go = &signal[0] if signal is not None and signal.shape[0] > 0 else NULL
        self.miscounted[k] = 0
        with nogil:
            if go != NULL:
                ss_flag_store(go, 1)
            if not self.remapped[k]:  # once a frame (a counting pass came first, or not)
                self.remapped[k] = 1
                if self.glint_r2 > 0.0:  # the specular returns' chains
                    for g in range(self.n_gen):
                        for i in range(a, b):
                            if self.back_chain[g, i] >= 0:
                                self.back_chain[g, i] = self.remap[k, self.back_chain[g, i]]
                for g in range(1, self.n_gen):
                    for i in range(a, b):
                        if self.sid[g, i] >= 0:
                            c = self.remap[k, self.chain[g, i]]
                            self.chain[g, i] = c
                            self.key[g, i] = c * <int>self.n_surfaces + self.sid[g, i]
            for o in range(n_opt):
                g = self.opt_gen[o]
                n = self.n_live[k, g]
                off = self.p_offset[o * self.n_blocks + k]
                K = self.opt_len[o]
                rays = self.live[g, a:a + n]
                if not self.opt_same[o] and not self.separate and g > 0 and self.opt_only[o] < 0:
                    # Only the rays whose chain outranks the transmit chain make paths (each
                    # reciprocal pair once). A generation's options come by rising rank: the
                    # rays left for one are those left for the one before that outrank it, kept
                    # in ray order (a frame's many chains of mesh mirrors mostly outrank its rays').
                    r_tx = self.rank[self.opt_tx[o]]
                    if kept_gen != g or r_tx < kept_rank:
                        memmove(&self.subset[a], &self.live[g, a], n * sizeof(Py_ssize_t))
                        n_kept = n
                        kept_gen = g
                    kept_rank = r_tx
                    j = 0
                    for i in range(n_kept):
                        if self.rank[self.chain[g, self.subset[a + i]]] > r_tx:
                            self.subset[a + j] = self.subset[a + i]
                            j += 1
                    n_kept = j
                    if n_kept == 0:
                        self.p_count[o * self.n_blocks + k] = 0
                        continue
                    rays = self.subset[a:a + n_kept]
                if counting:  # formed into the block's own scratch rows, and counted
                    # (The call written out twice, for the scratch and for the buffer: output
                    # slices held in local memoryviews instead made this loop 15 % slower.)
                    cnt = path_events_impl(
                        rays, self.dist[g], self.sid[g], self.point[g], self.intensity[g],
                        self.ones if g == 0 else self.atten[g], self.zeros if g == 0 else self.chain[g],
                        self.opt_same[o], self.opt_tx[o], self.opt_unfold[o], self.opt_sources[o, :K + 1],
                        self.opt_planes[o, :K], self.opt_specular[o], self.rank, self.separate, self.opt_label[o],
                        <int>self.n_planes, self.rays_per_beam, self.origin[0], self.origin[1], self.origin[2],
                        self.rotation, self.edges, self.half_el, self.range_min, self.range_max, self.surf_normal,
                        self.surf_offset, self.active, self.scratch_ray[a:a + n], self.scratch_dist[a:a + n],
                        self.scratch_energy[a:a + n], self.scratch_beam[a:a + n], self.scratch_beam_tx[a:a + n],
                        self.scratch_label[a:a + n], self.mt, &self.prim[g, 0] if self.mt != NULL else NULL,
                        self.sin_half, &self.tan_edges[0] if self.tan_edges is not None else NULL,
                        self.opt_only[o], self.cone, self.rf)
                    self.p_count[o * self.n_blocks + k] = cnt
                    continue
                if self.capacity is not None:  # room for what the counting pass counted
                    n = self.capacity[o * self.n_blocks + k]
                cnt = path_events_impl(
                    rays, self.dist[g], self.sid[g], self.point[g], self.intensity[g],
                    self.ones if g == 0 else self.atten[g], self.zeros if g == 0 else self.chain[g],
                    self.opt_same[o], self.opt_tx[o], self.opt_unfold[o], self.opt_sources[o, :K + 1],
                    self.opt_planes[o, :K], self.opt_specular[o], self.rank, self.separate, self.opt_label[o],
                    <int>self.n_planes, self.rays_per_beam, self.origin[0], self.origin[1], self.origin[2],
                    self.rotation, self.edges, self.half_el, self.range_min, self.range_max, self.surf_normal,
                    self.surf_offset, self.active, self.p_ray[off:off + n], self.p_dist[off:off + n],
                    self.p_energy[off:off + n], self.p_beam[off:off + n], self.p_beam_tx[off:off + n],
                    self.p_label[off:off + n], self.mt, &self.prim[g, 0] if self.mt != NULL else NULL,
                    self.sin_half, &self.tan_edges[0] if self.tan_edges is not None else NULL, self.opt_only[o],
                    self.cone, self.rf)
                if cnt > n or (self.capacity is not None and cnt != n):
                    self.miscounted[k] = 1
                    cnt = cnt if cnt <= n else n
                self.p_count[o * self.n_blocks + k] = cnt
                if has_labels and cnt:
                    labels.seg_count[o * self.n_blocks + k] = labels.deposit(
                        k, &self.point[g, 0, 0], &self.normal[g, 0, 0], &self.sid[0, 0] if g == 0 else &self.key[g, 0],
                        &self.sid[g, 0], &self.p_ray[off], &self.p_dist[off], &self.p_energy[off], &self.p_beam[off],
                        &self.p_label[off], cnt, self.opt_map[o], self.opt_moments[o],
                        &self.out[0] if splat else NULL, off)
                elif splat and cnt:
                    splat_events_impl(self.point[g], self.normal[g], self.sid[0] if g == 0 else self.key[g],
                                      self.p_ray[off:off + cnt], self.p_dist[off:off + cnt],
                                      self.p_energy[off:off + cnt], self.p_beam[off:off + cnt],
                                      self.p_label[off:off + cnt], 1.0, self.spread, self.n_el, self.range_min,
                                      self.dr, self.n_bins, self.n_beams, self.out)
            if has_labels:
                labels.resolve(k)
            if self.n_total_rows:
                # The block's columns are complete and recently touched: their total now.
                tot = &self.total[0]
                for j in range(self.n_bins):
                    row = j * self.n_beams
                    src = &self.out[0] + self.total_rows[0] * plane + row
                    for i in range(b0, b1):
                        tot[row + i] = src[i]
                    for q in range(1, self.n_total_rows):
                        src = &self.out[0] + self.total_rows[q] * plane + row
                        for i in range(b0, b1):
                            tot[row + i] = tot[row + i] + src[i]
        if self.miscounted[k]:
            raise RuntimeError(f"block {k} formed other paths than its counting pass counted (the room given "
                               "for them in options(capacity=...))")


def id_extents(const int[::1] ids, const int[:, ::1] extents, int[:, ::1] out):
    """Per id, the union of the boxes ``extents[c]`` (``[row_min, col_min, row_max, col_max]``,
    inclusive; ``row_min < 0``: no box) of the cells ``c`` holding it (twin:
    ``dataset.coco.fan_boxes``' reduction). ``out`` (n_ids, 4) must hold -1; ids outside
    ``0 .. n_ids - 1`` are skipped."""
    cdef Py_ssize_t c, n = ids.shape[0], n_ids = out.shape[0]
    cdef int k
    with nogil:
        for c in range(n):
            k = ids[c]
            if k < 0 or k >= n_ids or extents[c, 0] < 0:
                continue
            if out[k, 0] < 0:
                out[k, 0] = extents[c, 0]
                out[k, 1] = extents[c, 1]
                out[k, 2] = extents[c, 2]
                out[k, 3] = extents[c, 3]
                continue
            if extents[c, 0] < out[k, 0]:
                out[k, 0] = extents[c, 0]
            if extents[c, 1] < out[k, 1]:
                out[k, 1] = extents[c, 1]
            if extents[c, 2] > out[k, 2]:
                out[k, 2] = extents[c, 2]
            if extents[c, 3] > out[k, 3]:
                out[k, 3] = extents[c, 3]
