"""One colour per skill, the same in every view of a recording, in the review plot and in the README picture.

The colours are Okabe and Ito's colour-blind-safe qualitative set, ordered so that the first four (the size of most
skill libraries here) are far apart in hue and read on both the viewer's dark and matplotlib's white background.
A skill's colour is its position in the library: ``skill_colors(names)[k]`` is skill ``k``'s, wherever it is drawn.
"""

from __future__ import annotations

from collections.abc import Sequence

RGB = tuple[int, int, int]

# sky blue, orange, bluish green, reddish purple, vermillion, blue, yellow, grey
PALETTE: tuple[RGB, ...] = (
    (86, 180, 233),
    (230, 159, 0),
    (0, 158, 115),
    (204, 121, 167),
    (213, 94, 0),
    (0, 114, 178),
    (240, 228, 66),
    (153, 153, 153),
)
NEUTRAL: RGB = (235, 235, 235)  # the blended action, the task's key state: not a skill


def skill_colors(names: Sequence[str]) -> list[RGB]:
    """The colour of each skill in ``names``, by position (the palette repeats past eight skills)."""
    return [PALETTE[k % len(PALETTE)] for k in range(len(names))]


def shades(color: RGB, n: int) -> list[RGB]:
    """``n`` variants of ``color`` for several series of one skill in one view (an action's components, a
    skill's timings): the first is ``color`` itself, the others mixed towards white, up to 60%."""
    if n <= 1:
        return [color][:n]
    return [tuple(round(c + (255 - c) * 0.6 * j / (n - 1)) for c in color) for j in range(n)]  # type: ignore[misc]


def greys(n: int) -> list[RGB]:
    """``n`` neutral shades from near white to mid grey: the series of one view that are not skills."""
    if n <= 1:
        return [NEUTRAL][:n]
    return [(v, v, v) for v in (round(235 - 105 * j / (n - 1)) for j in range(n))]


def mpl(color: RGB) -> tuple[float, float, float]:
    """``color`` as matplotlib's (r, g, b) in [0, 1]."""
    return (color[0] / 255, color[1] / 255, color[2] / 255)
