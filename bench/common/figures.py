"""One look for every figure the project saves, so that a figure reads without the README.

- Colours from the Okabe-Ito palette (Okabe & Ito 2008, "Color Universal Design"), which readers
  with any common colour-vision deficiency can tell apart (matplotlib's ``tab10`` pairs red and
  green); past eight series a marker shape tells the wrapped colours apart.
- A run's non-default options in the title (:func:`titled`), as the command line spells them.
- Legends outside the data (:func:`legend_outside`), point names that never cover one another
  (:func:`label_points`), and saving with a tight bounding box so that
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


#: Where a point's name may go, in points from the point (x, y, horizontal alignment): beside it
#: first, then above and below, then further out; the first spot that covers no other name or
#: point is taken.
LABEL_SPOTS = tuple(
    (dx, dy, ha)
    for dy in (3, -11, 12, -20, 21, -29, 30, -38)
    for dx, ha in ((4, "left"), (-4, "right"))
)
#: Points closer than this on screen (px) are one place: one name lists them all.
SAME_PLACE_PX = 4.0
#: Half the side (px) of the square a large marker (a reference star, a ring) keeps clear.
LARGE_MARKER_PX = 12.0


def label_points(ax: plt.Axes, xs: Sequence[float], ys: Sequence[float], names: Sequence[str],
                 fontsize: float = 7, avoid: Sequence[tuple[float, float]] = (),
                 draw: bool = True) -> None:  # fmt: skip
    """Name each point beside it, no name over another name or a point: points that coincide
    on screen share one name ("a, b"); a name that would cover one already placed, another
    point, a large marker at an ``avoid`` point (x, y) or the axes' edge takes the first free
    spot of :data:`LABEL_SPOTS` (the first spot if none is free).
    The figure is drawn first, so that its layout has settled the axes' scales; ``draw=False``
    where the caller drew it after its last change (panels named in turn: names stay out of
    the layout, so one draw serves them all)."""
    import numpy as np
    from matplotlib.transforms import Bbox

    fig = ax.figure
    if draw:
        fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    data = np.column_stack([np.asarray(xs, float), np.asarray(ys, float)])
    screen = ax.transData.transform(data) if len(data) else np.empty((0, 2))
    places: list[tuple[int, list[str]]] = []  # (index of the first point, names there)
    for i, name in enumerate(names):
        near = [p for p in places if np.hypot(*(screen[p[0]] - screen[i])) < SAME_PLACE_PX]
        if near:
            near[0][1].append(str(name))
        else:
            places.append((i, [str(name)]))
    dots = [Bbox.from_extents(x - 4, y - 4, x + 4, y + 4) for x, y in screen]
    big, r = ax.transData.transform(np.asarray(avoid, float).reshape(-1, 2)), LARGE_MARKER_PX
    large = [Bbox.from_extents(x - r, y - r, x + r, y + r) for x, y in big]
    frame = ax.get_window_extent(renderer)  # a name stays inside the axes where it can
    taken: list = []
    for i, group in sorted(places, key=lambda p: -screen[p[0], 1]):  # top down
        others = [
            d for j, d in enumerate(dots) if np.hypot(*(screen[j] - screen[i])) >= SAME_PLACE_PX
        ]
        first = None

        def put(dx: float, dy: float, ha: str, group=group, i=i):  # not in the layout
            return ax.annotate(
                ", ".join(group), tuple(data[i]), fontsize=fontsize, ha=ha, xytext=(dx, dy),
                textcoords="offset points", in_layout=False,
            )  # fmt: skip

        for dx, dy, ha in LABEL_SPOTS:
            text = put(dx, dy, ha)
            box = text.get_window_extent(renderer)
            inside = frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0
            inside = inside and box.y1 <= frame.y1
            if inside and not any(box.overlaps(b) for b in taken + others + large):
                break
            text.remove()
            first = first or (dx, dy, ha)
        else:  # nowhere free: the first spot
            text = put(*first)
            box = text.get_window_extent(renderer)
        taken.append(box)


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
