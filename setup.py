"""The compiled extensions; everything else is in pyproject.toml.

* ``sonarsim.renderer._kernels``: the per-ray kernels (NumPy twins remain as the reference).
  ``-fno-tree-slp-vectorize``: gcc 12's SLP vectorizer drops the float32 rounding of a point
  that ``trace_leg`` rounds on purpose (as the caster reports it); the kernel twin tests catch it.
* ``sonarsim.sensor._stage`` (and ``_stage_avx2``, the same loops built with AVX2 and FMA on
  x86-64, used where the processor has them): the sensor stage's per-pixel loops. Its logarithm is inlined
  (vectorised everywhere); on x86-64 Linux with glibc, ``-ffast-math`` lets gcc also call
  glibc's vectorised ``expf`` (libmvec) in the gamma compression and vectorise the sums;
  ``-mrecip=none`` keeps square roots exact. Elsewhere the loops are built with plain ``-O3``
  (same results, slower).
* ``sonarsim.image._fan_levels``: the fan's 8-bit levels gathered from the polar grid's (one
  pass, integer arithmetic; :meth:`~sonarsim.image.fan.FanMapper.levels` has the NumPy twin).
* ``sonarsim.trace._embree4``: a small binding to the Embree 4 C API bundled with embreex. It
  is not linked against Embree: it opens the library at run time (dlopen), so only ``-ldl``
  (part of libc on recent glibc) is needed. Not built on Windows (no dlopen there).
"""

import platform
import sys

from setuptools import Extension, setup

VECTOR_MATH = (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")
               and platform.libc_ver()[0] == "glibc")
IS_MSVC = sys.platform == "win32"
# A second build of the sensor stage with AVX2 and FMA, chosen at run time where the processor
# has them (sonarsim.sensor.model); the baseline build stays for the others.
X86_64 = platform.machine().lower() in ("x86_64", "amd64") and not IS_MSVC


def flags(*args: str) -> list[str]:
    return [] if IS_MSVC else list(args)


setup(
    ext_modules=[
        Extension("sonarsim.renderer._kernels", ["src/sonarsim/renderer/_kernels.pyx"],
                  extra_compile_args=flags("-O3", "-fno-math-errno", "-fno-tree-slp-vectorize")),
        *[Extension(f"sonarsim.sensor.{name}", [f"src/sonarsim/sensor/{name}.pyx"],
                    depends=["src/sonarsim/sensor/_stage_body.pxi"],
                    extra_compile_args=flags("-O3", "-fno-math-errno")
                    + (["-ffast-math", "-mrecip=none"] if VECTOR_MATH else []) + simd,
                    extra_link_args=["-lmvec"] if VECTOR_MATH else [])
          for name, simd in [("_stage", [])] + ([("_stage_avx2", ["-mavx2", "-mfma"])] if X86_64 else [])],
        Extension("sonarsim.trace._hits", ["src/sonarsim/trace/_hits.pyx"], extra_compile_args=flags("-O3")),
        Extension("sonarsim.image._fan_levels", ["src/sonarsim/image/_fan_levels.pyx"], extra_compile_args=flags("-O3")),
        *([] if IS_MSVC else [
            Extension("sonarsim.trace._embree4", ["src/sonarsim/trace/_embree4.pyx"],
                      extra_compile_args=flags("-O3", "-fno-math-errno", "-fno-tree-slp-vectorize"),
                      libraries=["dl"] if sys.platform.startswith("linux") else []),
        ]),
    ],
)
