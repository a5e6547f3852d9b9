# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""A small binding to the Embree 4 C API of the library bundled with ``embreex``.

Why a binding of our own: embreex casts one ray at a time (``rtcIntersect1``) and hands back
Embree's raw answer, which the renderer then converts (distance, mesh index, unit normal) in a
second pass over memory. Here rays go to Embree in packets of 8 (``rtcIntersect8``, flagged
coherent by default: neighbouring rays of a sonar fan share their BVH walk) over a scene built
with the high-quality BVH, and each packet's hits are converted into what
:class:`sonarsim.trace.base.Hits` needs right after Embree returns, while the packet is still in
L1 cache: the first step of fusing per-ray work with the cast (tracker issue 14, item 2).

Why dlopen: no Embree 4 headers are installed (Debian's are Embree 3, an incompatible ABI) and
the only Embree 4 is the one inside the embreex wheel, ``embreex.libs/libembree4-<hash>.so.4``,
whose file name carries a hash that changes with every wheel build. Linking against it at build
time would tie this extension to one wheel; instead :func:`load` opens it by path at run time
(it is the same file, hence the same already-loaded copy, that ``import embreex`` maps) and looks
every function up with ``dlsym`` into a typed pointer. The declarations below are written from
Embree 4's documented API (``include/embree4/rtcore_*.h``, 4.x) for the few calls we make.
"""

from libc.math cimport sqrtf, INFINITY
from libc.string cimport memset
from libc.stdint cimport uintptr_t

from sonarsim.trace.cast_abi cimport cast_rays_t

import numpy as np

from ..errors import SonarsimError

cdef extern from "<dlfcn.h>" nogil:
    void* dlopen(const char* filename, int flags)
    void* dlsym(void* handle, const char* symbol)
    char* dlerror()
    int RTLD_NOW
    int RTLD_LOCAL

# ---------------------------------------------------------------------------------------------
# The ray-hit structures, in C so that they carry Embree's alignment (32 bytes for packets of
# 8; 16 for one ray) and so that the compiler checks the offsets we rely on.
#
# Embree as bundled with embreex 4.4 is built with EMBREE_GEOMETRY_INSTANCE_ARRAY=ON (the
# default since 4.3) and EMBREE_MAX_INSTANCE_LEVEL_COUNT=1. That adds ``instPrimID[L]`` after
# ``instID[L]`` in every hit structure, and Embree writes it on every hit (it copies the
# instance stack of the query context, even when there are no instances). A hit declared
# without it (as some bindings do, 80 bytes for one ray) is overrun by 4 bytes per ray, and by
# 32 bytes per packet of 8. sonarsim.trace.embree4.verify_layout checks these offsets against
# the library itself each time the binding is loaded (and tests/trace/test_embree4.py, lane by
# lane): it fills the structure and 64 bytes after it with canary bytes, casts, and requires
# Embree to have written instID and instPrimID where declared and nothing after.
#
# Packet of 8 (structure of arrays, each field 8 x 4 bytes = 32 bytes):
#   ray: org_x org_y org_z tnear dir_x dir_y dir_z time tfar mask id flags   12 x 32 = 384
#   hit: Ng_x Ng_y Ng_z u v primID geomID instID[1] instPrimID[1]            9 x 32 = 288
#   total 672 bytes, a multiple of 32 (no tail padding).
# One ray: ray 48 bytes; hit 9 x 4 = 36 bytes padded to 48 (16-byte alignment); total 96.
# ---------------------------------------------------------------------------------------------
cdef extern from *:
    """
    #include <stddef.h>
    #define SS_MAX_INSTANCE_LEVEL_COUNT 1
    typedef struct __attribute__((aligned(16))) {
        float org_x, org_y, org_z, tnear, dir_x, dir_y, dir_z, time, tfar;
        unsigned int mask, id, flags;
    } ss_RTCRay;
    typedef struct __attribute__((aligned(16))) {
        float Ng_x, Ng_y, Ng_z, u, v;
        unsigned int primID, geomID;
        unsigned int instID[SS_MAX_INSTANCE_LEVEL_COUNT];
        unsigned int instPrimID[SS_MAX_INSTANCE_LEVEL_COUNT];
    } ss_RTCHit;
    typedef struct { ss_RTCRay ray; ss_RTCHit hit; } ss_RTCRayHit;
    typedef struct __attribute__((aligned(32))) {
        float org_x[8], org_y[8], org_z[8], tnear[8], dir_x[8], dir_y[8], dir_z[8], time[8], tfar[8];
        unsigned int mask[8], id[8], flags[8];
    } ss_RTCRay8;
    typedef struct __attribute__((aligned(32))) {
        float Ng_x[8], Ng_y[8], Ng_z[8], u[8], v[8];
        unsigned int primID[8], geomID[8];
        unsigned int instID[SS_MAX_INSTANCE_LEVEL_COUNT][8];
        unsigned int instPrimID[SS_MAX_INSTANCE_LEVEL_COUNT][8];
    } ss_RTCHit8;
    typedef struct { ss_RTCRay8 ray; ss_RTCHit8 hit; } ss_RTCRayHit8;
    /* Embree reads the valid mask with aligned 32-byte loads. */
    typedef struct __attribute__((aligned(32))) { int v[8]; } ss_Valid8;
    /* RTCIntersectArguments: flags, feature_mask (enums, 4 bytes each), then the context,
       filter and intersect pointers. The trailing float exists only in builds with
       EMBREE_MIN_WIDTH; declaring it (as 0) is harmless where it does not. */
    typedef struct {
        int flags;
        unsigned int feature_mask;
        void* context;
        void* filter;
        void* intersect;
        float minWidthDistanceFactor;
    } ss_RTCIntersectArguments;

    _Static_assert(sizeof(ss_RTCRayHit8) == 672, "RTCRayHit8 is 672 bytes");
    _Static_assert(offsetof(ss_RTCRayHit8, hit) == 384, "RTCHit8 after 12 ray fields");
    _Static_assert(offsetof(ss_RTCRayHit8, hit.geomID) == 384 + 6 * 32, "geomID");
    _Static_assert(offsetof(ss_RTCRayHit8, hit.instID) == 384 + 7 * 32, "instID");
    _Static_assert(offsetof(ss_RTCRayHit8, hit.instPrimID) == 384 + 8 * 32, "instPrimID");
    _Static_assert(sizeof(ss_RTCRayHit) == 96, "RTCRayHit is 96 bytes");
    _Static_assert(offsetof(ss_RTCRayHit, hit) == 48, "RTCHit after the ray");
    _Static_assert(offsetof(ss_RTCRayHit, hit.instPrimID) == 48 + 32, "instPrimID");
    _Static_assert(sizeof(ss_RTCIntersectArguments) == 40, "RTCIntersectArguments");
    """
    ctypedef struct ss_RTCRay:
        float org_x, org_y, org_z, tnear, dir_x, dir_y, dir_z, time, tfar
        unsigned int mask, id, flags
    ctypedef struct ss_RTCHit:
        float Ng_x, Ng_y, Ng_z, u, v
        unsigned int primID, geomID
        unsigned int instID[1]
        unsigned int instPrimID[1]
    ctypedef struct ss_RTCRayHit:
        ss_RTCRay ray
        ss_RTCHit hit
    ctypedef struct ss_RTCRay8:
        float org_x[8]
        float org_y[8]
        float org_z[8]
        float tnear[8]
        float dir_x[8]
        float dir_y[8]
        float dir_z[8]
        float time[8]
        float tfar[8]
        unsigned int mask[8]
        unsigned int id[8]
        unsigned int flags[8]
    ctypedef struct ss_RTCHit8:
        float Ng_x[8]
        float Ng_y[8]
        float Ng_z[8]
        float u[8]
        float v[8]
        unsigned int primID[8]
        unsigned int geomID[8]
        unsigned int instID[1][8]
        unsigned int instPrimID[1][8]
    ctypedef struct ss_RTCRayHit8:
        ss_RTCRay8 ray
        ss_RTCHit8 hit
    ctypedef struct ss_Valid8:
        int v[8]
    ctypedef struct ss_RTCIntersectArguments:
        int flags
        unsigned int feature_mask
        void* context
        void* filter
        void* intersect
        float minWidthDistanceFactor

# Sizes and offsets as declared, compared with what the library writes (embree4.verify_layout).
RAYHIT8_SIZE = sizeof(ss_RTCRayHit8)
RAYHIT1_SIZE = sizeof(ss_RTCRayHit)


def _offsets8() -> dict:
    cdef ss_RTCRayHit8 rh
    cdef char* base = <char*>&rh
    return {"tfar": <char*>&rh.ray.tfar[0] - base, "Ng_x": <char*>&rh.hit.Ng_x[0] - base,
            "u": <char*>&rh.hit.u[0] - base, "v": <char*>&rh.hit.v[0] - base,
            "primID": <char*>&rh.hit.primID[0] - base, "geomID": <char*>&rh.hit.geomID[0] - base,
            "instID": <char*>&rh.hit.instID[0][0] - base, "instPrimID": <char*>&rh.hit.instPrimID[0][0] - base}


def _offsets1() -> dict:
    cdef ss_RTCRayHit rh
    cdef char* base = <char*>&rh
    return {"tfar": <char*>&rh.ray.tfar - base, "Ng_x": <char*>&rh.hit.Ng_x - base,
            "u": <char*>&rh.hit.u - base, "v": <char*>&rh.hit.v - base,
            "primID": <char*>&rh.hit.primID - base, "geomID": <char*>&rh.hit.geomID - base,
            "instID": <char*>&rh.hit.instID[0] - base, "instPrimID": <char*>&rh.hit.instPrimID[0] - base}


RAYHIT8_OFFSETS = _offsets8()
RAYHIT1_OFFSETS = _offsets1()

# Enumerations and constants (rtcore_common.h, rtcore_device.h, rtcore_scene.h, rtcore_buffer.h).
cdef enum:
    RTC_GEOMETRY_TYPE_TRIANGLE = 0
    RTC_BUFFER_TYPE_INDEX = 0
    RTC_BUFFER_TYPE_VERTEX = 1
    RTC_FORMAT_UINT3 = 0x5003
    RTC_FORMAT_FLOAT3 = 0x9003
    RTC_BUILD_QUALITY_HIGH = 2
    RTC_BUILD_QUALITY_REFIT = 3
    RTC_SCENE_FLAG_NONE = 0
    RTC_SCENE_FLAG_DYNAMIC = 1
    RTC_RAY_QUERY_FLAG_INCOHERENT = 0
    RTC_RAY_QUERY_FLAG_COHERENT = 1 << 16
    RTC_DEVICE_PROPERTY_VERSION = 0
    RTC_DEVICE_PROPERTY_VERSION_MAJOR = 1
cdef unsigned int RTC_INVALID_GEOMETRY_ID = 0xFFFFFFFF
cdef unsigned int RTC_FEATURE_FLAG_ALL = 0xFFFFFFFF

_ERRORS = {0: "RTC_ERROR_NONE", 1: "RTC_ERROR_UNKNOWN", 2: "RTC_ERROR_INVALID_ARGUMENT",
           3: "RTC_ERROR_INVALID_OPERATION", 4: "RTC_ERROR_OUT_OF_MEMORY",
           5: "RTC_ERROR_UNSUPPORTED_CPU", 6: "RTC_ERROR_CANCELLED"}

# Handles are opaque pointers (RTCDevice, RTCScene, RTCGeometry).
ctypedef void* (*f_rtcNewDevice)(const char* config) noexcept nogil
ctypedef void (*f_rtcReleaseDevice)(void* device) noexcept nogil
ctypedef int (*f_rtcGetDeviceError)(void* device) noexcept nogil
ctypedef void (*f_rtcErrorFunction)(void* user, int code, const char* msg) noexcept nogil
ctypedef void (*f_rtcSetDeviceErrorFunction)(void* device, f_rtcErrorFunction fn, void* user) noexcept nogil
ctypedef Py_ssize_t (*f_rtcGetDeviceProperty)(void* device, int prop) noexcept nogil
ctypedef void* (*f_rtcNewScene)(void* device) noexcept nogil
ctypedef void (*f_rtcReleaseScene)(void* scene) noexcept nogil
ctypedef void (*f_rtcSetSceneBuildQuality)(void* scene, int quality) noexcept nogil
ctypedef void (*f_rtcSetSceneFlags)(void* scene, int flags) noexcept nogil
ctypedef void (*f_rtcCommitScene)(void* scene) noexcept nogil
ctypedef void* (*f_rtcNewGeometry)(void* device, int type) noexcept nogil
ctypedef void (*f_rtcSetSharedGeometryBuffer)(void* geometry, int type, unsigned int slot, int format,
                                               const void* ptr, size_t byte_offset, size_t byte_stride,
                                               size_t item_count) noexcept nogil
ctypedef void (*f_rtcCommitGeometry)(void* geometry) noexcept nogil
ctypedef unsigned int (*f_rtcAttachGeometry)(void* scene, void* geometry) noexcept nogil
ctypedef void (*f_rtcReleaseGeometry)(void* geometry) noexcept nogil
ctypedef void* (*f_rtcGetGeometry)(void* scene, unsigned int geomID) noexcept nogil
ctypedef void (*f_rtcUpdateGeometryBuffer)(void* geometry, int type, unsigned int slot) noexcept nogil
ctypedef void (*f_rtcSetGeometryBuildQuality)(void* geometry, int quality) noexcept nogil
ctypedef void (*f_rtcDetachGeometry)(void* scene, unsigned int geomID) noexcept nogil
ctypedef void (*f_rtcAttachGeometryByID)(void* scene, void* geometry, unsigned int geomID) noexcept nogil
ctypedef void (*f_rtcEnableGeometry)(void* geometry) noexcept nogil
ctypedef void (*f_rtcDisableGeometry)(void* geometry) noexcept nogil
ctypedef void (*f_rtcIntersect1)(void* scene, ss_RTCRayHit* rayhit, ss_RTCIntersectArguments* args) noexcept nogil
ctypedef void (*f_rtcIntersect8)(const int* valid, void* scene, ss_RTCRayHit8* rayhit,
                                 ss_RTCIntersectArguments* args) noexcept nogil

cdef struct Api:
    f_rtcNewDevice rtcNewDevice
    f_rtcReleaseDevice rtcReleaseDevice
    f_rtcGetDeviceError rtcGetDeviceError
    f_rtcSetDeviceErrorFunction rtcSetDeviceErrorFunction
    f_rtcGetDeviceProperty rtcGetDeviceProperty
    f_rtcNewScene rtcNewScene
    f_rtcReleaseScene rtcReleaseScene
    f_rtcSetSceneBuildQuality rtcSetSceneBuildQuality
    f_rtcSetSceneFlags rtcSetSceneFlags
    f_rtcCommitScene rtcCommitScene
    f_rtcNewGeometry rtcNewGeometry
    f_rtcSetSharedGeometryBuffer rtcSetSharedGeometryBuffer
    f_rtcCommitGeometry rtcCommitGeometry
    f_rtcAttachGeometry rtcAttachGeometry
    f_rtcReleaseGeometry rtcReleaseGeometry
    f_rtcIntersect1 rtcIntersect1
    f_rtcIntersect8 rtcIntersect8
    f_rtcGetGeometry rtcGetGeometry
    f_rtcUpdateGeometryBuffer rtcUpdateGeometryBuffer
    f_rtcSetGeometryBuildQuality rtcSetGeometryBuildQuality
    f_rtcDetachGeometry rtcDetachGeometry
    f_rtcAttachGeometryByID rtcAttachGeometryByID
    f_rtcEnableGeometry rtcEnableGeometry
    f_rtcDisableGeometry rtcDisableGeometry

cdef Api api
cdef void* _handle = NULL
_loaded_path = None

_SYMBOLS = ("rtcNewDevice", "rtcReleaseDevice", "rtcGetDeviceError", "rtcSetDeviceErrorFunction",
            "rtcGetDeviceProperty", "rtcNewScene", "rtcReleaseScene", "rtcSetSceneBuildQuality",
            "rtcSetSceneFlags", "rtcCommitScene", "rtcNewGeometry", "rtcSetSharedGeometryBuffer",
            "rtcCommitGeometry", "rtcAttachGeometry", "rtcReleaseGeometry", "rtcIntersect1",
            "rtcIntersect8", "rtcGetGeometry", "rtcUpdateGeometryBuffer", "rtcSetGeometryBuildQuality",
            "rtcDetachGeometry", "rtcAttachGeometryByID", "rtcEnableGeometry", "rtcDisableGeometry")


def load(path: str) -> None:
    """Open the Embree 4 library at ``path`` and bind the functions this module calls.

    Once bound, the library stays loaded for the life of the process (it is never closed:
    scenes built from it may outlive any one caster, and embreex maps the same file anyway).

    Parameters
    ----------
    path : str
        Path of ``libembree4*.so*``.

    Raises
    ------
    SonarsimError
        The file cannot be opened or lacks one of the functions.
    """
    global _handle, _loaded_path
    if _handle != NULL:
        if path != _loaded_path:
            raise SonarsimError(f"Embree 4 is already bound from {_loaded_path}; cannot switch to {path}")
        return
    cdef bytes bpath = str(path).encode()
    cdef void* h = dlopen(bpath, RTLD_NOW | RTLD_LOCAL)
    if h == NULL:
        err = dlerror()
        raise SonarsimError(f"cannot open the Embree 4 library {path}: "
                            f"{(<bytes>err).decode(errors='replace') if err != NULL else 'unknown error'}")
    cdef void* found[24]
    missing = []
    cdef bytes bname
    for k, name in enumerate(_SYMBOLS):
        bname = name.encode()
        found[k] = dlsym(h, bname)
        if found[k] == NULL:
            missing.append(name)
    if missing:
        raise SonarsimError(f"the Embree library {path} lacks {', '.join(missing)}: not an Embree 4 C API")
    api.rtcNewDevice = <f_rtcNewDevice>found[0]
    api.rtcReleaseDevice = <f_rtcReleaseDevice>found[1]
    api.rtcGetDeviceError = <f_rtcGetDeviceError>found[2]
    api.rtcSetDeviceErrorFunction = <f_rtcSetDeviceErrorFunction>found[3]
    api.rtcGetDeviceProperty = <f_rtcGetDeviceProperty>found[4]
    api.rtcNewScene = <f_rtcNewScene>found[5]
    api.rtcReleaseScene = <f_rtcReleaseScene>found[6]
    api.rtcSetSceneBuildQuality = <f_rtcSetSceneBuildQuality>found[7]
    api.rtcSetSceneFlags = <f_rtcSetSceneFlags>found[8]
    api.rtcCommitScene = <f_rtcCommitScene>found[9]
    api.rtcNewGeometry = <f_rtcNewGeometry>found[10]
    api.rtcSetSharedGeometryBuffer = <f_rtcSetSharedGeometryBuffer>found[11]
    api.rtcCommitGeometry = <f_rtcCommitGeometry>found[12]
    api.rtcAttachGeometry = <f_rtcAttachGeometry>found[13]
    api.rtcReleaseGeometry = <f_rtcReleaseGeometry>found[14]
    api.rtcIntersect1 = <f_rtcIntersect1>found[15]
    api.rtcIntersect8 = <f_rtcIntersect8>found[16]
    api.rtcGetGeometry = <f_rtcGetGeometry>found[17]
    api.rtcUpdateGeometryBuffer = <f_rtcUpdateGeometryBuffer>found[18]
    api.rtcSetGeometryBuildQuality = <f_rtcSetGeometryBuildQuality>found[19]
    api.rtcDetachGeometry = <f_rtcDetachGeometry>found[20]
    api.rtcAttachGeometryByID = <f_rtcAttachGeometryByID>found[21]
    api.rtcEnableGeometry = <f_rtcEnableGeometry>found[22]
    api.rtcDisableGeometry = <f_rtcDisableGeometry>found[23]
    _handle = h
    _loaded_path = path


def loaded_path():
    """Path of the bound library, or None."""
    return _loaded_path


# The last error Embree reported through the callback, per device (Embree calls it on the thread
# that made the failing call; a caster checks it after each build and each cast).
cdef struct ErrorSlot:
    int code
    char message[256]


cdef void _on_error(void* user, int code, const char* msg) noexcept nogil:
    cdef ErrorSlot* slot = <ErrorSlot*>user
    cdef size_t k = 0
    if slot.code != 0:
        return  # keep the first error
    slot.code = code
    if msg != NULL:
        while k < 255 and msg[k] != 0:
            slot.message[k] = msg[k]
            k += 1
    slot.message[k] = 0


# ----- the packet loop ------------------------------------------------------------------------

cdef inline void shared_fields(ss_RTCRayHit8* rh, const float* o, Py_ssize_t o_step) noexcept nogil:
    """What every lane of every packet shares, set once: tnear, time, id, flags (0), the mask,
    and the origin where all rays share one (``o_step`` 0). Embree writes only tfar and the hit
    fields, and only on a hit (rtcIntersect1(3)), so these stay set from packet to packet."""
    cdef int k
    for k in range(8):
        rh.ray.tnear[k] = 0.0
        rh.ray.time[k] = 0.0
        rh.ray.mask[k] = 0xFFFFFFFF
        rh.ray.id[k] = 0
        rh.ray.flags[k] = 0
        if o_step == 0:
            rh.ray.org_x[k] = o[0]
            rh.ray.org_y[k] = o[1]
            rh.ray.org_z[k] = o[2]


cdef inline void load_rays(ss_RTCRayHit8* rh, const float* o, Py_ssize_t o_step, const float* d,
                           const float* tfar, Py_ssize_t tfar_step, Py_ssize_t start, int m) noexcept nogil:
    """Rays ``start .. start + m`` into lanes ``0 .. m`` (after :func:`shared_fields`); the
    other lanes keep what they held.

    Ray ``i`` starts at ``o + i * o_step`` (``o_step`` 3, or 0: one origin for all, set by
    :func:`shared_fields`) along ``d + 3 i``, up to ``tfar[i * tfar_step]`` (``tfar_step`` 1,
    or 0: one limit for all). geomID is reset: a lane's hit fields keep its last hit, and
    geomID left invalid tells a miss.
    """
    cdef int k
    cdef Py_ssize_t i
    for k in range(m):
        i = start + k
        if o_step != 0:
            rh.ray.org_x[k] = o[i * o_step]
            rh.ray.org_y[k] = o[i * o_step + 1]
            rh.ray.org_z[k] = o[i * o_step + 2]
        rh.ray.dir_x[k] = d[3 * i]
        rh.ray.dir_y[k] = d[3 * i + 1]
        rh.ray.dir_z[k] = d[3 * i + 2]
        rh.ray.tfar[k] = tfar[i * tfar_step]
        rh.hit.geomID[k] = RTC_INVALID_GEOMETRY_ID


cdef inline void load_packet(ss_RTCRayHit8* rh, const float[:, ::1] o, const float[:, ::1] d,
                             const float[::1] tfar, Py_ssize_t start, int m) noexcept nogil:
    """:func:`shared_fields` and :func:`load_rays` from (n, 3) origins and directions and (n,)
    limits (the canary probe: one packet)."""
    shared_fields(rh, &o[0, 0], 3)
    load_rays(rh, &o[0, 0], 3, &d[0, 0], &tfar[0], 1, start, m)


cdef inline void packet_mask(ss_Valid8* valid, int m) noexcept nogil:
    """Lanes ``0 .. m`` active (-1), the rest inactive (0): a partial tail packet casts only its rays."""
    cdef int k
    for k in range(8):
        valid.v[k] = -1 if k < m else 0


cdef void cast_rays(void* scene, const float* o, Py_ssize_t o_step, const float* d, const float* tfar,
                    Py_ssize_t tfar_step, const int* ids, float* distance, int* mesh_id, float* normal,
                    int* prim, float* uv, Py_ssize_t n, bint coherent) noexcept nogil:
    """Cast ``n`` rays in packets of 8 and write each packet's hits at once.

    The rays are as for :func:`load_rays`; ``distance`` (n), ``mesh_id`` (n) and ``normal``
    (n x 3) receive the hits, ``prim`` (n) and ``uv`` (n x 2) too where not NULL. This is the
    one packet loop: :meth:`Scene.cast` runs it, and the compiled kernels call it by address
    (:func:`cast_rays_address`) to cast in the middle of their own loops.
    """
    cdef ss_RTCRayHit8 rh
    cdef ss_Valid8 valid
    cdef ss_RTCIntersectArguments args
    cdef Py_ssize_t start, i
    cdef int m, k
    cdef unsigned int g
    cdef float nx, ny, nz, inv
    memset(&rh, 0, sizeof(rh))  # lanes a tail packet leaves inactive hold zeros, never garbage
    memset(&args, 0, sizeof(args))
    args.flags = RTC_RAY_QUERY_FLAG_COHERENT if coherent else RTC_RAY_QUERY_FLAG_INCOHERENT
    args.feature_mask = RTC_FEATURE_FLAG_ALL
    shared_fields(&rh, o, o_step)
    start = 0
    while start < n:
        m = <int>(n - start) if n - start < 8 else 8
        load_rays(&rh, o, o_step, d, tfar, tfar_step, start, m)
        packet_mask(&valid, m)
        api.rtcIntersect8(valid.v, scene, &rh, &args)
        # Fused: the packet is still in L1; write what Hits needs (as trace._hits.embree_hits does).
        for k in range(m):
            i = start + k
            g = rh.hit.geomID[k]
            if g != RTC_INVALID_GEOMETRY_ID:
                distance[i] = rh.ray.tfar[k]
                mesh_id[i] = ids[g]
                nx = rh.hit.Ng_x[k]
                ny = rh.hit.Ng_y[k]
                nz = rh.hit.Ng_z[k]
                # float32 sum and root, the reciprocal correctly rounded: as the kernel twin.
                inv = <float>(1.0 / <double>sqrtf(nx * nx + ny * ny + nz * nz))
                normal[3 * i] = nx * inv
                normal[3 * i + 1] = ny * inv
                normal[3 * i + 2] = nz * inv
                if prim != NULL:
                    prim[i] = <int>rh.hit.primID[k]
                    uv[2 * i] = rh.hit.u[k]
                    uv[2 * i + 1] = rh.hit.v[k]
            else:
                distance[i] = INFINITY
                mesh_id[i] = -1
                normal[3 * i] = 0.0
                normal[3 * i + 1] = 0.0
                normal[3 * i + 2] = 0.0
                if prim != NULL:
                    prim[i] = -1
                    uv[2 * i] = 0.0
                    uv[2 * i + 1] = 0.0
        start += 8


# The compiler checks that the loop has the signature the kernels call it by.
cdef cast_rays_t _cast_rays_checked = cast_rays


def cast_rays_address() -> int:
    """Address of the packet loop :func:`cast_rays` (a ``cast_abi.cast_rays_t``), for the kernels."""
    return <size_t>_cast_rays_checked


cdef void cast_chunk_raw(void* scene, const float[:, ::1] o, const float[:, ::1] d, float[::1] tfar,
                         int[::1] geom_id, float[:, ::1] ng, bint coherent) noexcept nogil:
    """Embree's raw answer only (tfar written back, geomID -1 for a miss, Ng): no fused work."""
    cdef ss_RTCRayHit8 rh
    cdef ss_Valid8 valid
    cdef ss_RTCIntersectArguments args
    cdef Py_ssize_t n = d.shape[0], start, i
    cdef int m, k
    memset(&rh, 0, sizeof(rh))
    memset(&args, 0, sizeof(args))
    args.flags = RTC_RAY_QUERY_FLAG_COHERENT if coherent else RTC_RAY_QUERY_FLAG_INCOHERENT
    args.feature_mask = RTC_FEATURE_FLAG_ALL
    shared_fields(&rh, &o[0, 0], 3)
    start = 0
    while start < n:
        m = <int>(n - start) if n - start < 8 else 8
        load_rays(&rh, &o[0, 0], 3, &d[0, 0], &tfar[0], 1, start, m)
        packet_mask(&valid, m)
        api.rtcIntersect8(valid.v, scene, &rh, &args)
        for k in range(m):
            i = start + k
            tfar[i] = rh.ray.tfar[k]
            geom_id[i] = <int>rh.hit.geomID[k]
            ng[i, 0] = rh.hit.Ng_x[k]
            ng[i, 1] = rh.hit.Ng_y[k]
            ng[i, 2] = rh.hit.Ng_z[k]
        start += 8


cdef class Scene:
    """An Embree 4 device and a committed scene of triangle meshes (high-quality BVH).

    Parameters
    ----------
    vertices : list of (n_v, 3) float32 C-contiguous ndarrays, metres
        Copied once (with the padding row Embree needs).
    faces : list of (n_f, 3) int32 C-contiguous ndarrays
        One entry per non-empty mesh; Embree's geometry ``k`` is entry ``k``. Shared with
        Embree (not copied) and kept alive by this object.
    config : str
        Embree device configuration, e.g. ``"threads=2"`` (it only affects the build; see
        :func:`sonarsim.trace.embree4.device_config`).
    quality : {"high", "medium", "low"}
        BVH build quality (high: spatial splits, slower to build, faster to cast).
    dynamic : bool
        A scene whose geometries move (:meth:`replace`, then :meth:`commit`): Embree's
        two-level BVH, each geometry refitted; empty meshes are then allowed (disabled).
    """

    cdef void* device
    cdef void* scene
    cdef ErrorSlot error
    cdef list _keep
    cdef list _enabled
    cdef readonly int n_geometries
    cdef readonly bint dynamic

    def __cinit__(self):
        self.device = NULL
        self.scene = NULL
        self.error.code = 0
        self.error.message[0] = 0

    def __init__(self, list vertices, list faces, str config="", str quality="high", bint dynamic=False):
        if _handle == NULL:
            raise SonarsimError("the Embree 4 library is not loaded (call sonarsim.trace._embree4.load first)")
        self._keep = []
        self._enabled = []
        self.n_geometries = 0
        self.dynamic = dynamic
        cdef bytes bconf = config.encode()
        self.device = api.rtcNewDevice(bconf)
        if self.device == NULL:
            code = api.rtcGetDeviceError(NULL)
            raise SonarsimError(f"Embree could not create a device ({_ERRORS.get(code, code)})")
        api.rtcSetDeviceErrorFunction(self.device, _on_error, &self.error)
        if api.rtcGetDeviceProperty(self.device, RTC_DEVICE_PROPERTY_VERSION_MAJOR) != 4:
            raise SonarsimError("the bound Embree library is not Embree 4")
        self.scene = api.rtcNewScene(self.device)
        self.check("rtcNewScene")
        # Static scene: the high-quality (spatial-split) BVH costs more to build, less to cast.
        qualities = {"low": 0, "medium": 1, "high": RTC_BUILD_QUALITY_HIGH}
        if quality not in qualities:
            raise ValueError(f"quality must be one of {', '.join(qualities)}")
        api.rtcSetSceneBuildQuality(self.scene, qualities[quality])
        # Not ROBUST, as the embreex caster: closed meshes lose no hits at this precision.
        # DYNAMIC: Embree's two-level BVH, a tree per geometry under one over them, so that a
        # geometry moved (replace) is refitted or rebuilt alone and the rest stays as built.
        api.rtcSetSceneFlags(self.scene, RTC_SCENE_FLAG_DYNAMIC if dynamic else RTC_SCENE_FLAG_NONE)
        cdef void* geom
        for vv, ff in zip(vertices, faces):
            if len(ff) == 0 and not dynamic:
                raise SonarsimError("empty meshes are not given to Embree")
            geom = self._geometry(vv, ff)
            api.rtcAttachGeometry(self.scene, geom)
            api.rtcReleaseGeometry(geom)  # the scene holds its own reference
            self.check("building a triangle geometry")
            self._enabled.append(True)
            if len(ff) == 0:
                self._disable(self.n_geometries)
            self.n_geometries += 1
        with nogil:
            api.rtcCommitScene(self.scene)
        self.check("rtcCommitScene")

    cdef void* _geometry(self, vv, ff) except NULL:
        """A committed triangle geometry sharing copies of ``vv`` (n, 3) and ``ff`` (m, 3); an
        empty ``ff`` gets one degenerate triangle (the geometry is then disabled)."""
        cdef const float[:, ::1] v
        cdef const int[:, ::1] f
        if len(ff) == 0:
            vv = np.zeros((3, 3), np.float32)
            ff = np.array([[0, 1, 2]], np.int32)
        f = ff
        # Embree reads the last vertex with a 16-byte load: a shared float3 buffer needs 4
        # bytes of padding after it (rtcSetSharedGeometryBuffer), hence one spare row.
        arr = np.zeros((len(vv) + 1, 3), np.float32)
        arr[:-1] = vv
        v = arr
        cdef void* geom = api.rtcNewGeometry(self.device, RTC_GEOMETRY_TYPE_TRIANGLE)
        self.check("rtcNewGeometry")
        api.rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3,
                                       &v[0, 0], 0, 12, v.shape[0] - 1)
        api.rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                       &f[0, 0], 0, 12, f.shape[0])
        if self.dynamic:
            # A move that keeps the triangles refits this geometry's tree instead of rebuilding it.
            api.rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_REFIT)
        api.rtcCommitGeometry(geom)
        self._keep.append((arr, ff))
        return geom

    cdef _disable(self, unsigned int k):
        if self._enabled[k]:
            api.rtcDisableGeometry(api.rtcGetGeometry(self.scene, k))
            self._enabled[k] = False

    def replace(self, int k, vertices, faces) -> str:
        """Give geometry ``k`` new vertices (and faces) for the next commit (dynamic scenes only).

        The same faces as before: the vertices are written into the shared buffer and the
        geometry's tree is refitted at :meth:`commit`. Other faces: a new geometry takes
        ``k``'s id (its tree alone is built). No faces: the geometry is disabled (no hits).

        Parameters
        ----------
        k : int
            Geometry id, ``0 <= k < n_geometries``.
        vertices : (n, 3) float array, metres
        faces : (m, 3) int32 C-contiguous array

        Returns
        -------
        str
            What was done: ``'refit'``, ``'rebuilt'`` or ``'disabled'``.
        """
        if not self.dynamic:
            raise SonarsimError("this Embree scene is static (built without dynamic=True): its geometries cannot move")
        if not 0 <= k < self.n_geometries:
            raise ValueError(f"geometry id {k} out of range 0..{self.n_geometries - 1}")
        if self.scene == NULL:
            raise SonarsimError("the Embree scene is closed")
        cdef void* geom = api.rtcGetGeometry(self.scene, k)
        if len(faces) == 0:
            self._disable(k)
            self.check("rtcDisableGeometry")
            return "disabled"
        arr, ff = self._keep[k]
        if self._enabled[k] and ff.shape == faces.shape and np.array_equal(ff, faces):
            arr[:-1] = vertices
            api.rtcUpdateGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0)
            api.rtcCommitGeometry(geom)
            self.check("refitting a geometry")
            return "refit"
        geom = self._geometry(vertices, np.ascontiguousarray(faces, dtype=np.int32))
        self._keep[k] = self._keep.pop()
        api.rtcDetachGeometry(self.scene, k)
        api.rtcAttachGeometryByID(self.scene, geom, k)
        api.rtcReleaseGeometry(geom)
        self._enabled[k] = True
        self.check("replacing a geometry")
        return "rebuilt"

    def commit(self) -> None:
        """Commit the scene after :meth:`replace` (its BVH updated; GIL released)."""
        if self.scene == NULL:
            raise SonarsimError("the Embree scene is closed")
        with nogil:
            api.rtcCommitScene(self.scene)
        self.check("rtcCommitScene")

    cdef check(self, what):
        """Raise the first error Embree reported since the last check."""
        cdef int code = self.error.code
        if code == 0 and self.device != NULL:
            code = api.rtcGetDeviceError(self.device)
        if code != 0:
            msg = (<bytes>self.error.message).decode(errors="replace")
            self.error.code = 0
            self.error.message[0] = 0
            raise SonarsimError(f"Embree failed in {what}: {_ERRORS.get(code, code)} {msg}".rstrip())

    def cast(self, const float[:, ::1] origins, const float[:, ::1] directions, const float[::1] tfar,
             const int[::1] ids, float[::1] distance, int[::1] mesh_id, float[:, ::1] normal,
             int[::1] primitive_id=None, float[:, ::1] barycentric=None, bint coherent=False):
        """Closest hits of ``n`` rays, written into the output arrays (GIL released).

        Parameters
        ----------
        origins, directions : (n, 3) float32 C-contiguous, metres and unit vectors
        tfar : (n,) float32, metres
            Per-ray limit (not modified).
        ids : (n_geometries,) int32
            Mesh index of each Embree geometry.
        distance : (n,) float32, out; metres, ``inf`` for a miss
        mesh_id : (n,) int32, out; -1 for a miss
        normal : (n, 3) float32, out; unit geometric normal, 0 for a miss
        primitive_id : (n,) int32, out, optional; -1 for a miss
        barycentric : (n, 2) float32, out, optional; Embree's (u, v), 0 for a miss
        coherent : bool
            Tell Embree the rays of a packet are coherent.
        """
        cdef Py_ssize_t n = directions.shape[0]
        if (origins.shape[0] != n or tfar.shape[0] != n or distance.shape[0] != n or mesh_id.shape[0] != n
                or normal.shape[0] != n or origins.shape[1] != 3 or directions.shape[1] != 3 or normal.shape[1] != 3):
            raise ValueError("ray and output arrays must agree: (n, 3), (n,)")
        if ids.shape[0] != self.n_geometries:
            raise ValueError("one mesh index per Embree geometry")
        cdef int* prim = NULL
        cdef float* uv = NULL
        if (primitive_id is None) != (barycentric is None):
            raise ValueError("primitive_id and barycentric go together")
        if primitive_id is not None:
            if primitive_id.shape[0] != n or barycentric.shape[0] != n or barycentric.shape[1] != 2:
                raise ValueError("primitive_id (n,), barycentric (n, 2)")
            if n:
                prim = &primitive_id[0]
                uv = &barycentric[0, 0]
        if n == 0:
            return
        if self.scene == NULL:
            raise SonarsimError("the Embree scene is closed")
        with nogil:
            cast_rays(self.scene, &origins[0, 0], 3, &directions[0, 0], &tfar[0], 1, &ids[0] if ids.shape[0] else NULL,
                      &distance[0], &mesh_id[0], &normal[0, 0], prim, uv, n, coherent)
        self.check("rtcIntersect8")

    def address(self) -> int:
        """Address of the committed Embree scene, for :func:`cast_rays` called from the kernels
        (valid while this object lives and is not closed)."""
        if self.scene == NULL:
            raise SonarsimError("the Embree scene is closed")
        return <size_t>self.scene

    def cast_raw(self, const float[:, ::1] origins, const float[:, ::1] directions, float[::1] tfar,
                 int[::1] geom_id, float[:, ::1] ng, bint coherent=False):
        """Embree's raw answer, as embreex gives it: ``tfar`` cut to the hits (in place), ``geom_id``
        (-1 for a miss) and the unnormalised normal ``ng`` (n, 3). For benchmarks."""
        cdef Py_ssize_t n = directions.shape[0]
        if origins.shape[0] != n or tfar.shape[0] != n or geom_id.shape[0] != n or ng.shape[0] != n:
            raise ValueError("ray and output arrays must agree")
        if n == 0:
            return
        if self.scene == NULL:
            raise SonarsimError("the Embree scene is closed")
        with nogil:
            cast_chunk_raw(self.scene, origins, directions, tfar, geom_id, ng, coherent)
        self.check("rtcIntersect8")

    def probe_packet(self, const float[:, ::1] origins, const float[:, ::1] directions, const float[::1] tfar,
                     int m, unsigned char canary=0xA5):
        """One packet of 8 cast into a canary-filled buffer; the raw bytes come back (tests).

        All 8 lanes are loaded with the given rays (so inactive lanes hold real rays too), then
        the hit fields, including ``instID`` and ``instPrimID``, and 64 bytes after the structure
        are filled with ``canary``; only lanes ``0 .. m`` are made active, as the casting loop
        does for a tail packet. What Embree wrote shows where it thinks the fields are.

        Returns
        -------
        bytes, ``RAYHIT8_SIZE + 64`` long.
        """
        if origins.shape[0] != 8 or directions.shape[0] != 8 or tfar.shape[0] != 8:
            raise ValueError("a packet is 8 rays")
        cdef unsigned char raw[672 + 64 + 32]
        # The structure must start 32-byte aligned: place it in the buffer by hand.
        cdef ss_RTCRayHit8* rh = <ss_RTCRayHit8*>((<uintptr_t>raw + 31) & ~(<uintptr_t>31))
        cdef ss_Valid8 valid
        cdef ss_RTCIntersectArguments args
        memset(&args, 0, sizeof(args))
        args.feature_mask = RTC_FEATURE_FLAG_ALL
        memset(rh, canary, sizeof(ss_RTCRayHit8) + 64)
        load_packet(rh, origins, directions, tfar, 0, 8)
        memset(&rh.hit, canary, sizeof(ss_RTCHit8))
        packet_mask(&valid, m)
        api.rtcIntersect8(valid.v, self.scene, rh, &args)
        self.check("rtcIntersect8")
        return (<unsigned char*>rh)[:sizeof(ss_RTCRayHit8) + 64]

    def probe_single(self, float ox, float oy, float oz, float dx, float dy, float dz, float tfar,
                     unsigned char canary=0xA5):
        """One ray through ``rtcIntersect1`` into a canary-filled buffer; raw bytes back (tests).

        Returns
        -------
        bytes, ``RAYHIT1_SIZE + 64`` long.
        """
        cdef unsigned char raw[96 + 64 + 16]
        cdef ss_RTCRayHit* rh = <ss_RTCRayHit*>((<uintptr_t>raw + 15) & ~(<uintptr_t>15))
        cdef ss_RTCIntersectArguments args
        memset(&args, 0, sizeof(args))
        args.feature_mask = RTC_FEATURE_FLAG_ALL
        memset(rh, canary, sizeof(ss_RTCRayHit) + 64)
        rh.ray.org_x, rh.ray.org_y, rh.ray.org_z = ox, oy, oz
        rh.ray.dir_x, rh.ray.dir_y, rh.ray.dir_z = dx, dy, dz
        rh.ray.tnear, rh.ray.time, rh.ray.tfar = 0.0, 0.0, tfar
        rh.ray.mask, rh.ray.id, rh.ray.flags = 0xFFFFFFFF, 0, 0
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID
        api.rtcIntersect1(self.scene, rh, &args)
        self.check("rtcIntersect1")
        return (<unsigned char*>rh)[:sizeof(ss_RTCRayHit) + 64]

    def close(self) -> None:
        """Release the scene and the device (idempotent)."""
        if self.scene != NULL:
            api.rtcReleaseScene(self.scene)
            self.scene = NULL
        if self.device != NULL:
            api.rtcReleaseDevice(self.device)
            self.device = NULL
        self._keep = []

    def __dealloc__(self):
        if self.scene != NULL:
            api.rtcReleaseScene(self.scene)
        if self.device != NULL:
            api.rtcReleaseDevice(self.device)
