"""How to install an optional extra (``ros``, ``ray``, ``viewer``, ``diff``, ``xtf``, ``gazebo``, ``torch``): the one home of the
install hints that the messages about a missing library give.

From a checkout (sonarsim imported from a clone's ``src/``, as ``pip install -e .`` or
``PYTHONPATH=src`` leave it) the hint is ``pip install -e '<the clone>[ros]'``: ``pip install
'sonarsim[ros]'`` would fetch whatever package the index holds under that name instead of
adding the extra to this one. Elsewhere (sonarsim installed from a wheel or an index) it is
``pip install 'sonarsim[ros]'``.
"""

from __future__ import annotations

import os
import shlex
from pathlib import Path

__all__ = ["EXTRAS", "checkout_root", "install_command", "install_hint"]

#: The extras of pyproject.toml that a message may ask for, and what each brings.
EXTRAS = {
    "ros": "the ROS extra",
    "ray": "the Ray extra",
    "viewer": "the viewer extra",
    "diff": "the differentiable engine's extra (JAX)",
    "xtf": "the XTF extra (pyxtf)",
    "live": "the live extra (Cyclone DDS and rosbags)",
    "gazebo": "the Gazebo extra (pycollada, for Collada meshes)",
    "torch": "the PyTorch extra (install the CPU build first where a CUDA one is not wanted)",
}


def checkout_root() -> Path | None:
    """The clone sonarsim is imported from (its ``pyproject.toml`` beside ``src/sonarsim``), or
    None for an installed package."""
    # This file is src/sonarsim/core/extras.py in a clone.
    root = Path(__file__).resolve().parents[3]
    if (root / "pyproject.toml").is_file() and (root / "src" / "sonarsim" / "__init__.py").is_file():
        return root
    return None


def install_command(extra: str) -> str:
    """The shell command that installs ``extra`` for this sonarsim.

    Examples
    --------
    ``pip install -e '.[ros]'`` (from the clone's folder), ``pip install -e '/home/me/sonarsim[ros]'``
    (a clone, elsewhere), ``pip install 'sonarsim[ros]'`` (an installed package).
    """
    if extra not in EXTRAS:
        raise ValueError(f"extra must be one of {', '.join(EXTRAS)}, got {extra!r}")
    root = checkout_root()
    if root is None:
        return f"pip install 'sonarsim[{extra}]'"
    try:
        here = Path.cwd().resolve() == root
    except OSError:  # a deleted working directory
        here = False
    where = "." if here else os.fspath(root)
    return f"pip install -e {shlex.quote(f'{where}[{extra}]')}"


def install_hint(extra: str) -> str:
    """``install <what>: <command>``, the end of a message about a missing optional library."""
    return f"install {EXTRAS[extra]}: {install_command(extra)}"
