"""Pictures people can read: annotated matplotlib figures, notebook displays, the live viewer.

Everything here is for people to look at; the exact-pixel PNGs and arrays that programs read
are written by :mod:`sonarsim.io`. matplotlib is imported only when a figure is made, with the
Agg backend unless one was chosen (``import sonarsim`` stays fast and needs no display).
"""

#: Formats figures are written in (``--figure-format``; :func:`sonarsim.plot.figures.save_figure`).
FIGURE_FORMATS = ("png", "svg", "pdf")
