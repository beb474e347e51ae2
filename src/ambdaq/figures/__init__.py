"""Every figure ambdaq draws, in one package behind the ``plot`` extra: matplotlib on the Agg
backend (no display needed).

A recording-only install on a controller PC goes without matplotlib, and a command asked for a
figure then says so in one line.  Each module draws one kind of result (a workflow's, or a
recording's signals) into a :class:`matplotlib.figure.Figure`; the command line saves it, the
commissioning report embeds it.
"""

from __future__ import annotations

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


def save(fig, out, dpi: int = 100) -> None:
    """Write ``fig`` to ``out`` (a path, its format from the suffix; or a binary file, PNG) and
    close it."""
    try:
        fig.savefig(out, dpi=dpi, format=None if isinstance(out, (str, bytes)) or hasattr(out, "__fspath__") else "png")
    finally:
        pyplot().close(fig)


__all__ = ["EXTRA", "image_formats", "pyplot", "save"]
