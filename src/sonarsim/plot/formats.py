"""The formats figures are written in; a module of its own, importing nothing, so that the
command line checks ``--figure-format`` without NumPy and :mod:`sonarsim.plot.figures` reads
the list without importing its package (which imports the figures' hooks)."""

#: Formats figures are written in (``--figure-format``; :func:`sonarsim.plot.figures.save_figure`).
FIGURE_FORMATS = ("png", "svg", "pdf")
