"""Write ``before_issue37.npz``: the small scenes' images and gradients (of the smooth functional
the tests use) rendered by another sonarsim tree, for ``test_a_normal_scene_renders_as_before_issue_37``.

Run with the tree to take the reference from on the path, e.g.
``PYTHONPATH=<tree>/src python tests/diff/data/make_before_issue37.py out.npz``. The stored file was
made by the engine just before the degenerate-geometry guards and the objects posed at once
(issue 37), with the ray weight's cos(elevation) already in it, so that the test isolates those
changes from that physics fix.
"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # small_scenes.py beside this folder

import sonarsim.diff as sd  # noqa: E402
from sonarsim.diff.check import smooth_weights  # noqa: E402
from small_scenes import SCENES  # noqa: E402


def main(out: str) -> None:
    arrays = {}
    for name, doc in SCENES.items():
        r = sd.Renderer(doc)
        p = r.params()
        image = np.asarray(r.render(p))
        arrays[f"{name}/image"] = image
        w = jnp.asarray(smooth_weights(image.shape))
        for k, v in jax.grad(lambda q: jnp.sum(w * r.render(q)))(p).items():
            arrays[f"{name}/grad/{k}"] = np.asarray(v)
    np.savez(out, **arrays)


if __name__ == "__main__":
    main(sys.argv[1])
