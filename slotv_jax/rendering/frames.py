"""Frames of a motion: the Panda in its scene, drawn by MuJoCo's ``mujoco.Renderer``.

One motion is a joint path ``q (T, 7)`` (rad) at normalised times ``t_i = i / (T − 1)``
(or given times), in a scene of up to 8 goals. The goals stand on the cube mocap bodies
of ``franka_assets/scene.xml`` (unused cubes are moved out of sight, 10 m below the
floor). A clip of ``duration`` seconds at ``fps`` frames per second shows normalised time
``s ∈ [0, τ]``:

    s_k = min(k / (fps · duration), τ),   k = 0, …, ⌈τ · fps · duration⌉

then holds its last frame for ``round(hold · fps)`` more frames, as a legibility study
shows a motion stopped at τ (Dragan & Srinivasa 2013). Between the path's samples the
joints are interpolated linearly, so the clip is resampled in time, not frame-skipped.
The frame at ``s_k`` is the same whatever τ: a clip cut at τ ends on the full clip's
frame at τ when ``τ · fps · duration`` is a whole number.

Drawn into MuJoCo's scene (``MjvScene`` user geoms): the TCP trace up to ``s`` (the tool
centre point's path, GL lines 3 px wide at 360 rows) and, optionally, a disc under the
target cube.
Drawn onto the pixels afterwards (:mod:`slotv_jax.rendering.overlay`): goal labels.

Opening a renderer needs OpenGL; :class:`RenderBackendError` says what to install when
none can be opened. Nothing else in this module needs it.

>>> frames = motion_frames(q, goals, goal_mask, tau=0.5, size=(320, 180))  # doctest: +SKIP
>>> frames.shape  # 46 frames of motion (0 ... 0.5 of 3 s at 30 fps) + 30 held  # doctest: +SKIP
(76, 180, 320, 3)
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Sequence

import jax
import mujoco
import numpy as np
from jaxtyping import Bool, Float, UInt8

from slotv_jax.core import validation
from slotv_jax.core.validation import G_MAX
from slotv_jax.rendering.backend import RenderBackendError, backend_message, check_backend
from slotv_jax.rendering.camera import View, check_view, scene_model, view_camera
from slotv_jax.rendering.overlay import draw_goal_labels
from slotv_jax.robot import kinematics
from slotv_jax.world import scene

MAX_SIDE = 4096  # largest frame width or height (pixels)
# The bounds of one clip (check_clip), generous for real use and far below what exhausts a
# machine: every frame of a clip is held in memory as uint8 before it is encoded.
MAX_FPS = 240.0  # frames per second: the fastest common displays; more only adds frames
MAX_CLIP_FRAMES = 18_000  # 10 minutes at 30 fps (a study's clip lasts seconds)
# 4 GiB of frames (side by side: every panel's): 3.5 minutes of 640x360 at 30 fps, 23 s of
# 1920x1080. The peak can be a few times that (panels side by side are copied into one
# array, a GIF copies its frames): still within the project's 23 GB machine.
MAX_CLIP_BYTES = 4 * 2**30
CLIP_BOUNDS = (  # the bounds in words, for the commands' --help
    f"A clip has at most {MAX_CLIP_FRAMES} frames (the motion and --hold: 10 minutes at 30 "
    f"fps), --fps at most {MAX_FPS:g}, and at most {MAX_CLIP_BYTES / 2**30:g} GiB of frames "
    "(W x H x 3 bytes a frame, each panel's side by side): every frame is held in memory "
    "before it is encoded."
)
HIDDEN_Z = -10.0  # height (m) that unused cubes are moved to: below the floor, out of sight
TRACE_PX = 3.0  # width (pixels) of the TCP trace's lines in a 360-pixel-high frame (scaled)
TRACE_RGBA = (0.05, 0.05, 0.05, 1.0)  # the trace's colour (a dark line reads on every surface)
TARGET_RGBA = (1.0, 1.0, 1.0, 0.9)  # the disc under the target cube
TARGET_DISC = (0.045, 0.001)  # its radius and half-height (m)


# ----------------------------------------------------------------- time and inputs


def frame_times(
    tau: float = 1.0, *, fps: float = 30.0, duration: float = 3.0, hold: float = 1.0
) -> Float[np.ndarray, " F"]:
    """Normalised motion time of every frame of a clip cut at τ (see the module docstring).

    >>> frame_times(0.5, fps=4, duration=2, hold=0.5).tolist()
    [0.0, 0.125, 0.25, 0.375, 0.5, 0.5, 0.5]
    """
    check_timing(tau, fps, duration, hold)
    moving, held = _frame_counts(tau, fps, duration, hold)
    s = np.minimum(np.arange(moving) / (fps * duration), tau)
    return np.concatenate([s, np.full(held, tau)])


def _frame_counts(tau, fps, duration, hold) -> tuple[int, int]:
    """The frames of a clip's motion (0 … τ) and its held frames (:func:`frame_times`)."""
    return math.ceil(tau * fps * duration - 1e-9) + 1, round(hold * fps)


def check_clip(
    size: tuple[int, int],
    *,
    fps: float,
    duration: float | None,
    hold: float,
    tau: float = 1.0,
    panels: int = 1,
    prefix: str = "",
) -> int:
    """The number of frames of a clip (:func:`frame_times`), checked against the bounds
    before any of them is made: ``fps`` at most :data:`MAX_FPS`, at most
    :data:`MAX_CLIP_FRAMES` frames (motion and hold), and the frames' bytes
    (``panels · W · H · 3`` each, ``size = (W, H)`` one panel's) at most
    :data:`MAX_CLIP_BYTES`. ``duration`` None: a clip whose length is not known yet (a
    motion at the robot's speed), its held frames checked. ValueError naming the argument
    (``prefix`` + its name: ``"--"`` for a command's flags) otherwise.

    >>> check_clip((640, 360), fps=30, duration=3, hold=1)
    121
    """
    check_timing(tau, fps, 1.0 if duration is None else duration, hold)
    w, h = check_size(size)
    p = prefix
    if fps > MAX_FPS:
        raise ValueError(f"{p}fps {fps:g}: expected frames per second in (0, {MAX_FPS:g}]")
    moving, held = _frame_counts(tau, fps, 0.0 if duration is None else duration, hold)
    n = moving + held
    if n > MAX_CLIP_FRAMES:  # named: whichever of the motion and the hold has more frames
        limit = f"expected at most {MAX_CLIP_FRAMES} (10 minutes at 30 fps)"
        if duration is None or held > moving:
            raise ValueError(
                f"{p}hold {hold:g}: a clip of {n} frames ({held} of them held) at {fps:g} "
                f"fps, {limit}"
            )
        raise ValueError(
            f"{p}duration {duration:g}: a clip of {n} frames at {fps:g} fps (with {hold:g} s "
            f"held), {limit}"
        )
    nbytes = n * panels * w * h * 3
    if nbytes > MAX_CLIP_BYTES:
        of = f" of {panels} panels" if panels > 1 else ""
        raise ValueError(
            f"{p}size {w}x{h}: {n} frames{of} take {nbytes / 2**30:.1f} GiB, expected at most "
            f"{MAX_CLIP_BYTES / 2**30:g} GiB of frames: a smaller {p}size, or fewer frames "
            f"({p}duration, {p}fps, {p}hold)"
        )
    return n


def check_timing(tau, fps, duration, hold) -> None:
    """τ in (0, 1], fps and duration > 0, hold ≥ 0 (ValueError naming the argument)."""
    if not (isinstance(tau, int | float | np.floating) and 0.0 < tau <= 1.0):
        raise ValueError(f"tau: expected a normalised time in (0, 1], got {tau!r}")
    validation.check_positive("fps", fps)
    validation.check_positive("duration", duration)
    if not (np.isfinite(hold) and hold >= 0):
        raise ValueError(f"hold: expected seconds >= 0, got {hold!r}")


def check_size(size) -> tuple[int, int]:
    """``size = (width, height)`` in pixels, each in [16, MAX_SIDE]."""
    try:
        w, h = (int(v) for v in size)
        ok = (w, h) == tuple(size) and 16 <= w <= MAX_SIDE and 16 <= h <= MAX_SIDE
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise ValueError(f"size: expected (width, height) in 16..{MAX_SIDE} pixels, got {size!r}")
    return w, h


def check_motion(q, goals, goal_mask, *, t=None, target=None, labels=None) -> None:
    """Boundary checks of one motion (ValueError naming the argument)."""
    validation.check_array("q", q, (None, kinematics.NQ))
    if np.shape(q)[0] < 2:
        raise ValueError(f"q: expected at least 2 configurations, got {np.shape(q)[0]}")
    validation.check_goals("goals", goals, goal_mask)
    n_goals = int(np.asarray(goal_mask, bool).sum())
    if t is not None:
        validation.check_array("t", t, (np.shape(q)[0],))
        if np.any(np.diff(np.asarray(t, np.float64)) <= 0):
            raise ValueError("t: expected strictly increasing times")
    if target is not None and not (
        isinstance(target, int | np.integer) and 0 <= target < G_MAX and goal_mask[target]
    ):
        raise ValueError(
            f"target: expected the slot of a real goal (0..{n_goals - 1}), got {target!r}"
        )
    if labels is not None:
        if isinstance(labels, str) or len(labels) != n_goals:
            raise ValueError(
                f"labels: expected {n_goals} strings (one per real goal), got {labels!r}"
            )
        if not all(isinstance(s, str) for s in labels):
            raise ValueError(f"labels: expected strings, got {labels!r}")


def goal_labels(goal_mask) -> list[str]:
    """The default goal labels: A, B, C, … for the real goal slots."""
    return [chr(ord("A") + k) for k in range(int(np.asarray(goal_mask, bool).sum()))]


def resample(
    q: Float[np.ndarray, "T 7"], s: Float[np.ndarray, " F"], t=None
) -> Float[np.ndarray, "F 7"]:
    """Joint configurations at normalised times ``s`` (linear between samples).

    ``t`` (T,) are the samples' times in any unit (default ``i / (T − 1)``); they are
    normalised to [0, 1] first.
    """
    q = np.asarray(q, np.float64)
    tn = normalised_times(t, q.shape[0])
    return np.stack([np.interp(s, tn, q[:, j]) for j in range(q.shape[1])], axis=1)


def joints_from_tcp(xyz: Float[np.ndarray, "T 3"]) -> tuple[np.ndarray, float]:
    """A joint path (T, 7) for a TCP path (m), by the project's warm-started IK from
    ``Q_HOME`` (:func:`slotv_jax.kinematics.solve_path_ik`), and its worst miss (m)."""
    validation.check_array("xyz", xyz, (None, 3))
    res = jax.jit(kinematics.solve_path_ik)(np.asarray(xyz, np.float32))
    return np.asarray(res.q, np.float64), float(np.max(res.residual))


# ----------------------------------------------------------------------- renderer


@dataclasses.dataclass(frozen=True)
class Trace:
    """A TCP path drawn into the scene up to the current time."""

    xyz: np.ndarray  # (T, 3) TCP positions (m)
    s: np.ndarray  # (T,) their normalised times
    rgba: tuple[float, float, float, float] = TRACE_RGBA


class MotionRenderer:
    """One offscreen MuJoCo renderer of the scene at one frame size, reused across motions.

    ``MotionRenderer((640, 360), shadows=False)`` opens the OpenGL context (or raises
    :class:`RenderBackendError`); :meth:`frame` draws one pose.
    """

    def __init__(self, size: tuple[int, int] = (640, 360), *, shadows: bool = False):
        w, h = check_size(size)
        self.size = (w, h)
        model = scene_model().__copy__()
        model.vis.global_.offwidth = max(w, model.vis.global_.offwidth)
        model.vis.global_.offheight = max(h, model.vis.global_.offheight)
        self.model = model
        self.data = mujoco.MjData(model)
        check_backend()
        try:
            self._r = mujoco.Renderer(model, height=h, width=w)
        except Exception as e:  # the GL backends raise ImportError, RuntimeError, FatalError...
            raise RenderBackendError(backend_message(e)) from e
        self.shadows = bool(shadows)
        self._site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, kinematics.TCP_SITE)
        self._free = mujoco.MjvCamera()
        self._opt = mujoco.MjvOption()
        self._opt.sitegroup[:] = 0  # the TCP site's red dot stays hidden

    def close(self) -> None:
        """Release the OpenGL context."""
        self._r.close()

    def __enter__(self) -> MotionRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def set_goals(self, goals: Float[np.ndarray, "8 3"], goal_mask: Bool[np.ndarray, "8"]) -> None:
        """Put real goals on cubes 0..n−1 and move the other cubes out of sight."""
        m = np.asarray(goal_mask, bool)
        pos = np.zeros((self.model.nmocap, 3))
        pos[:, 2] = HIDDEN_Z
        pos[:G_MAX][m] = np.asarray(goals, np.float64)[m]
        self.data.mocap_pos[:] = pos

    def pose(self, q: Float[np.ndarray, "7"]) -> np.ndarray:
        """Set the joints and run the kinematics; returns the TCP position (m)."""
        self.data.qpos[:] = q
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_camlight(self.model, self.data)
        return self.data.site_xpos[self._site].copy()

    def tcp_path(self, q: Float[np.ndarray, "T 7"]) -> Float[np.ndarray, "T 3"]:
        """TCP positions of a joint path (MuJoCo C forward kinematics)."""
        return np.stack([self.pose(qi) for qi in np.asarray(q, np.float64)])

    def _update(self, camera: View) -> None:
        check_view(camera)
        if scene.is_camera_file(camera):
            self._r.update_scene(self.data, "observer", self._opt)
            _pose_gl_camera(self._r.scene, view_camera(camera))
        elif isinstance(camera, str):
            self._r.update_scene(self.data, camera, self._opt)
        else:
            c = self._free
            c.type = mujoco.mjtCamera.mjCAMERA_FREE
            c.lookat[:] = camera.lookat
            c.distance, c.azimuth, c.elevation = camera.distance, camera.azimuth, camera.elevation
            self._r.update_scene(self.data, c, self._opt)
        self._r.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self.shadows

    def frame(
        self,
        q: Float[np.ndarray, "7"],
        camera: View = "observer",
        *,
        traces: Sequence[tuple[Trace, float]] = (),
        target_pos: np.ndarray | None = None,
        markers: Sequence[tuple[np.ndarray, float, tuple]] = (),
        segmentation: bool = False,
    ) -> np.ndarray:
        """One image of pose ``q``: (H, W, 3) uint8, or with ``segmentation`` (H, W, 2)
        int32 (object id, object type) from MuJoCo's segmentation rendering.

        ``traces``: (trace, s) pairs; each draws its path up to normalised time s.
        ``target_pos``: where to draw the target disc (the target cube's centre).
        ``markers``: (position, radius, rgba) spheres drawn into the scene.
        """
        self.pose(q)
        self._update(camera)
        scn = self._r.scene
        for tr, s in traces:
            _add_trace(scn, tr, s, TRACE_PX * self.size[1] / 360)
        if target_pos is not None:
            p = np.asarray(target_pos, np.float64) + np.array([0.0, 0.0, -0.025 + TARGET_DISC[1]])
            _add_geom(scn, mujoco.mjtGeom.mjGEOM_CYLINDER, [*TARGET_DISC, 0.0], p, TARGET_RGBA)
        for pos, radius, rgba in markers:
            _add_geom(scn, mujoco.mjtGeom.mjGEOM_SPHERE, [radius, 0, 0], pos, rgba)
        if segmentation:
            self._r.enable_segmentation_rendering()
            try:
                return self._r.render().copy()
            finally:
                self._r.disable_segmentation_rendering()
        return self._r.render().copy()


def _pose_gl_camera(scn: mujoco.MjvScene, cam: scene.Camera) -> None:
    """Move the scene's OpenGL cameras (both eyes, at the camera centre: the picture is
    mono) and the headlight to a camera file's pose, and set the vertical field of view:
    frustum half-height ``near · tan(fovy / 2)``, its width from the frame's aspect (as
    ``mjv_updateScene`` sets them for a camera of the model)."""
    pos, rot = np.asarray(cam.pos, np.float64), np.asarray(cam.rot, np.float64)
    for i in range(2):
        c = scn.camera[i]
        c.pos[:], c.forward[:], c.up[:] = pos, -rot[:, 2], rot[:, 1]
        half = c.frustum_near * np.tan(np.deg2rad(float(cam.fovy)) / 2)
        c.frustum_bottom, c.frustum_top, c.frustum_center, c.frustum_width = -half, half, 0, 0
    for i in range(scn.nlight):
        if scn.lights[i].headlight:
            scn.lights[i].pos[:], scn.lights[i].dir[:] = pos, -rot[:, 2]


def _add_geom(scn, kind, size, pos, rgba, mat=None) -> None:
    if scn.ngeom >= scn.maxgeom:
        return
    mat = np.eye(3).ravel() if mat is None else mat
    g = scn.geoms[scn.ngeom]
    mujoco.mjv_initGeom(
        g, kind, np.asarray(size, np.float64), pos, mat, np.asarray(rgba, np.float32)
    )
    scn.ngeom += 1


def _add_trace(scn, tr: Trace, s: float, px: float) -> None:
    """Lines ``px`` pixels wide along the path up to normalised time s (the last one ends
    at the point at s). Lines, not capsules: a capsule chain of 100 points cost 40 % more
    CPU time per frame on Mesa's software rasteriser (1.8 s in a 100-frame clip against
    0.15 s), for a picture that looks the same at these widths."""
    n = int(np.searchsorted(tr.s, s, side="right"))  # samples with time <= s
    pts = list(tr.xyz[:n])
    if n < len(tr.s) and n > 0 and s > tr.s[n - 1]:
        a = (s - tr.s[n - 1]) / (tr.s[n] - tr.s[n - 1])
        pts.append((1 - a) * tr.xyz[n - 1] + a * tr.xyz[n])
    rgba = np.asarray(tr.rgba, np.float32)
    for a, b in itertools.pairwise(pts):
        if scn.ngeom >= scn.maxgeom:
            return
        if np.linalg.norm(b - a) < 1e-6:
            continue
        g = scn.geoms[scn.ngeom]
        mujoco.mjv_initGeom(
            g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).ravel(), rgba
        )
        mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, px, a, b)
        scn.ngeom += 1


# ------------------------------------------------------------------- public API


def motion_frames(
    q: Float[np.ndarray, "T 7"],
    goals: Float[np.ndarray, "8 3"],
    goal_mask: Bool[np.ndarray, "8"],
    *,
    camera: View = "observer",
    tau: float = 1.0,
    size: tuple[int, int] = (640, 360),
    fps: float = 30.0,
    duration: float = 3.0,
    hold: float = 1.0,
    t: Float[np.ndarray, " T"] | None = None,
    labels: Sequence[str] | None = None,
    show_labels: bool = True,
    target: int | None = None,
    trace: bool = True,
    trace_rgba: tuple[float, float, float, float] = TRACE_RGBA,
    shadows: bool = False,
    renderer: MotionRenderer | None = None,
    rendered: dict[float, np.ndarray] | None = None,
) -> UInt8[np.ndarray, "F H W 3"]:
    """The frames of one motion cut at τ, as a participant of a study would see it.

    The clip runs ``duration`` seconds for the whole motion (τ = 1) at ``fps``; it shows
    normalised time 0 … τ and then holds the last frame ``hold`` seconds
    (:func:`frame_times`). ``labels`` name the real goals (default A, B, C, …) and are
    drawn above the cubes (``show_labels=False``: none). ``target`` (a goal slot) draws
    a white disc under that cube; ``trace`` draws the TCP's path so far (in
    ``trace_rgba``). ``renderer``
    reuses an open :class:`MotionRenderer` of the same size (its ``shadows`` setting
    applies); without one, a renderer is opened and closed here. ``rendered`` ({s: frame})
    holds this motion's unlabelled frames already drawn with the same camera, size, times,
    trace and target (the frame at s is the same whatever τ): they are reused, and the
    frames drawn here are added, so that the clips of one motion at several τ draw each
    moment once (:class:`slotv_jax.webstudy.make_stimuli.SceneRenderer`).

    Returns (F, H, W, 3) uint8 frames, ``size = (W, H)``.

    >>> f = motion_frames(q, goals, mask, tau=0.4, fps=10, duration=2, hold=0.5)  # doctest: +SKIP
    >>> f.shape[0]  # 0, 0.05, ..., 0.4 (9 frames) + 5 held  # doctest: +SKIP
    14
    """
    check_motion(q, goals, goal_mask, t=t, target=target, labels=labels)
    check_view(camera)
    size = check_size(size)
    s = frame_times(tau, fps=fps, duration=duration, hold=hold)
    if renderer is not None and renderer.size != size:
        raise ValueError(f"renderer: expected one of size {size}, got {renderer.size}")
    r = renderer if renderer is not None else MotionRenderer(size, shadows=shadows)
    try:
        out = clips(
            r, [(q, t)], goals, goal_mask, s, camera, rgbas=[trace_rgba], target=target,
            trace=trace, rendered=rendered,
        )[0]  # fmt: skip
    finally:
        if renderer is None:
            r.close()
    if show_labels:
        names = goal_labels(goal_mask) if labels is None else list(labels)
        draw_goal_labels(out, goals, goal_mask, names, camera, target=target)
    return out


def normalised_times(t, n: int) -> np.ndarray:
    """Sample times mapped to [0, 1]: ``t`` (any unit) or ``i / (n − 1)`` without it."""
    if t is None:
        return np.linspace(0.0, 1.0, n)
    t = np.asarray(t, np.float64)
    return (t - t[0]) / (t[-1] - t[0])


def clips(
    r: MotionRenderer,
    motions: Sequence[tuple[np.ndarray, np.ndarray | None]],
    goals: np.ndarray,
    goal_mask: np.ndarray,
    s: np.ndarray,
    camera: View,
    *,
    rgbas: Sequence[tuple] | None = None,
    target: int | None = None,
    trace: bool = True,
    overlay: bool = False,
    rendered: dict[float, np.ndarray] | None = None,
) -> list[np.ndarray]:
    """Unlabelled frames (F, H, W, 3) of checked motions ``(q, t)`` at normalised times s.

    One clip per motion, each with its own trace; with ``overlay``, one clip: at every
    time each motion is drawn with every trace and the images are averaged, so the
    scene and the traces stay solid and each robot shows through at 1/n. ``rendered``
    (one motion, no overlay): its frames already drawn, by s; reused and added to.
    """
    if rendered is not None and (overlay or len(motions) != 1):
        raise ValueError("rendered: frames of one motion, without overlay")
    r.set_goals(goals, goal_mask)
    rgbas = [TRACE_RGBA] * len(motions) if rgbas is None else list(rgbas)
    traces = [
        Trace(r.tcp_path(q), normalised_times(t, len(q)), tuple(c))
        for (q, t), c in zip(motions, rgbas, strict=True)
    ]
    qs = [resample(q, s, t) for q, t in motions]
    target_pos = None if target is None else np.asarray(goals, np.float64)[target]
    shape = (len(s), r.size[1], r.size[0], 3)
    out = [np.empty(shape, np.uint8) for _ in range(1 if overlay else len(motions))]
    for k in range(len(s)):
        if k > 0 and s[k] == s[k - 1]:
            for o in out:
                o[k] = o[k - 1]  # held frames are copies
            continue
        shown = [(tr, s[k]) for tr in traces] if trace else []
        if overlay:
            imgs = [r.frame(qi[k], camera, traces=shown, target_pos=target_pos) for qi in qs]
            out[0][k] = np.round(np.mean(imgs, axis=0)).astype(np.uint8)
        elif rendered is not None and float(s[k]) in rendered:
            out[0][k] = rendered[float(s[k])]
        else:
            for i, o in enumerate(out):
                own = [shown[i]] if trace else []
                o[k] = r.frame(qs[i][k], camera, traces=own, target_pos=target_pos)
            if rendered is not None:
                rendered[float(s[k])] = out[0][k].copy()
    return out


def still(
    q: Float[np.ndarray, "T 7"],
    goals: Float[np.ndarray, "8 3"],
    goal_mask: Bool[np.ndarray, "8"],
    *,
    tau: float = 1.0,
    **kw,
) -> UInt8[np.ndarray, "H W 3"]:
    """One picture of the motion at normalised time τ (default: its end), goals labelled.

    The same frame as the last one of ``motion_frames(..., tau=tau)``; keyword arguments
    as there (``fps``, ``duration`` and ``hold`` do not apply).
    """
    for k in ("fps", "duration", "hold"):
        if k in kw:
            raise TypeError(f"still() takes no {k!r}")
    return motion_frames(q, goals, goal_mask, tau=tau, fps=1.0 / tau, duration=1.0, hold=0.0, **kw)[
        -1
    ]
