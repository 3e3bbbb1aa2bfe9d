"""One look for every figure the project saves, so that a figure reads without the README.

- Colours from the Okabe-Ito palette (Okabe & Ito 2008, "Color Universal Design"), which readers
  with any common colour-vision deficiency can tell apart (matplotlib's ``tab10`` pairs red and
  green); past eight series a marker shape tells the wrapped colours apart.
- A run's non-default options in the title (:func:`titled`), as the command line spells them.
- Legends outside the data (:func:`legend_outside`), and saving with a tight bounding box so that
  no title or legend is clipped (:func:`save`); the title goes into the PNG's metadata too, so a
  test (or a reader's file browser) can read it from the file.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402

from bench.common.atomic import atomic_path  # noqa: E402

#: Okabe-Ito, yellow last (the least contrast on white) and its black after the colours.
PALETTE = ("#E69F00", "#56B4E9", "#009E73", "#0072B2", "#D55E00", "#CC79A7", "#000000", "#F0E442")
ORANGE, SKY_BLUE, GREEN, BLUE, VERMILLION, PURPLE, BLACK, YELLOW = PALETTE
#: Neutral greys for what is not a series (behind a front, refused, reference lines).
GREY, LIGHT_GREY = "#8c8c8c", "#c8c8c8"
#: One marker per pass through the palette: series i and i + 8 share a colour, not a marker.
MARKERS = ("o", "s", "^", "D", "v", "P")
DPI = 120
#: Title lines wrap here, so a long list of options never runs past the figure's edge.
TITLE_WIDTH = 110


def colour(i: int) -> str:
    """The i-th series' colour."""
    return PALETTE[i % len(PALETTE)]


def marker(i: int) -> str:
    """The i-th series' marker: changes each time the colours wrap."""
    return MARKERS[(i // len(PALETTE)) % len(MARKERS)]


def titled(title: str, options: Sequence[str] = ()) -> str:
    """``title`` with a last line naming the run's non-default options (``--quick``,
    ``--sizes 8.8,13.2``), wrapped; just ``title`` when every option is the default."""
    if not options:
        return title
    wrapped = textwrap.fill("options: " + " ".join(options), TITLE_WIDTH)
    return f"{title}\n{wrapped}"


def legend_outside(fig: plt.Figure, handles: list, labels: list | None = None, **kwargs) -> None:
    """A figure legend right of the axes, never over the title or the data: a constrained
    layout makes room for it; otherwise it hangs past the figure's edge, and :func:`save`'s tight
    box takes it in."""
    from matplotlib.layout_engine import ConstrainedLayoutEngine

    if isinstance(fig.get_layout_engine(), ConstrainedLayoutEngine):
        where = {"loc": "outside right center"}
    else:
        where = {"loc": "center left", "bbox_to_anchor": (1.0, 0.5)}
    kwargs = {**where, "frameon": False, **kwargs}
    if labels is None:
        fig.legend(handles=handles, **kwargs)
    else:
        fig.legend(handles, labels, **kwargs)


def figure_title(fig: plt.Figure) -> str:
    """The suptitle, else the axes' titles joined: what the PNG's metadata records."""
    if fig.get_suptitle():
        return fig.get_suptitle()
    return " | ".join(ax.get_title() for ax in fig.axes if ax.get_title())


def save(fig: plt.Figure, path: Path, dpi: int = DPI) -> None:
    """Write the figure as PNG atomically, its bounding box tight around every artist (nothing
    clipped), its title in the PNG's ``Title`` metadata; then close it."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(
            tmp,
            format="png",
            dpi=dpi,
            bbox_inches="tight",
            pad_inches=0.1,
            metadata={"Title": figure_title(fig)},
        )
    plt.close(fig)
