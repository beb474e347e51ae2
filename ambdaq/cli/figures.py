"""Figures: matplotlib on the Agg backend (no display needed) and the image files it can write.

matplotlib is the ``plot`` extra (``pip install 'ambdaq[plot]'``): a recording-only install on a
controller PC goes without it, and a command asked for a figure then says so in one line.
"""

from __future__ import annotations

from pathlib import Path

import click

from ..errors import BadInputError

EXTRA = "pip install 'ambdaq[plot]'"


def pyplot():
    """matplotlib.pyplot on the Agg backend; BadInputError naming the extra if it is not installed."""
    try:
        import matplotlib
    except ImportError:
        raise BadInputError(f"figures need matplotlib, the plot extra: {EXTRA}") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def image_formats() -> dict[str, str]:
    """File suffixes matplotlib writes (without the dot) -> what they are."""
    pyplot()
    from matplotlib.backend_bases import FigureCanvasBase

    return FigureCanvasBase.get_supported_filetypes()


class ImagePath(click.ParamType):
    """An image file to write: its suffix must be one matplotlib writes (png, pdf, svg ...),
    checked before any work is done."""

    name = "IMAGE"

    def convert(self, value, param, ctx):
        path = Path(value)
        if path.is_dir():
            self.fail(f"{value!r} is a directory", param, ctx)
        formats = image_formats()
        if path.suffix.lstrip(".").lower() not in formats:
            self.fail(f"{value!r}: an image needs one of the suffixes {', '.join('.' + k for k in sorted(formats))}",
                      param, ctx)
        return str(path)


def plot_option(help_text: str):
    """``--plot IMAGE``: where a command draws its figure."""
    return click.option("--plot", "plot_path", type=ImagePath(), help=help_text)
