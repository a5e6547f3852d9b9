"""Registers the pictures (and the NPZ writer) of the image types into :mod:`sonarsim.image.display`.

:class:`~sonarsim.image.result.SonarImage` and :class:`~sonarsim.image.fan.FanImage` do not import
this package (it sits above them); their ``_repr_png_``, ``plot``, ``save``, ``to_pil`` and
``save_npz`` call the hooks installed here. This module is imported by :mod:`sonarsim.plot`
(and so by ``import sonarsim``) and must stay light: each hook imports what does the work
(:mod:`sonarsim.plot.notebook`, matplotlib, :mod:`sonarsim.io.output`) on its first call, so that
``import sonarsim`` and the command's start load none of them.

The NPZ writer belongs to :mod:`sonarsim.io`, which registers it too when
:mod:`sonarsim.io.output` is imported; it is registered here as well (plot sits above io) so that
``import sonarsim`` gives ``save_npz`` without loading the writers.
"""

from __future__ import annotations

from typing import Any

from ..image.display import register

__all__: list[str] = []


def _image_repr_png(image: Any) -> bytes:
    from .notebook import image_repr_png

    return image_repr_png(image)


def _image_plot(image: Any, *args: Any, **options: Any) -> Any:
    from .notebook import image_plot

    return image_plot(image, *args, **options)


def _image_save(image: Any, *args: Any, **options: Any) -> None:
    from .notebook import image_save

    image_save(image, *args, **options)


def _image_to_pil(image: Any, *args: Any, **options: Any) -> Any:
    from .notebook import image_to_pil

    return image_to_pil(image, *args, **options)


def _fan_repr_png(fan: Any) -> bytes:
    from .notebook import fan_image_repr_png

    return fan_image_repr_png(fan)


def _fan_plot(fan: Any, *args: Any, **options: Any) -> Any:
    from .notebook import fan_image_plot

    return fan_image_plot(fan, *args, **options)


def _fan_save(fan: Any, *args: Any, **options: Any) -> None:
    from .notebook import fan_image_save

    fan_image_save(fan, *args, **options)


def _write_npz(*args: Any, **kwargs: Any) -> None:
    from ..io.output import write_npz

    write_npz(*args, **kwargs)


def register_all() -> None:
    """Install every hook (done on import; again after a test replaced one)."""
    register("image_repr_png", _image_repr_png)
    register("image_plot", _image_plot)
    register("image_save", _image_save)
    register("image_to_pil", _image_to_pil)
    register("fan_repr_png", _fan_repr_png)
    register("fan_plot", _fan_plot)
    register("fan_save", _fan_save)
    register("write_npz", _write_npz)


register_all()
