"""``python -m sonarsim``: the command-line interface."""

from .cli.main import console_main

console_main()
