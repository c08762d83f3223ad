"""Frames to files: MP4 (H.264), GIF, PNG stills and contact sheets.

Rendering and encoding are two steps: :mod:`slotv_jax.rendering.frames` returns uint8 arrays
(F, H, W, 3) and the functions here write them. MP4 goes through PyAV (``av``), whose
wheel carries its own FFmpeg with libx264: no system ffmpeg, and numpy frames go to the
encoder in-process, without a subprocess and a pipe. It was chosen over imageio-ffmpeg,
whose wheel is twice the size (68 MB against 35 MB) and which drives an ffmpeg binary
through a pipe. The video is H.264 in yuv420p with the index at the front
(``movflags=+faststart``), which every browser plays as it streams. GIF and PNG go
through Pillow.

Every file is written to a temporary name beside the target and renamed
(:func:`slotv_jax.core.fileio.atomic_write`).

>>> write_video("clip.mp4", frames, fps=30)  # doctest: +SKIP
>>> write_png("sheet.png", contact_sheet(frames, n=6, cols=3))  # doctest: +SKIP
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from jaxtyping import UInt8
from PIL import Image

from slotv_jax.core.fileio import OutputError, atomic_write, check_output_file
from slotv_jax.rendering.overlay import title

VIDEO_SUFFIXES = (".mp4", ".gif")
IMAGE_SUFFIXES = (".png",)
SUFFIXES = VIDEO_SUFFIXES + IMAGE_SUFFIXES
CRF = 20  # H.264 constant rate factor: 0 lossless ... 51 worst; ~18-23 looks clean
PRESET = "veryfast"  # libx264 speed preset: a 100-frame 640x360 clip in about a second
CODED_WIDTH = 64  # the coded width is a multiple of this (bytes of libx264's widest loads)
CODED_HEIGHT = 32  # ... and the height of this (rows FFmpeg allocates a frame's planes to)


def check_frames(frames, *, video: bool = True) -> np.ndarray:
    """uint8 (F, H, W, 3) frames with F ≥ 1 (or one (H, W, 3) image when not ``video``)."""
    a = np.asarray(frames)
    want = 4 if video else 3
    if a.dtype != np.uint8 or a.ndim != want or a.shape[-1] != 3 or 0 in a.shape:
        shape = "(F, H, W, 3)" if video else "(H, W, 3)"
        raise ValueError(f"frames: expected uint8 RGB {shape}, got {a.dtype}{list(a.shape)}")
    return a


def check_output(
    path: str | os.PathLike,
    *,
    overwrite: bool = False,
    suffixes: Sequence[str] = SUFFIXES,
    what: str = "--out",
) -> Path:
    """Check, before any rendering, that ``path`` may be written: a known suffix and the
    project's output rule (:func:`slotv_jax.core.fileio.check_output_file`: a writable folder,
    no directory in the way, an existing file replaced only with ``overwrite``).
    Raises :class:`slotv_jax.core.fileio.OutputError` (a ValueError)."""
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        raise OutputError(f"{what} {path}: expected a file ending in {' or '.join(suffixes)}")
    check_output_file(path, overwrite=overwrite, what=what)
    return path


def encode_mp4(frames: UInt8[np.ndarray, "F H W 3"], fps: float) -> bytes:
    """H.264 (yuv420p) MP4 bytes. 4:2:0 chroma needs an even width and height: an odd
    one gets its last row or column repeated once.

    The same frames give the same bytes in every process. libx264 reads a little past
    the picture's last rows and columns when coding its last macroblock, and FFmpeg's
    frame buffers leave rows up to a multiple of 32 uninitialised: what lay there differed
    from process to process and changed the coding of that macroblock in some clips (up
    to 12 levels in a decoded pixel, and through motion prediction more). The frames are
    therefore padded, by repeating their edges, to a width that is a multiple of
    :data:`CODED_WIDTH` and a height that is a multiple of :data:`CODED_HEIGHT`, and the
    stream's crop rectangle (H.264's frame cropping) shows the picture at its own size:
    decoders return the frames' own width and height.
    """
    frames = check_frames(frames)
    _, h, w, _ = frames.shape
    shown_h, shown_w = h + h % 2, w + w % 2
    coded_h = -(-shown_h // CODED_HEIGHT) * CODED_HEIGHT
    coded_w = -(-shown_w // CODED_WIDTH) * CODED_WIDTH
    if (coded_h, coded_w) != (h, w):
        frames = np.pad(frames, ((0, 0), (0, coded_h - h), (0, coded_w - w), (0, 0)), mode="edge")
    crop = f"crop-rect=0,0,{coded_w - shown_w},{coded_h - shown_h}"  # left, top, right, bottom
    # +faststart moves the index to the front in a second pass over a named file.
    with tempfile.TemporaryDirectory() as tmp:
        name = Path(tmp) / "clip.mp4"
        with av.open(str(name), mode="w", options={"movflags": "+faststart"}) as out:
            stream = out.add_stream("libx264", rate=_rate(fps))
            stream.width, stream.height, stream.pix_fmt = coded_w, coded_h, "yuv420p"
            stream.options = {"crf": str(CRF), "preset": PRESET, "x264-params": crop}
            for f in frames:
                out.mux(stream.encode(av.VideoFrame.from_ndarray(f, format="rgb24")))
            out.mux(stream.encode(None))
        return name.read_bytes()


def _rate(fps: float):
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps: expected a number > 0, got {fps!r}")
    return Fraction(fps).limit_denominator(1001)


def encode_gif(frames: UInt8[np.ndarray, "F H W 3"], fps: float) -> bytes:
    """An endlessly looping GIF (frame times rounded to GIF's 10 ms)."""
    frames = check_frames(frames)
    imgs = [Image.fromarray(f) for f in frames]
    buf = io.BytesIO()
    ms = round(1000 / float(_rate(fps)) / 10) * 10
    imgs[0].save(buf, format="GIF", save_all=True, append_images=imgs[1:], duration=ms, loop=0)
    return buf.getvalue()


def write_video(path: str | os.PathLike, frames: UInt8[np.ndarray, "F H W 3"], fps: float) -> Path:
    """Write frames as a video; the suffix picks the format: ``.mp4`` (H.264) or ``.gif``.

    ``.png`` writes the last frame (the still a clip ends on).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".mp4":
        data = encode_mp4(frames, fps)
    elif suffix == ".gif":
        data = encode_gif(frames, fps)
    elif suffix == ".png":
        return write_png(path, check_frames(frames)[-1])
    else:
        raise ValueError(f"path: expected a suffix in {list(SUFFIXES)}, got {str(path)!r}")
    atomic_write(path, lambda f: f.write(data))
    return path


def write_png(path: str | os.PathLike, image: UInt8[np.ndarray, "H W 3"]) -> Path:
    """Write one RGB image as PNG."""
    img = Image.fromarray(check_frames(image, video=False))
    atomic_write(path, lambda f: img.save(f, format="PNG"))
    return Path(path)


def read_video(path: str | os.PathLike) -> UInt8[np.ndarray, "F H W 3"]:
    """Decode a video file (MP4 or GIF) to RGB frames, through PyAV."""
    with av.open(str(path)) as c:
        return np.stack([f.to_ndarray(format="rgb24") for f in c.decode(video=0)])


def pick(n_frames: int, n: int) -> np.ndarray:
    """``n`` frame indices evenly spread from the first to the last frame."""
    return np.unique(np.round(np.linspace(0, n_frames - 1, n)).astype(int))


def grid(
    images: Sequence[np.ndarray], cols: int, *, pad: int = 4, fill: int = 255
) -> UInt8[np.ndarray, "H W 3"]:
    """Images of one size in a grid, ``cols`` per row, ``pad`` pixels apart."""
    imgs = [check_frames(im, video=False) for im in images]
    if not imgs or any(im.shape != imgs[0].shape for im in imgs):
        raise ValueError("images: expected one or more images of the same shape")
    if int(cols) < 1:
        raise ValueError(f"cols: expected >= 1, got {cols!r}")
    cols = min(int(cols), len(imgs))
    rows = -(-len(imgs) // cols)
    h, w, _ = imgs[0].shape
    out = np.full((rows * h + (rows + 1) * pad, cols * w + (cols + 1) * pad, 3), fill, np.uint8)
    for i, im in enumerate(imgs):
        r, c = divmod(i, cols)
        y, x = pad + r * (h + pad), pad + c * (w + pad)
        out[y : y + h, x : x + w] = im
    return out


def contact_sheet(
    frames: UInt8[np.ndarray, "F H W 3"],
    n: int = 6,
    cols: int = 3,
    *,
    captions: Sequence[str] | None = None,
    pad: int = 4,
) -> UInt8[np.ndarray, "H W 3"]:
    """``n`` frames spread evenly over a clip (first and last included), in a grid.

    ``captions`` (one per picked frame, e.g. ``"τ = 0.40"``) are drawn above each frame.
    """
    frames = check_frames(frames)
    if int(n) < 1:
        raise ValueError(f"n: expected >= 1, got {n!r}")
    idx = pick(len(frames), int(n))
    picked = [frames[i] for i in idx]
    if captions is not None:
        if len(captions) != len(idx):
            raise ValueError(f"captions: expected {len(idx)} strings, got {len(captions)}")
        picked = [np.concatenate([title(f, c), f]) for f, c in zip(picked, captions, strict=True)]
    return grid(picked, cols, pad=pad)
