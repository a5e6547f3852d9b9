"""Pictures people can read: annotated matplotlib figures, notebook displays, the live viewer.

Everything here is for people to look at; the exact-pixel PNGs and arrays that programs read
are written by :mod:`sonarsim.io`. matplotlib is imported only when a figure is made, with the
Agg backend unless one was chosen (``import sonarsim`` stays fast and needs no display).

The image types (:mod:`sonarsim.image`) sit below this package and do not import it: their
``_repr_png_``, ``plot``, ``save`` and ``to_pil`` call the hooks that :mod:`sonarsim.plot.hooks`
registers when this package is imported (``import sonarsim`` imports it).
"""

from . import hooks  # noqa: F401  (installs the image types' picture methods: sonarsim.image.display)
from .formats import FIGURE_FORMATS  # noqa: F401
