"""``sonarsim view``: a scene in 3D in the browser, with its live sonar images; or a recording.

The logic (what is shown, re-rendering, saving) lives in plain Python classes that need no
browser and no viser (:mod:`.state`, :mod:`.geometry`); :mod:`.app` wires them to a viser
page; :mod:`.guard` stands between the network and viser (connections only from the page's own
origin and by the server's own names; messages only with values the controls allow). viser is
an optional dependency (the ``viewer`` extra): :func:`require_viser` says how to install it
when it is missing.
"""

from __future__ import annotations

from types import ModuleType

from ...core.extras import install_hint
from ...errors import SonarsimError

__all__ = ["VIEWER_EXTRA_MESSAGE", "require_viser"]

#: What ``sonarsim view`` says when viser is not installed.
VIEWER_EXTRA_MESSAGE = install_hint("viewer")  # (a clone's pip install -e, or the package's extra)


def require_viser() -> ModuleType:
    """The :mod:`viser` module.

    Raises
    ------
    SonarsimError
        viser is not installed; the message names the extra that installs it.
    """
    try:
        import viser
    except ImportError:
        raise SonarsimError(VIEWER_EXTRA_MESSAGE) from None
    return viser
