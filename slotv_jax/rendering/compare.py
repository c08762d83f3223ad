"""Several motions of one scene in one picture: side by side, or overlaid.

For papers and talks: the straight line, the oracle's legible plan and the learned
observer's plan to the same goal, on the same clock. ``layout="side"`` puts one panel per
motion in a row, each titled and with its TCP trace in its own colour; ``"overlay"``
draws every trace into one scene and averages the robots (each shows through at 1/n),
with a legend of the colours above.

>>> frames = compare_frames([q_straight, q_plan], goals, mask,
...                         names=["straight", "legible"], tau=0.5)  # doctest: +SKIP
>>> write_png("compare.png", frames[-1])                            # doctest: +SKIP
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from jaxtyping import Bool, Float, UInt8

from slotv_jax.rendering.camera import View, check_view
from slotv_jax.rendering.frames import (
    MotionRenderer,
    check_motion,
    check_size,
    clips,
    frame_times,
    goal_labels,
)
from slotv_jax.rendering.overlay import draw_goal_labels, legend, title

LAYOUTS = ("side", "overlay")
# Trace colours of the compared motions, in order: dark grey, blue, orange, green, purple, red,
# brown, teal.
PALETTE = (
    (0.15, 0.15, 0.15, 1.0),
    (0.10, 0.35, 0.90, 1.0),
    (0.95, 0.45, 0.00, 1.0),
    (0.10, 0.60, 0.20, 1.0),
    (0.55, 0.25, 0.70, 1.0),
    (0.85, 0.10, 0.10, 1.0),
    (0.55, 0.35, 0.15, 1.0),
    (0.00, 0.55, 0.55, 1.0),
)
GAP = 6  # pixels between side-by-side panels


def compare_frames(
    qs: Sequence[Float[np.ndarray, "T 7"]],
    goals: Float[np.ndarray, "8 3"],
    goal_mask: Bool[np.ndarray, "8"],
    *,
    names: Sequence[str] | None = None,
    rgbas: Sequence[tuple[float, float, float, float]] | None = None,
    ts: Sequence[Float[np.ndarray, " T"] | None] | None = None,
    layout: str = "side",
    camera: View = "observer",
    tau: float = 1.0,
    size: tuple[int, int] = (640, 360),
    fps: float = 30.0,
    duration: float = 3.0,
    hold: float = 1.0,
    labels: Sequence[str] | None = None,
    show_labels: bool = True,
    target: int | None = None,
    trace: bool = True,
    shadows: bool = False,
    renderer: MotionRenderer | None = None,
    cols: int | None = None,
) -> UInt8[np.ndarray, "F H W 3"]:
    """Frames of several motions of one scene on one clock (see the module docstring).

    ``size`` is one panel's; ``names`` title the panels (side) or the legend (overlay);
    ``rgbas`` colour the motions' traces and names (default: :data:`PALETTE` in order);
    ``ts`` are the motions' sample times (any unit, normalised per motion, as ``t`` of
    :func:`slotv_jax.render.motion_frames`; None: evenly spaced); the other arguments as in
    :func:`slotv_jax.render.motion_frames`. Side by side the panels, each with a title bar
    on top, lie in rows of ``cols`` panels (None: :func:`side_columns`), GAP pixels apart.
    """
    if len(qs) < 1 or len(qs) > len(PALETTE):
        raise ValueError(f"qs: expected 1..{len(PALETTE)} motions, got {len(qs)}")
    ts = [None] * len(qs) if ts is None else list(ts)
    if len(ts) != len(qs):
        raise ValueError(f"ts: expected {len(qs)} time arrays (or None), got {len(ts)}")
    for i, q in enumerate(qs):
        try:
            check_motion(q, goals, goal_mask, t=ts[i], target=target, labels=labels)
        except ValueError as e:
            raise ValueError(f"qs[{i}]: {e}") from None
    names = [f"motion {i}" for i in range(len(qs))] if names is None else list(names)
    if len(names) != len(qs) or not all(isinstance(n, str) for n in names):
        raise ValueError(f"names: expected {len(qs)} strings, got {names!r}")
    if layout not in LAYOUTS:
        raise ValueError(f"layout: expected one of {list(LAYOUTS)}, got {layout!r}")
    check_view(camera)
    size = check_size(size)
    s = frame_times(tau, fps=fps, duration=duration, hold=hold)
    if renderer is not None and renderer.size != size:
        raise ValueError(f"renderer: expected one of size {size}, got {renderer.size}")
    rgbas = PALETTE[: len(qs)] if rgbas is None else tuple(tuple(c) for c in rgbas)
    if len(rgbas) != len(qs) or any(len(c) != 4 or not all(0 <= v <= 1 for v in c) for c in rgbas):
        raise ValueError(f"rgbas: expected {len(qs)} RGBA colours in [0, 1], got {rgbas!r}")
    r = renderer if renderer is not None else MotionRenderer(size, shadows=shadows)
    try:
        out = clips(
            r,
            [(np.asarray(q), t) for q, t in zip(qs, ts, strict=True)],
            goals,
            goal_mask,
            s,
            camera,
            rgbas=rgbas,
            target=target,
            trace=trace,
            overlay=layout == "overlay",
        )
    finally:
        if renderer is None:
            r.close()
    if show_labels:
        text = goal_labels(goal_mask) if labels is None else list(labels)
        for o in out:
            draw_goal_labels(o, goals, goal_mask, text, camera, target=target)
    colours = [tuple(round(255 * c) for c in rgba[:3]) for rgba in rgbas]
    if layout == "overlay":
        bar = legend(out[0][0], names, colours)
        return np.concatenate([np.broadcast_to(bar, (len(s), *bar.shape)), out[0]], axis=1)
    panels = []
    for o, n, c in zip(out, names, colours, strict=True):
        bar = title(o[0], n, colour=c)
        panels.append(np.concatenate([np.broadcast_to(bar, (len(s), *bar.shape)), o], axis=1))
    if cols is None:
        cols = side_columns(len(panels))
    elif not (isinstance(cols, int) and cols >= 1):
        raise ValueError(f"cols: expected an int >= 1 or None, got {cols!r}")
    blank = np.full_like(panels[0], 255)
    panels += [blank] * (-len(panels) % cols)  # the last row filled with white
    rows = [_joined(panels[i : i + cols], axis=2) for i in range(0, len(panels), cols)]
    return np.ascontiguousarray(_joined(rows, axis=1))


def _joined(parts: list[np.ndarray], axis: int) -> np.ndarray:
    """``parts`` (F, H, W, 3) joined along ``axis`` (1: rows, 2: columns), GAP white pixels
    between each two."""
    gap = np.full_like(np.take(parts[0], range(GAP), axis=axis), 255)
    return np.concatenate([x for part in parts for x in (gap, part)][1:], axis=axis)


def side_columns(n: int) -> int:
    """Panels per row of ``n`` motions side by side: one row up to three, else a grid of
    ⌈√n⌉ columns, at most four (seven planners at 640 × 360: 3 columns, 3 rows, not one
    row of 4516 × 392 pixels)."""
    return n if n <= 3 else min(4, math.ceil(math.sqrt(n)))
