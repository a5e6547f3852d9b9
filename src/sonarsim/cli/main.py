"""Command-line interface: a thin layer over the library; one module per command.

Results go to files; progress and timing go to stderr. Bad input ends with a one-line message
naming the key or file, exit status 2, and no traceback.
"""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from ..errors import SonarsimError

EXIT_BAD_INPUT = 2


def _log(msg: str) -> None:
    print(f"sonarsim: {msg}", file=sys.stderr, flush=True)


def _memory_size(text: str) -> int:
    from ..core.memory import parse_size

    try:
        return parse_size(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    """The ``sonarsim`` parser: one sub-command per module of :mod:`sonarsim.cli`."""
    from .calibrate import add_calibrate_parser
    from .compare import add_compare_parser
    from .demo import add_demo_parser
    from .fit import add_fit_parser
    from .presets import add_presets_parser
    from .render import add_render_parser
    from .show import add_show_parser

    parser = argparse.ArgumentParser(
        prog="sonarsim",
        description="Simulate 2D forward-looking sonar images (with ground echoes) from 3D scenes.",
    )
    from .. import __version__

    parser.add_argument("--version", action="version", version=f"sonarsim {__version__}")
    parser.add_argument("--max-memory", type=_memory_size, default=None, metavar="SIZE",
                        help="memory budget that sizes are checked against before allocating, e.g. 4G "
                        "(default: $SONARSIM_MAX_MEMORY, else 8 GiB or 80%% of the machine's memory)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    add_render_parser(sub)
    add_demo_parser(sub)
    add_presets_parser(sub)
    # Real data: reading recordings, comparing images, fitting the pose.
    add_show_parser(sub)
    add_compare_parser(sub)
    add_fit_parser(sub)
    add_calibrate_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``sonarsim`` command; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    from ..core.memory import set_memory_budget

    set_memory_budget(args.max_memory)
    try:
        args.func(args)
    except SonarsimError as exc:
        _log(f"error: {exc}")
        return EXIT_BAD_INPUT
    except OSError as exc:  # e.g. an output folder that cannot be written
        # A failed rename names the temporary file first; the user wants the destination.
        name = exc.filename2 or exc.filename or ""
        _log(f"error: {name}: {exc.strerror or exc}")
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
