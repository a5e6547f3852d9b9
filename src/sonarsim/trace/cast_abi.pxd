# The C signature by which sonarsim.trace._embree4 lends its packet loop to the compiled
# kernels (sonarsim.renderer._kernels), so that a kernel casts without returning to Python.
# The kernels get the function's address from the binding at run time (no link between the
# two extensions: the kernels still build and load where the binding does not).

ctypedef void (*cast_rays_t)(void* scene, const float* origins, Py_ssize_t origin_step,
                             const float* directions, const float* tfar, Py_ssize_t tfar_step,
                             const int* ids, float* distance, int* mesh_id, float* normal,
                             int* prim, float* uv, Py_ssize_t n, bint coherent) noexcept nogil
