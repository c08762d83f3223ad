"""Rendering (slotv_jax.render) on the CPU through EGL (MUJOCO_GL=egl, set in conftest).

What is drawn is checked against the numbers it came from: the TCP of MJX kinematics,
projected through the MJX camera, lands on the pixel where MuJoCo draws the gripper; a
clip cut at τ ends on the full clip's frame at τ; videos decode to the frames written.
"""

from __future__ import annotations

import subprocess
import sys

import av
import mujoco
import numpy as np
import pytest
from PIL import Image, ImageDraw

from slotv_jax import render
from slotv_jax.core import opengl
from slotv_jax.rendering import backend, compare, overlay, writers
from slotv_jax.rendering import frames as frames_lib
from slotv_jax.robot import kinematics
from slotv_jax.world import scene

SIZE = (160, 96)  # small frames keep the software rasteriser fast
PIXEL_TOL = 1.0  # pixels: marker centroid vs. projected TCP
Q_A = np.array([0.3, -0.2, 0.1, -2.0, 0.05, 1.9, 0.7])  # a reachable pose over the goal table
GOALS = np.zeros((8, 3), np.float32)
GOALS[:3] = [[0.45, -0.25, 0.025], [0.55, 0.0, 0.025], [0.40, 0.25, 0.025]]
MASK = np.arange(8) < 3


def _path(n=12):
    """A joint path from Q_HOME to Q_A."""
    a = np.linspace(0, 1, n)[:, None]
    return (1 - a) * kinematics.Q_HOME + a * Q_A


@pytest.fixture(scope="module")
def renderer():
    with render.MotionRenderer(SIZE) as r:
        yield r


@pytest.fixture(scope="module")
def mjx_ref():
    """MJX kinematics of the scene model at Q_A (one compiled call): the TCP and the
    three cameras, as slotv_jax.scene.Camera (the reference rendering.camera is checked on)."""
    m = kinematics.mj_model(kinematics.SCENE_XML)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, kinematics.TCP_SITE)

    def fk(mx, q):
        d = kinematics.mjx.kinematics(mx, kinematics.mjx.make_data(mx).replace(qpos=q))
        d = kinematics.mjx.camlight(mx, d)
        return d.site_xpos[site], d.cam_xpos, d.cam_xmat

    tcp, pos, mat = kinematics.host_eval(fk, m, np.asarray(Q_A, np.float32))
    cams = {
        n: scene.Camera(
            pos=pos[i], rot=mat[i].reshape(3, 3), fovy=m.cam_fovy[i], resolution=np.zeros(2)
        )
        for i, n in enumerate(render.CAMERAS)
    }
    return np.asarray(tcp, np.float64), cams


def _mjx_pixel(point, cam, size):
    """Pixel of a world point through an MJX-posed camera (independent of rendering.camera)."""
    uv, _ = scene.project(np.asarray(point, np.float64), cam)
    w, h = size
    f = (h / 2) / np.tan(np.deg2rad(float(cam.fovy)) / 2)
    return np.array([w / 2 + f * float(uv[0]), h / 2 - f * float(uv[1])])


def _centroid(mask):
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean() + 0.5, ys.mean() + 0.5])


@pytest.mark.parametrize("camera", ["observer", "observer_side"])
def test_tcp_projects_onto_the_drawn_gripper(mjx_ref, camera):
    """A marker sphere drawn at the TCP has its centroid within a pixel of the MJX TCP
    projected through the MJX camera, and that pixel lies between the gripper's fingers."""
    size = (640, 360)
    tcp, cams = mjx_ref
    with render.MotionRenderer(size) as r:
        q = Q_A
        seg = r.frame(q, camera, segmentation=True)
        robot = r.model.geom_bodyid > 0
        robot &= r.model.body_mocapid[r.model.geom_bodyid] < 0
        r.model.geom_group[robot] = 3  # hidden (MjvOption shows groups 0-2): no occlusion
        plain = r.frame(q, camera).astype(int)
        marked = r.frame(q, camera, markers=[(tcp, 0.006, (1, 0, 1, 1))]).astype(int)
    changed = np.abs(marked - plain).sum(-1) > 30
    assert changed.sum() > 10  # the marker is visible
    want = _mjx_pixel(tcp, cams[camera], size)
    np.testing.assert_allclose(_centroid(changed), want, atol=PIXEL_TOL)
    # render.pixels (MuJoCo C camera) agrees with the MJX camera
    got, depth = render.pixels(tcp[None], camera, size)
    np.testing.assert_allclose(got[0], want, atol=0.05)
    assert depth[0] > 0
    # the finger geoms (the two small boxes of the hand) are drawn around the TCP's pixel
    m = r.model
    hand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "hand")
    drawn = kinematics.mj_model(kinematics.SCENE_XML).geom_group < 3  # not collision shapes
    fingers = [g for g in range(m.ngeom)
               if m.geom_bodyid[g] == hand and drawn[g] and m.geom_size[g, 0] < 0.015]  # fmt: skip
    assert len(fingers) == 2
    is_finger = (seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM) & np.isin(seg[..., 0], fingers)
    ys, xs = np.nonzero(is_finger)
    assert xs.min() - 1 <= want[0] <= xs.max() + 2 and ys.min() - 1 <= want[1] <= ys.max() + 2
    d = np.hypot(xs + 0.5 - want[0], ys + 0.5 - want[1])
    assert d.min() < 12.0  # 2 cm (half the finger gap) at 1.2 m is about 8 px


def test_free_camera_projection_matches_the_drawn_marker(renderer, mjx_ref):
    cam = render.FreeCamera(lookat=(0.4, 0.1, 0.2), distance=1.4, azimuth=150.0, elevation=-25.0)
    tcp, _ = mjx_ref
    marker = [(tcp, 0.012, (1, 0, 1, 1))]
    shown = renderer.model.geom_group.copy()
    robot = (renderer.model.geom_bodyid > 0) & (
        renderer.model.body_mocapid[renderer.model.geom_bodyid] < 0
    )
    renderer.model.geom_group[robot] = 3  # hidden: the marker is seen whole
    try:
        plain = renderer.frame(Q_A, cam).astype(int)
        marked = renderer.frame(Q_A, cam, markers=marker).astype(int)
    finally:
        renderer.model.geom_group[:] = shown
    changed = np.abs(marked - plain).sum(-1) > 30
    assert changed.sum() > 4
    got, _ = render.pixels(tcp[None], cam, SIZE)
    np.testing.assert_allclose(_centroid(changed), got[0], atol=PIXEL_TOL)


def test_frame_times_by_hand():
    s = render.frame_times(0.5, fps=4, duration=2, hold=0.5)
    np.testing.assert_array_equal(s, [0, 0.125, 0.25, 0.375, 0.5, 0.5, 0.5])
    s = render.frame_times(0.3, fps=10, duration=1, hold=0)  # 0.3 * 10 = 3 frames after 0
    np.testing.assert_allclose(s, [0, 0.1, 0.2, 0.3])
    s = render.frame_times(0.33, fps=10, duration=1, hold=0)  # the last frame at τ itself
    np.testing.assert_allclose(s, [0, 0.1, 0.2, 0.3, 0.33])


def test_tau_cut_ends_on_the_full_clips_frame(renderer):
    q = _path()
    kw = {"size": SIZE, "fps": 10, "duration": 1.0, "hold": 0.3, "renderer": renderer}
    full = render.motion_frames(q, GOALS, MASK, tau=1.0, target=1, **kw)
    cut = render.motion_frames(q, GOALS, MASK, tau=0.5, target=1, **kw)
    assert full.shape == (11 + 3, SIZE[1], SIZE[0], 3)
    assert cut.shape == (6 + 3, SIZE[1], SIZE[0], 3)
    np.testing.assert_array_equal(cut[5], full[5])  # the frame at τ = 0.5
    np.testing.assert_array_equal(cut[5:], np.broadcast_to(full[5], cut[5:].shape))  # held
    assert np.abs(full[10].astype(int) - full[5]).sum() > 0  # the robot moved on after τ
    still = render.still(q, GOALS, MASK, tau=0.5, size=SIZE, target=1, renderer=renderer)
    np.testing.assert_array_equal(still, cut[-1])


def test_one_motion_s_clips_at_several_taus_draw_each_moment_once(renderer, monkeypatch):
    """Frames shared through ``rendered`` (what ``study stimuli`` does for one motion's τs)
    are the frames each clip draws alone, labels and held frames included, and each moment
    (normalised time) is drawn once: 0.33 is off the 10 fps grid, so its last frame is new."""
    q, taus = _path(), (0.33, 0.7, 1.0)
    kw = {"size": SIZE, "fps": 10, "duration": 1.0, "hold": 0.3, "renderer": renderer}
    alone = [render.motion_frames(q, GOALS, MASK, tau=t, **kw) for t in taus]
    drawn = []
    frame = frames_lib.MotionRenderer.frame
    monkeypatch.setattr(frames_lib.MotionRenderer, "frame",
                        lambda self, *a, **k: drawn.append(1) or frame(self, *a, **k))  # fmt: skip
    shared: dict = {}
    for t, ref in zip(taus, alone, strict=True):
        np.testing.assert_array_equal(render.motion_frames(q, GOALS, MASK, tau=t, **kw,
                                                           rendered=shared), ref)  # fmt: skip
    moments = {float(x) for t in taus for x in render.frame_times(t, fps=10, duration=1.0)}
    assert len(drawn) == len(shared) == len(moments) == 12  # 0, 0.1, ..., 1 and 0.33
    with pytest.raises(ValueError, match="rendered"):
        frames_lib.clips(renderer, [(q, None)] * 2, GOALS, MASK, np.zeros(2), "observer",
                         rendered={})  # fmt: skip


def test_labels_stand_above_their_cubes(renderer, mjx_ref):
    names = ["A", "Bo", "C"]
    layer = overlay.label_layer(SIZE, GOALS, MASK, names, "observer")
    anchor = GOALS[:3] + np.array([0, 0, overlay.LABEL_LIFT])
    xy = np.stack([_mjx_pixel(p, mjx_ref[1]["observer"], SIZE) for p in anchor])
    opaque = layer[..., 3] > 200
    for x, y in xy:  # every label box covers its projected anchor
        assert opaque[int(y), int(x)]
    assert not opaque[: int(xy[:, 1].min()) - 15].any()  # nothing far above the labels
    f = render.motion_frames(
        _path(), GOALS, MASK, size=SIZE, fps=2, duration=1, hold=0, renderer=renderer
    )
    g = render.motion_frames(
        _path(),
        GOALS,
        MASK,
        size=SIZE,
        fps=2,
        duration=1,
        hold=0,
        renderer=renderer,
        show_labels=False,
    )
    differ = np.abs(f[-1].astype(int) - g[-1]).sum(-1) > 0
    assert differ.any() and not (differ & ~(layer[..., 3] > 0)).any()  # labels only where drawn


@pytest.mark.parametrize("suffix", [".mp4", ".gif"])
def test_video_decodes_with_size_and_count(tmp_path, renderer, suffix):
    clip = render.motion_frames(
        _path(), GOALS, MASK, size=SIZE, fps=10, duration=0.8, hold=0.2, renderer=renderer
    )
    out = render.write_video(tmp_path / f"clip{suffix}", clip, fps=10)
    back = render.read_video(out)
    if suffix == ".gif":  # GIF merges repeated frames into one shown longer: expand them
        with Image.open(out) as im:
            ms = [(im.seek(i), im.info["duration"])[1] for i in range(im.n_frames)]
        back = np.repeat(back, np.round(np.asarray(ms) / 100).astype(int), axis=0)
    assert back.shape == clip.shape
    err = np.abs(back.astype(int) - clip).mean()
    assert err < (4.0 if suffix == ".mp4" else 12.0)
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


@pytest.mark.parametrize("size", [(270, 480), (269, 477), (48, 64), (360, 640)])
def test_mp4_is_coded_padded_and_shown_at_its_own_size(tmp_path, size):
    """libx264 reads past the picture's last rows and columns when coding its last
    macroblock, and what lies there differs from process to process: a few study clips'
    bytes (and last macroblocks) differed between runs of the same command. The encoder
    gets the frames padded to a width that is a multiple of 64 and a height that is a
    multiple of 32, and the stream's crop shows them at their own size (an odd one gains
    a repeated edge)."""
    h, w = size
    yy, xx = np.mgrid[:h, :w]
    clip = np.stack([np.stack([(xx * 3 + 7 * i) % 256, (yy * 2) % 256,
                               np.full_like(xx, 40 * i)], -1) for i in range(4)])  # fmt: skip
    clip = clip.astype(np.uint8)
    path = writers.write_video(tmp_path / "c.mp4", clip, fps=10)
    with av.open(str(path)) as c:
        stream = c.streams.video[0]
        first = next(iter(c.decode(stream)))
        coded = (stream.codec_context.coded_height, stream.codec_context.coded_width)
    shown = (h + h % 2, w + w % 2)
    assert (first.height, first.width) == shown
    assert coded[0] % writers.CODED_HEIGHT == 0 and coded[1] % writers.CODED_WIDTH == 0, coded
    back = writers.read_video(path).astype(int)
    assert back.shape == (4, *shown, 3)
    assert np.abs(back[:, :h, :w] - clip).mean() < 4.0  # the picture, not the padding


def test_png_and_contact_sheet(tmp_path, renderer):
    clip = render.motion_frames(
        _path(), GOALS, MASK, size=SIZE, fps=5, duration=1, hold=0, renderer=renderer
    )
    sheet = render.contact_sheet(clip, n=4, cols=2, pad=3)
    h, w = SIZE[1], SIZE[0]
    assert sheet.shape == (2 * h + 3 * 3, 2 * w + 3 * 3, 3)
    np.testing.assert_array_equal(sheet[3 : 3 + h, 3 : 3 + w], clip[0])
    np.testing.assert_array_equal(sheet[6 + h : 6 + 2 * h, 6 + w : 6 + 2 * w], clip[-1])
    render.write_png(tmp_path / "s.png", sheet)
    np.testing.assert_array_equal(render.read_video(tmp_path / "s.png")[0], sheet)


def _no_rendering(monkeypatch):
    def boom(*a, **k):
        raise AssertionError("rendering started before the input was checked")

    monkeypatch.setattr(frames_lib.MotionRenderer, "__init__", boom)


@pytest.mark.parametrize(
    ("change", "name"),
    [
        ({"q": np.where(np.arange(7) == 2, np.nan, _path())}, "q"),
        ({"q": _path()[:, :6]}, "q"),
        ({"camera": "ceiling"}, "camera"),
        ({"tau": 0.0}, "tau"),
        ({"tau": 1.2}, "tau"),
        ({"tau": float("nan")}, "tau"),
        ({"size": (8, 8)}, "size"),
        ({"labels": ["A", "B"]}, "labels"),
        ({"target": 5}, "target"),
        ({"goal_mask": np.zeros(8, bool)}, "goal_mask"),
    ],
)
def test_bad_input_is_named_before_rendering(monkeypatch, change, name):
    _no_rendering(monkeypatch)
    kw = {"q": _path(), "goals": GOALS, "goal_mask": MASK, **change}
    with pytest.raises(ValueError, match=rf"^{name}:"):
        render.motion_frames(kw.pop("q"), kw.pop("goals"), kw.pop("goal_mask"), **kw)


def test_unwritable_output_is_named(tmp_path):
    with pytest.raises(ValueError, match=r"^--out .*a.avi: expected a file ending in .mp4"):
        writers.check_output(tmp_path / "a.avi")
    (tmp_path / "d.mp4").mkdir()
    with pytest.raises(ValueError, match=r"^--out .*d.mp4: is a directory"):
        writers.check_output(tmp_path / "d.mp4")
    (tmp_path / "f").write_text("")
    with pytest.raises(ValueError, match=r"^--out .*is a file, not a directory"):
        writers.check_output(tmp_path / "f" / "a.mp4")
    (tmp_path / "old.gif").write_text("")
    with pytest.raises(ValueError, match=r"^--out .*old.gif: the file exists"):
        writers.check_output(tmp_path / "old.gif")
    writers.check_output(tmp_path / "old.gif", overwrite=True)
    with pytest.raises(ValueError, match=r"^--out .*cannot write in /proc"):
        writers.check_output("/proc/a.mp4")


def test_missing_gl_backend_is_explained(monkeypatch):
    def no_gl(*a, **k):
        raise ImportError("Cannot find libEGL")

    monkeypatch.setattr(mujoco, "Renderer", no_gl)
    with pytest.raises(render.RenderBackendError, match=r"MUJOCO_GL.*libegl1 libgl1-mesa-dri"):
        render.MotionRenderer(SIZE)


def test_choose_mujoco_gl_egl_where_it_loads_else_disable(monkeypatch):
    """Headless and unset: egl where an EGL library loads, disable (MuJoCo loads no OpenGL)
    where none does; a display, the user's own value or an imported MuJoCo: unchanged."""
    monkeypatch.delitem(sys.modules, "mujoco")  # as before MuJoCo's first import
    monkeypatch.setattr(opengl, "egl_library", lambda: "libEGL.so.1")
    assert opengl.choose_mujoco_gl(env := {}) == "egl" and env == {"MUJOCO_GL": "egl"}
    assert opengl.choose_mujoco_gl(env := {"DISPLAY": ":0"}) is None and "MUJOCO_GL" not in env
    monkeypatch.setattr(opengl, "egl_library", lambda: None)
    assert opengl.choose_mujoco_gl({}) == "disable"
    assert opengl.choose_mujoco_gl({"MUJOCO_GL": "egl"}) == "egl"  # the user's choice
    monkeypatch.setitem(sys.modules, "mujoco", mujoco)
    assert opengl.choose_mujoco_gl(env := {}) is None and env == {}  # too late to choose


@pytest.mark.parametrize("gl", ["egl", "disable"])
def test_no_egl_library_is_one_line_before_any_context(monkeypatch, gl):
    """Headless with no EGL library: the renderer refuses before MuJoCo opens a context, and
    a backend failure is explained as the missing library, in one line."""
    for k in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("MUJOCO_GL", gl)
    monkeypatch.setattr(opengl, "egl_library", lambda: None)
    monkeypatch.setattr(mujoco, "Renderer", None)  # must not be reached
    with pytest.raises(render.RenderBackendError) as e:
        render.MotionRenderer(SIZE)
    text = str(e.value)
    assert text.startswith("cannot render: ") and "\n" not in text
    assert "libEGL.so.1" in text and "apt-get install libegl1 libgl1-mesa-dri" in text
    err = AttributeError("'NoneType' object has no attribute 'eglQueryString'")
    assert backend.backend_message(err) == text
    monkeypatch.setattr(opengl, "egl_library", lambda: "libEGL.so.1")  # EGL there: no verdict
    backend.check_backend()
    assert "MUJOCO_GL=" + gl in backend.backend_message(err)


def test_the_library_never_imports_the_renderer():
    """Nor PyAV: a GPU server without the video stack fits, picks and plans (the answers'
    pool once reached the renderer for its camera names, and the loop failed to import)."""
    code = (
        "import sys, slotv_jax, slotv_jax.data, slotv_jax.planning, slotv_jax.answers, "
        "slotv_jax.study, slotv_jax.experiments.people_loop; "
        "print(any(m.startswith('slotv_jax.render') or m == 'av' for m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_compare_layouts(renderer):
    """Side by side: each panel is that motion's own clip under a title; overlay of two
    copies of one motion (one colour) is that motion's clip under a legend."""
    q1, q2 = _path(), _path()[::-1].copy()
    kw = {"size": SIZE, "fps": 4, "duration": 1, "hold": 0, "renderer": renderer}
    c = compare.PALETTE
    side = render.compare_frames([q1, q2], GOALS, MASK, names=["a", "b"], **kw)
    h, w = SIZE[1], SIZE[0]
    bar = side.shape[1] - h
    assert side.shape == (5, bar + h, 2 * w + compare.GAP, 3)
    for q, x, rgba in ((q1, 0, c[0]), (q2, w + compare.GAP, c[1])):
        own = render.motion_frames(q, GOALS, MASK, trace_rgba=rgba, **kw)
        np.testing.assert_array_equal(side[:, bar:, x : x + w], own)
    over = render.compare_frames(
        [q1, q1], GOALS, MASK, names=["a", "b"], rgbas=[c[2], c[2]], layout="overlay", **kw
    )
    own = render.motion_frames(q1, GOALS, MASK, trace_rgba=c[2], **kw)
    np.testing.assert_array_equal(over[:, -h:], own)
    with pytest.raises(ValueError, match=r"^layout:"):
        render.compare_frames([q1], GOALS, MASK, layout="grid", **kw)


def _text_mask(img: np.ndarray) -> np.ndarray:
    """Text pixels of a label (RGB) or of a reference (grey), cropped to their bounding box:
    darker than half-way between the ink (the darkest pixel) and the paper (the median; a
    label's box lets a little of the scene through)."""
    g = (img if img.ndim == 2 else img.max(-1)).astype(float)
    dark = g < (g.min() + np.median(g)) / 2
    ys, xs = np.nonzero(dark)
    return dark[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]


def _overlap(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two masks aligned at their top-left corners."""
    h, w = max(a.shape[0], b.shape[0]), max(a.shape[1], b.shape[1])
    pa, pb = np.zeros((h, w), bool), np.zeros((h, w), bool)
    pa[: a.shape[0], : a.shape[1]], pb[: b.shape[0], : b.shape[1]] = a, b
    return float((pa & pb).sum() / (pa | pb).sum())


def test_each_label_is_drawn_over_its_own_goal(mjx_ref):
    """Goal by goal, with names unlike each other: the label box standing over goal k's
    projected anchor (MJX camera) and over cube k as MuJoCo draws it holds the text of name
    k (Pillow's own drawing of each name is the reference), and no other name matches it as
    well. Names drawn in another order (e.g. reversed) put the wrong text over a cube."""
    from scipy import ndimage

    size = (640, 360)
    names = ["i", "WWW", "Mm"]  # widths and shapes unlike each other
    q = np.stack([kinematics.Q_HOME] * 4)  # the arm stays home, clear of the cubes
    with render.MotionRenderer(size) as r:
        kw = {"size": size, "renderer": r}
        labelled = render.still(q, GOALS, MASK, labels=names, **kw).astype(int)
        bare = render.still(q, GOALS, MASK, show_labels=False, **kw).astype(int)
        r.set_goals(GOALS, MASK)
        seg = r.frame(kinematics.Q_HOME, "observer", segmentation=True)
        cube_geom = {
            int(r.model.body_mocapid[r.model.geom_bodyid[g]]): g
            for g in range(r.model.ngeom)
            if r.model.body_mocapid[r.model.geom_bodyid[g]] >= 0
        }
    boxes, n = ndimage.label(np.abs(labelled - bare).sum(-1) > 0)
    assert n == 3, n  # one box per goal, apart from each other
    fnt = overlay.font(overlay.font_size(size[1]))
    cam = mjx_ref[1]["observer"]
    for k, name in enumerate(names):
        x, y = _mjx_pixel(GOALS[k] + [0, 0, overlay.LABEL_LIFT], cam, size)
        assert boxes[int(y), int(x)] > 0, f"goal {k}: no label over its anchor"
        ys, xs = np.nonzero(boxes == boxes[int(y), int(x)])
        cube = (seg[..., 1] == mujoco.mjtObj.mjOBJ_GEOM) & (seg[..., 0] == cube_geom[k])
        cy, cx = np.nonzero(cube)
        assert cube.sum() > 20, f"cube {k} is not in sight"
        assert xs.min() <= cx.mean() <= xs.max() and ys.mean() < cy.mean(), f"goal {k}"
        refs = []  # each name alone, drawn by Pillow on white at the anchor's sub-pixel offset
        for other in names:
            img = Image.new("L", (200, 60), 255)
            at = (100 + x % 1, 30 + y % 1)
            ImageDraw.Draw(img).text(at, other, font=fnt, fill=0, anchor="mm")
            refs.append(_text_mask(np.asarray(img)))
        crop = labelled[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1].astype(np.uint8)
        inner = crop[3:-3, 3:-3]  # inside the coloured border
        score = [_overlap(_text_mask(inner), ref) for ref in refs]
        assert score[k] > 0.8, (k, name, score)
        assert max(np.delete(score, k)) < 0.5, (k, name, score)
