"""The ``sonarsim`` command line: :mod:`~sonarsim.cli.main` dispatches to one module per
command (``render``, ``demo``, ``presets``, ``show``, ``compare``, ``fit``)."""
