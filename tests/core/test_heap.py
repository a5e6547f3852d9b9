"""sonarsim.core.memory.keep_freed_memory: big frames do not page-fault in steady state."""

from __future__ import annotations

import resource
import sys

import pytest

import sonarsim
from sonarsim.config.examples import demo_scene_dict


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's heap tuning")
def test_a_1024_beam_frame_reuses_the_heap_instead_of_faulting_pages():
    # 187,392 rays, a (5, 1288, 1024) float32 image stack (26 MB): above glibc's own mmap
    # threshold, each frame's blocks were fresh mappings, 2,300 page faults a frame.
    doc = demo_scene_dict()
    doc["sonar"]["n_beams"] = 1024
    sim = sonarsim.Simulator(doc)
    for _ in range(3):
        sim.render(keep_rays=False)
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(4):
        sim.render(keep_rays=False)
    faults = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 4
    assert faults < 100, f"{faults:.0f} page faults per frame"
