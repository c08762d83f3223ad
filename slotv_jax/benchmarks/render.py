"""Rendering speed: frames per second and a 100-frame MP4, against baselines in one run.

    python -m slotv_jax.benchmarks.render [--size 640x360] [--frames 100] [--json FILE]

On one joint path (``Q_HOME`` to a pose over the goal table, three goals), one open
:class:`slotv_jax.render.MotionRenderer`:

1. ``frame()`` in a loop, shadows off and on: frames/s (the OpenGL draw and the pixel
   read-back, plus MuJoCo's kinematics and scene update);
2. the naive baseline: a new ``mujoco.Renderer`` (a new OpenGL context) for every
   frame, as a per-frame helper without a kept renderer would do;
3. a ``--frames``-frame clip: ``motion_frames`` (resampling, TCP trace, goal labels)
   alone, and without the trace and labels, then the same frames encoded to MP4 (H.264
   through PyAV) and to GIF (Pillow), and the whole MP4 (render + encode + write) as a
   user gets it;
4. the clips of one motion at ``study stimuli``'s stop times τ = 0.4, 0.7, 1, each drawn
   alone (the baseline) and drawing each moment once (``motion_frames(...,
   rendered=...)``, what ``study stimuli`` does), the frames checked equal.

Times are wall clock (best of ``--repeats``) with the process's CPU time beside them;
the load average is printed before and after (the machine may be shared). The OpenGL
renderer string says what drew the pixels (Mesa's llvmpipe on a CPU, or a GPU).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import av
import mujoco
import numpy as np
from OpenGL import GL  # PyOpenGL: a dependency of mujoco's GL backends

from slotv_jax import render
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.core import cli, fileio
from slotv_jax.render.cli import parse_size
from slotv_jax.rendering import frames, writers
from slotv_jax.robot import kinematics

Q_END = np.array([0.3, -0.2, 0.1, -2.0, 0.05, 1.9, 0.7])
GOALS = np.zeros((8, 3))
GOALS[:3] = [[0.45, -0.25, 0.025], [0.55, 0.0, 0.025], [0.40, 0.25, 0.025]]
MASK = np.arange(8) < 3


def _path(n: int = 100) -> np.ndarray:
    a = np.linspace(0.0, 1.0, n)[:, None]
    return (1 - a) * kinematics.Q_HOME + a * Q_END


def _best(f, repeats: int) -> dict:
    wall, cpu = [], []
    for _ in range(repeats):
        w, c = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - w)
        cpu.append(time.process_time() - c)
    return {"wall_s": min(wall), "cpu_s": min(cpu)}


def gl_renderer() -> str:
    """The current OpenGL context's renderer and version strings (optional query)."""
    try:
        return (
            f"{GL.glGetString(GL.GL_RENDERER).decode()} / {GL.glGetString(GL.GL_VERSION).decode()}"
        )
    except Exception as e:  # no PyOpenGL, or no current context
        return f"unknown ({type(e).__name__})"


def run(size=(640, 360), n_frames: int = 100, repeats: int = 3, naive: int = 5) -> dict:
    q = _path()
    qs = frames.resample(q, np.linspace(0, 1, n_frames))
    res: dict = {"size": list(size), "frames": n_frames, "repeats": repeats}
    r = render.MotionRenderer(size)
    res["gl_renderer"] = gl_renderer()
    r.set_goals(GOALS, MASK)
    r.frame(qs[0])  # warm up: shaders, textures
    for shadows in (False, True):
        r.shadows = shadows
        n = n_frames if not shadows else max(10, n_frames // 4)
        t = _best(lambda n=n: [r.frame(qs[i % n_frames]) for i in range(n)], repeats)
        res[f"frame_fps_shadows_{'on' if shadows else 'off'}"] = n / t["wall_s"]
        res[f"frame_cpu_ms_shadows_{'on' if shadows else 'off'}"] = 1e3 * t["cpu_s"] / n
    r.shadows = False

    def naive_frames():
        for i in range(naive):
            rr = mujoco.Renderer(r.model, height=size[1], width=size[0])
            r.pose(qs[i])
            rr.update_scene(r.data, "observer")
            rr.render()
            rr.close()

    t = _best(naive_frames, 1)
    res["naive_fps"] = naive / t["wall_s"]

    kw = {"size": size, "fps": 30.0, "duration": (n_frames - 1) / 30.0, "hold": 0.0}
    clip = {}

    def frames_only():
        clip["f"] = render.motion_frames(q, GOALS, MASK, renderer=r, **kw)

    t = _best(frames_only, repeats)
    assert clip["f"].shape[0] == n_frames, clip["f"].shape
    res["clip_frames_s"] = t["wall_s"]
    res["clip_frames_cpu_s"] = t["cpu_s"]
    bare = {**kw, "trace": False, "show_labels": False}
    t = _best(lambda: render.motion_frames(q, GOALS, MASK, renderer=r, **bare), repeats)
    res["clip_bare_s"] = t["wall_s"]
    res["clip_bare_cpu_s"] = t["cpu_s"]
    res["encode_mp4_s"] = _best(lambda: writers.encode_mp4(clip["f"], 30.0), repeats)["wall_s"]
    res["encode_gif_s"] = _best(lambda: writers.encode_gif(clip["f"], 30.0), repeats)["wall_s"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "clip.mp4"

        def mp4():
            render.write_video(out, render.motion_frames(q, GOALS, MASK, renderer=r, **kw), 30.0)

        t = _best(mp4, repeats)
        res["mp4_total_s"] = t["wall_s"]
        res["mp4_total_cpu_s"] = t["cpu_s"]
        res["mp4_bytes"] = out.stat().st_size
        back = render.read_video(out)
        res["mp4_decoded"] = list(back.shape)

    def taus_clips(key: str, share: bool):  # the clips at τ = 0.4, 0.7, 1, into clip[key]
        shared: dict | None = {} if share else None
        clip[key] = [
            render.motion_frames(q, GOALS, MASK, renderer=r, tau=t, rendered=shared, **kw)
            for t in (0.4, 0.7, 1.0)
        ]

    res["taus_alone_s"] = _best(lambda: taus_clips("alone", False), repeats)["wall_s"]
    res["taus_shared_s"] = _best(lambda: taus_clips("shared", True), repeats)["wall_s"]
    for a, b in zip(clip["alone"], clip["shared"], strict=True):
        assert np.array_equal(a, b), "the shared frames differ from the clips drawn alone"
    r.close()
    return res


@cli.command
def main(argv=None) -> int:
    p = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.render", description=__doc__)
    p.add_argument("--size", default="640x360", help="frame size WxH")
    p.add_argument("--frames", type=int, default=100, help="frames of the clip")
    p.add_argument("--repeats", type=int, default=3, help="best of this many runs")
    p.add_argument("--json", type=Path, help="also write the results here")
    args = p.parse_args(argv)
    if args.json:  # checked before the benchmark; the file is regenerated
        fileio.check_output_files(args.json.parent, [args.json.name], what="--json")
    size = parse_size(args.size)
    if args.frames < 2 or args.repeats < 1:
        raise cli.InputError("--frames >= 2 and --repeats >= 1 expected")
    load0 = os.getloadavg()
    res = run(size, args.frames, args.repeats)
    res.update(
        date=datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        machine=f"{cpu_model()}, {os.cpu_count()} cores, {platform.system()}",
        versions=f"Python {platform.python_version()}, mujoco {mujoco.__version__}, "
        f"PyAV {av.__version__} (FFmpeg libx264), NumPy {np.__version__}",
        mujoco_gl=os.environ.get("MUJOCO_GL", ""),
        load_before=[round(v, 2) for v in load0],
        load_after=[round(v, 2) for v in os.getloadavg()],
    )
    w, h = size
    n = args.frames
    rows = [
        ("MotionRenderer.frame, shadows off, frames/s", f"{res['frame_fps_shadows_off']:.1f}"),
        ("MotionRenderer.frame, shadows on, frames/s", f"{res['frame_fps_shadows_on']:.1f}"),
        ("naive: new mujoco.Renderer per frame, frames/s", f"{res['naive_fps']:.2f}"),
        (f"motion_frames, {n} frames (trace, labels), s", f"{res['clip_frames_s']:.2f}"),
        (f"motion_frames, {n} frames, no trace or labels, s", f"{res['clip_bare_s']:.2f}"),
        (f"encode {n} frames to MP4 (H.264), s", f"{res['encode_mp4_s']:.2f}"),
        (f"encode {n} frames to GIF, s", f"{res['encode_gif_s']:.2f}"),
        (f"{n}-frame MP4, render + encode + write, s", f"{res['mp4_total_s']:.2f}"),
        ("clips at τ = 0.4, 0.7, 1, each drawn alone, s", f"{res['taus_alone_s']:.2f}"),
        ("the same, each moment drawn once (study stimuli), s", f"{res['taus_shared_s']:.2f}"),
    ]
    print(f"# render benchmark, {w}x{h}, {res['date']}")
    print(f"# {res['machine']}; {res['versions']}")
    print(f"# MUJOCO_GL={res['mujoco_gl']}; OpenGL: {res['gl_renderer']}")
    print(f"# load average before {res['load_before']}, after {res['load_after']}")
    print("| measure | value |\n|---|---|")
    for k, v in rows:
        print(f"| {k} | {v} |")
    fps = res["frame_fps_shadows_off"]
    print(
        f"reused renderer vs new renderer per frame: {fps / res['naive_fps']:.0f}x;"
        f" shadows cost {res['frame_fps_shadows_off'] / res['frame_fps_shadows_on']:.1f}x;"
        f" encoding is {res['encode_mp4_s'] / res['mp4_total_s']:.0%} of the MP4's time;"
        f" {1e3 / fps:.1f} ms per frame; one motion's three clips"
        f" {res['taus_alone_s'] / res['taus_shared_s']:.1f}x faster drawing each moment once"
    )
    if args.json:
        fileio.write_text(args.json, json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
