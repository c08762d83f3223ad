"""Text drawn onto rendered frames with Pillow: goal labels and panel titles.

A goal's label stands above its cube: the point 6 cm over the cube's centre is projected
through the camera (:func:`slotv_jax.rendering.camera.pixels`) and the label is centred
there, dark letters on a light rounded box with the cube's colour as its border, so that
a participant can name the cube ("B") whatever is behind it. The labels of a clip do not
move (the camera and cubes stand still), so they are drawn once into an RGBA layer and
blended into every frame.
"""

from __future__ import annotations

import functools
import importlib.util
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from jaxtyping import UInt8
from PIL import Image, ImageDraw, ImageFont

from slotv_jax.rendering.camera import View, pixels, scene_model

LABEL_LIFT = 0.06  # metres above the cube centre where a label is anchored


def _dejavu() -> Path | None:
    """matplotlib's DejaVu Sans (Greek and accented letters too), found without importing it."""
    spec = importlib.util.find_spec("matplotlib")
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "mpl-data" / "fonts" / "ttf" / "DejaVuSans.ttf"
    return path if path.is_file() else None


@functools.cache
def font(px: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    """DejaVu Sans at ``px`` pixels (shipped with matplotlib), else Pillow's bundled font."""
    path = _dejavu()
    return ImageFont.truetype(str(path), px) if path else ImageFont.load_default(size=px)


def font_size(height: int) -> int:
    """Label text height for a frame of ``height`` pixels (18 px at 360)."""
    return max(10, round(height / 20))


def cube_colours() -> np.ndarray:
    """(8, 3) uint8 colours of the cubes (cube k carries goal slot k)."""
    m = scene_model()
    out = []
    for k in range(m.nmocap):
        body = next(b for b in range(m.nbody) if m.body_mocapid[b] == k)
        geom = next(g for g in range(m.ngeom) if m.geom_bodyid[g] == body)
        out.append(np.round(m.geom_rgba[geom, :3] * 255))
    return np.asarray(out, np.uint8)


def label_layer(
    size: tuple[int, int],
    goals: np.ndarray,
    goal_mask: np.ndarray,
    names: Sequence[str],
    camera: View,
    *,
    target: int | None = None,
) -> UInt8[np.ndarray, "H W 4"]:
    """An RGBA image (H, W, 4) holding the goal labels (transparent elsewhere).

    ``target``'s label gets a thicker border.
    """
    w, h = size
    idx = np.flatnonzero(np.asarray(goal_mask, bool))
    anchor = np.asarray(goals, np.float64)[idx] + [0.0, 0.0, LABEL_LIFT]
    xy, depth = pixels(anchor, camera, size)
    img = Image.new("RGBA", (w, h), (0, 0, 0, 0))
    draw = ImageDraw.Draw(img)
    fnt = font(font_size(h))
    colours = cube_colours()
    pad = max(2, font_size(h) // 4)
    for k, (x, y), d, name in zip(idx, xy, depth, names, strict=True):
        if d <= 0:
            continue
        l, t, r, b = draw.textbbox((x, y), name, font=fnt, anchor="mm")
        box = (l - pad, t - pad, r + pad, b + pad)
        border = (*(int(c) for c in colours[k]), 255)
        wide = 3 if k == target else 2
        draw.rounded_rectangle(
            box, radius=pad, fill=(255, 255, 255, 225), outline=border, width=wide
        )
        draw.text((x, y), name, font=fnt, fill=(20, 20, 20, 255), anchor="mm")
    return np.asarray(img)


def blend(frames: np.ndarray, layer: np.ndarray) -> None:
    """Alpha-blend an RGBA layer into frames (..., H, W, 3) uint8, in place."""
    a = layer[..., 3:4].astype(np.float32) / 255.0
    rows = np.flatnonzero(a[..., 0].any(axis=1))
    if rows.size == 0:
        return
    sl = slice(rows[0], rows[-1] + 1)
    a = a[sl]
    f = frames[..., sl, :, :].astype(np.float32)
    frames[..., sl, :, :] = np.round(f * (1 - a) + layer[sl, :, :3].astype(np.float32) * a).astype(
        np.uint8
    )


def draw_goal_labels(
    frames: np.ndarray,
    goals: np.ndarray,
    goal_mask: np.ndarray,
    names: Sequence[str],
    camera: View,
    *,
    target: int | None = None,
) -> None:
    """Draw the goal labels into frames (F, H, W, 3) or one frame (H, W, 3), in place."""
    h, w = frames.shape[-3:-1]
    blend(frames, label_layer((w, h), goals, goal_mask, names, camera, target=target))


def _bar(width: int, frame_height: int) -> tuple[Image.Image, int]:
    fh = font_size(frame_height)
    return Image.new("RGB", (width, round(fh * 1.8)), (255, 255, 255)), fh


def title(
    frame: np.ndarray, text: str, *, colour: tuple[int, int, int] = (20, 20, 20)
) -> UInt8[np.ndarray, "h W 3"]:
    """A title bar as wide as ``frame`` (white, centred text in ``colour``) to stack above it."""
    img, fh = _bar(frame.shape[1], frame.shape[0])
    draw = ImageDraw.Draw(img)
    draw.text((img.width / 2, img.height / 2), text, font=font(fh), fill=colour, anchor="mm")
    return np.asarray(img)


def legend(
    frame: np.ndarray, names: Sequence[str], colours: Sequence[tuple[int, int, int]]
) -> UInt8[np.ndarray, "h W 3"]:
    """A bar as wide as ``frame`` naming each colour: a swatch, then the name, side by side."""
    img, fh = _bar(frame.shape[1], frame.shape[0])
    draw = ImageDraw.Draw(img)
    fnt = font(fh)
    sw, gap = fh, fh
    widths = [sw + fh // 3 + draw.textlength(n, font=fnt) for n in names]
    x = (img.width - sum(widths) - gap * (len(names) - 1)) / 2
    y = img.height / 2
    for n, c, w in zip(names, colours, widths, strict=True):
        draw.rectangle((x, y - sw / 2 + 2, x + sw, y + sw / 2 - 2), fill=tuple(c))
        draw.text((x + sw + fh // 3, y), n, font=fnt, fill=(20, 20, 20), anchor="lm")
        x += w + gap
    return np.asarray(img)
