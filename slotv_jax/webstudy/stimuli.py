"""Stimulus sets: motions stopped at τ, rendered for a legibility study, with a manifest.

A *stimulus* is one motion shown from one camera up to normalised time τ (Dragan et al.,
HRI 2013): a clip that ends at τ (the file holds nothing after τ, so no participant can
scrub past it) and a still of its last frame with the goals labelled, on which the
participant clicks the goal they believe the robot is reaching for.

The study folder and its rounds
-------------------------------
``python -m slotv_jax.study stimuli ... --out STIMDIR`` writes round 0 into ``STIMDIR``;
a later round r (``python -m slotv_jax.study next``) is a complete stimulus set in
``STIMDIR/round-r`` (r = 1, 2, ...). A round exists once its ``manifest.json`` does: the
manifest is written last, atomically, so a half-written round is never seen. The server
(``study serve --stimuli STIMDIR``) looks for new rounds whenever a new participant
starts, without a restart; new participants get trials from the newest round, earlier
participants keep theirs. Trajectory ids are global across rounds (the same id must mean
the same points and goals). A later round is written so (the arrays as for round 0)::

    r, folder = next_round(stimdir)                   # (1, stimdir/round-1), ...
    write_stimulus_set(folder, q=q, xyz=xyz, goals=goals, goal_mask=mask, ids=ids,
                       specs=specs, targets=targets, round_=r,
                       render=make_stimuli.SceneRenderer.like(stimdir))

Beside round 0 lie the files a researcher edits:

- ``consent.html`` and ``instructions.html``: HTML fragments shown before the trials;
- ``study.json``: settings, ``{"title", "trials_per_participant" (null: every
  trajectory), "attention_checks", "confidence" (ask for a 1-5 rating), "completion_code"
  (null: a random code per participant), "completion_url" (null: none)}``.

A stimulus set (one round)
--------------------------
::

    manifest.json        the stimuli (below)
    trajectories.csv     trajectory,t,x,y,z   one row per point, t normalised to [0, 1]
    goals.csv            trajectory,goal,x,y,z   the goals of each trajectory, by label
    clips/ID.mp4         H.264, cut at τ
    stills/ID.png        the clip's last frame, goals labelled

``manifest.json`` holds ``format`` (``"slotv_jax.webstudy.stimuli/1"``), ``round``,
``source`` (where the motions came from), ``size`` [W, H], ``fps``, ``duration`` (seconds
of a whole motion; null with a ``timing``), ``hold`` (seconds the last frame is held),
``timing`` (null: every motion ``duration`` seconds; or the robot whose speed the clips show,
``{"robot", "speed", "limits"}``: each clip as long as its motion, its time stamps the
robot's), ``trajectories`` and ``goals`` (the tables' file names) and ``stimuli``, a list of
objects:

=================  =====================================================================
key                meaning
=================  =====================================================================
``id``             the stimulus id (letters, digits, ``._-``; unique in the round)
``kind``           ``"trial"``, ``"attention"`` (τ = 1, a check) or ``"practice"``
``trajectory``     trajectory id (in ``trajectories.csv``)
``tau``            normalised stop time τ ∈ (0, 1]
``scene``          scene id (trajectories of one scene share their goals)
``camera``         camera name (the answers' ``condition``)
``goals``          the goal labels, in slot order (``goals.csv`` has their positions)
``goal_pixels``    [[x, y], ...]: each goal's label position on the still (pixels)
``target``         the goal the motion reaches (a label; ``null`` when unknown)
``clip``           file of the clip (relative), and ``clip_sha256`` its SHA-256
``still``          file of the still (relative), and ``still_sha256`` its SHA-256
=================  =====================================================================

The tables are in the import format of ``python -m slotv_jax.study import``, so that the
answers exported from the server (``study export``) import unchanged.

>>> specs = cross_specs(range(3), taus=(0.4, 0.7), cameras=("observer",))  # doctest: +SKIP
>>> write_stimulus_set("stim", q=q, xyz=xyz, goals=goals, goal_mask=mask,  # doctest: +SKIP
...                    ids=ids, specs=specs, source={"kind": "split"})
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import io
import json
import re
import shutil
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple, Protocol

import numpy as np
from jaxtyping import Bool, Float, UInt8
from tqdm.auto import tqdm

from slotv_jax.core.fileio import (
    atomic_write,
    check_output_dir,
    replace_dir,
    temp_dir_beside,
    write_text,
)
from slotv_jax.webstudy.design import KINDS
from slotv_jax.world import scene as world_scene

FORMAT = "slotv_jax.webstudy.stimuli/1"
MANIFEST = "manifest.json"
ROUND_DIR = "round-{}"
TABLES = ("trajectories.csv", "goals.csv")  # the tables in the study import format
EDITABLE = ("consent.html", "instructions.html", "study.json")  # a researcher's files
ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,99}$")
SETTINGS = {
    "title": "Which object is the robot reaching for?",
    "trials_per_participant": None,
    "attention_checks": 2,
    "confidence": True,
    "completion_code": None,
    "completion_url": None,
}
CONSENT = """<h1>Consent</h1>
<p>In this study you will watch short videos of a robot arm that starts reaching for one
of several objects. Each video stops part-way; you then choose the object you think the
robot is reaching for. The study takes about 5 minutes. We store your answers, the time
you took, and the participant id of the platform that sent you here; nothing else.
Taking part is voluntary and you may stop at any time.</p>
<p>Edit this text in <code>consent.html</code> of the stimulus folder.</p>
"""
INSTRUCTIONS = """<h1>Instructions</h1>
<p>Each video plays once. When it stops, click the object you think the robot is
reaching for: on the picture or on the buttons below it. Answer as well as you can, even
when you are unsure. The first video is a practice trial.</p>
"""


class StimulusSpec(NamedTuple):
    """One stimulus to render: a motion (index into the arrays), τ, camera and kind."""

    index: int  # row of the trajectory arrays
    tau: float  # normalised stop time in (0, 1]
    camera: str  # camera name
    kind: str = "trial"  # "trial", "attention" or "practice"


@dataclasses.dataclass(frozen=True)
class StimulusSet:
    """A loaded, verified stimulus set (one round)."""

    path: Path  # the round's folder
    manifest: dict  # manifest.json
    trajectories: dict[str, list]  # id -> [[t, x, y, z], ...]
    goals: dict[str, list]  # id -> [[label, x, y, z], ...]

    @property
    def round(self) -> int:
        return int(self.manifest["round"])

    def file(self, stimulus: dict, which: str) -> Path:
        """The verified path of a stimulus' ``clip`` or ``still`` inside the set's folder."""
        return self.path / stimulus[which]


def cross_specs(
    indices: Sequence[int],
    *,
    taus: Sequence[float],
    cameras: Sequence[str],
    attention: Sequence[int] = (),
    practice: Sequence[int] = (),
) -> list[StimulusSpec]:
    """Every trial motion at every τ from every camera, plus checks and practice at τ = 1.

    Attention checks and the practice trial use the first camera.

    >>> [tuple(s) for s in cross_specs([0], taus=[0.5, 1.0], cameras=["c"], practice=[1])]
    [(0, 0.5, 'c', 'trial'), (0, 1.0, 'c', 'trial'), (1, 1.0, 'c', 'practice')]
    """
    specs = [StimulusSpec(i, float(t), c) for i in indices for t in taus for c in cameras]
    specs += [StimulusSpec(i, 1.0, cameras[0], "attention") for i in attention]
    specs += [StimulusSpec(i, 1.0, cameras[0], "practice") for i in practice]
    return specs


def round_dir(stimdir: str | Path, round_: int) -> Path:
    """The folder of round ``round_`` of a study folder (round 0: the folder itself)."""
    return Path(stimdir) if round_ == 0 else Path(stimdir) / ROUND_DIR.format(round_)


def find_rounds(stimdir: str | Path) -> list[int]:
    """The complete rounds (with a manifest) of a study folder, in order."""
    stimdir = Path(stimdir)
    found = [0] if (stimdir / MANIFEST).is_file() else []
    for p in stimdir.glob("round-*"):
        m = re.fullmatch(r"round-([1-9][0-9]{0,5})", p.name)
        if m and (p / MANIFEST).is_file():
            found.append(int(m.group(1)))
    return sorted(found)


def next_round(stimdir: str | Path) -> tuple[int, Path]:
    """The number and folder of the next round of a study folder (for ``study next``)."""
    rounds = find_rounds(stimdir)
    if not rounds:
        raise ValueError(f"--stimuli {stimdir}: no stimulus set ({MANIFEST} missing)")
    r = rounds[-1] + 1
    return r, round_dir(stimdir, r)


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _csv(rows: list[list], header: Sequence[str]) -> bytes:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue().encode()


def trajectory_rows(points: dict[str, list]) -> list[list]:
    """``trajectories.csv`` rows (trajectory, t, x, y, z) of {id: [[t, x, y, z], ...]}."""
    return [[tid, *p] for tid, pts in points.items() for p in pts]


def goal_rows(goals: dict[str, list]) -> list[list]:
    """``goals.csv`` rows (trajectory, goal, x, y, z) of {id: [[label, x, y, z], ...]}."""
    return [[tid, *g] for tid, gs in goals.items() for g in gs]


def write_tables(out: Path, points: dict[str, list], goals: dict[str, list]) -> None:
    """Write ``trajectories.csv`` and ``goals.csv`` (the study import format) into ``out``."""
    atomic_write(out / "trajectories.csv", lambda f: f.write(
        _csv(trajectory_rows(points), ("trajectory", "t", "x", "y", "z"))))  # fmt: skip
    atomic_write(out / "goals.csv", lambda f: f.write(
        _csv(goal_rows(goals), ("trajectory", "goal", "x", "y", "z"))))  # fmt: skip


def _round6(v) -> float:
    return float(f"{float(v):.6g}")


def motion_tables(
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    ids: Sequence[str],
    *,
    length: Sequence[int] | None = None,
    t: Float[np.ndarray, "N T"] | None = None,
) -> tuple[dict[str, list], dict[str, list], list[list[str]]]:
    """Points [[t, x, y, z]] (t normalised to [0, 1]) and goals [[label, x, y, z]] per id.

    Goals are labelled A, B, C, ... in slot order. Returns (points, goals, labels).
    """
    n, tmax = xyz.shape[:2]
    length = np.full(n, tmax) if length is None else np.asarray(length)
    points, goal_tab, labels = {}, {}, []
    for i, tid in enumerate(ids):
        L = int(length[i])
        ti = np.linspace(0.0, 1.0, L) if t is None else np.asarray(t[i, :L], np.float64)
        ti = (ti - ti[0]) / (ti[-1] - ti[0])
        points[tid] = [[_round6(ti[j]), *(_round6(v) for v in xyz[i, j])] for j in range(L)]
        names = [chr(ord("A") + k) for k in range(int(np.sum(goal_mask[i])))]
        goal_tab[tid] = [[name, *(_round6(v) for v in goals[i, k])] for k, name in enumerate(names)]
        labels.append(names)
    return points, goal_tab, labels


def check_cameras(
    cameras: Sequence[str], goals: Float[np.ndarray, "N 8 3"], goal_mask: Bool[np.ndarray, "N 8"]
) -> dict[str, dict]:
    """Check the stimuli's cameras before anything is rendered: each a camera of the scene
    or a valid camera file (:func:`slotv_jax.scene.check_camera`) that sees a real goal of
    every motion's scene (:func:`slotv_jax.scene.check_sees_goals`), their labels (a
    file's stem: the stimuli's ids and the answers' ``condition``) distinct. Returns each
    camera file's record for the manifest, ``{label: {"file", "position", "rotation",
    "fovy", "resolution"}}`` (ValueError naming ``--cameras``)."""
    out: dict[str, dict] = {}
    by_label: dict[str, str] = {}
    for c in dict.fromkeys(cameras):
        try:
            world_scene.check_camera(c)
            world_scene.check_sees_goals(c, goals, goal_mask)
        except ValueError as e:
            raise ValueError(f"--cameras: {e}") from None
        label = world_scene.camera_label(c)
        if label in by_label or (world_scene.is_camera_file(c) and label in world_scene.CAMERAS):
            other = by_label.get(label, label)
            raise ValueError(f"--cameras: {c!r} and {other!r} share the label {label!r} "
                             "(a camera file's stem): rename one")  # fmt: skip
        by_label[label] = c
        if world_scene.is_camera_file(c):
            cam = world_scene.read_camera_file(c)
            out[label] = {
                "file": str(c),
                "position": [_round6(v) for v in np.asarray(cam.pos, np.float64)],
                "rotation": [[_round6(v) for v in row] for row in np.asarray(cam.rot, np.float64)],
                "fovy": _round6(cam.fovy),
                "resolution": [int(v) for v in np.asarray(cam.resolution)],
            }
        if not ID_RE.match(label):
            raise ValueError(f"--cameras: {c!r}: expected a file name of letters, digits and ._-")
    return out


def stimulus_id(trajectory: str, tau: float, camera: str, kind: str) -> str:
    """A readable, file-safe stimulus id, e.g. ``trajectory_test-17_t0.40_observer``."""
    tag = {"trial": "", "attention": "_check", "practice": "_practice"}[kind]
    return f"{trajectory}_t{tau:.2f}_{camera}{tag}"


def check_manifest(m: dict, where: str) -> None:
    """Validate a manifest's structure (ValueError naming the field)."""
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise ValueError(f"{where}: expected format {FORMAT!r}")
    if not isinstance(m.get("round"), int) or m["round"] < 0:
        raise ValueError(f"{where}, field 'round': expected an integer >= 0")
    stims = m.get("stimuli")
    if not isinstance(stims, list) or not stims:
        raise ValueError(f"{where}, field 'stimuli': expected a non-empty list")
    seen = set()
    for i, s in enumerate(stims):
        w = f"{where}, stimuli[{i}]"
        if not isinstance(s, dict):
            raise ValueError(f"{w}: expected an object")
        for key in ("id", "trajectory", "camera", "scene", "clip", "still"):
            if not isinstance(s.get(key), str) or not s[key]:
                raise ValueError(f"{w}, field {key!r}: expected a non-empty string")
        if not ID_RE.match(s["id"]) or s["id"] in seen:
            raise ValueError(f"{w}, field 'id': expected a unique id of [A-Za-z0-9._-]")
        seen.add(s["id"])
        if s.get("kind") not in KINDS:
            raise ValueError(f"{w}, field 'kind': expected one of {KINDS}")
        tau = s.get("tau")
        if not isinstance(tau, int | float) or not 0.0 < tau <= 1.0:
            raise ValueError(f"{w}, field 'tau': expected a number in (0, 1]")
        goals = s.get("goals")
        if (
            not isinstance(goals, list)
            or not 1 <= len(goals) <= 8
            or not all(isinstance(g, str) and g for g in goals)
            or len(set(goals)) != len(goals)
        ):
            raise ValueError(f"{w}, field 'goals': expected 1-8 distinct labels")
        if s.get("target") is not None and s["target"] not in goals:
            raise ValueError(f"{w}, field 'target': expected one of {goals} or null")
        if s["kind"] == "attention" and (s.get("target") is None or tau != 1.0):
            raise ValueError(f"{w}: an attention check needs tau = 1 and a target")
        px = s.get("goal_pixels")
        if px is not None and (
            not isinstance(px, list)
            or len(px) != len(goals)
            or not all(
                isinstance(p, list) and len(p) == 2 and all(isinstance(v, int | float) for v in p)
                for p in px
            )
        ):
            raise ValueError(f"{w}, field 'goal_pixels': expected one [x, y] per goal")


def _inside(root: Path, rel: str, where: str) -> Path:
    p = Path(rel)
    if p.is_absolute() or ".." in p.parts:
        raise ValueError(f"{where}: expected a relative path inside the set, got {rel!r}")
    full = (root / p).resolve()
    if not full.is_relative_to(root.resolve()) or not full.is_file():
        raise ValueError(f"{where}: no file {rel!r} inside {root}")
    return full


def _read_rows(path: Path, header: Sequence[str]) -> list[list[str]]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows or [c.strip() for c in rows[0]] != list(header):
        raise ValueError(f"{path}: expected the header {','.join(header)}")
    return [r for r in rows[1:] if r]


def load_stimulus_set(path: str | Path, *, verify: bool = True) -> StimulusSet:
    """Read and verify one stimulus set (a round's folder): manifest, tables, files.

    Checks the manifest's fields, that every file lies inside the folder (no absolute
    paths, no ``..``) with its recorded SHA-256 (``verify=False``: existence only), and
    that every stimulus' trajectory and goals are in the tables.
    """
    path = Path(path)
    where = str(path / MANIFEST)
    try:
        m = json.loads((path / MANIFEST).read_text())
    except FileNotFoundError:
        raise ValueError(
            f"--stimuli {path}: no {MANIFEST} (write one with `study stimuli`)"
        ) from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{where}: not valid JSON ({e})") from None
    check_manifest(m, where)
    points: dict[str, list] = {}
    for r in _read_rows(_inside(path, m.get("trajectories", ""), where),
                        ("trajectory", "t", "x", "y", "z")):  # fmt: skip
        points.setdefault(r[0], []).append([float(v) for v in r[1:]])
    goals: dict[str, list] = {}
    for r in _read_rows(_inside(path, m.get("goals", ""), where),
                        ("trajectory", "goal", "x", "y", "z")):  # fmt: skip
        goals.setdefault(r[0], []).append([r[1], *(float(v) for v in r[2:])])
    for i, s in enumerate(m["stimuli"]):
        w = f"{where}, stimuli[{i}]"
        if s["trajectory"] not in points or s["trajectory"] not in goals:
            raise ValueError(f"{w}: trajectory {s['trajectory']!r} is not in the tables")
        if [g[0] for g in goals[s["trajectory"]]] != s["goals"]:
            raise ValueError(f"{w}, field 'goals': not the goals of {s['trajectory']!r}")
        for which in ("clip", "still"):
            f = _inside(path, s[which], f"{w}, field {which!r}")
            if verify and _sha256(f) != s.get(f"{which}_sha256"):
                raise ValueError(f"{w}, field {which!r}: {s[which]} does not match its sha256")
    return StimulusSet(path, m, points, goals)


def write_settings(stimdir: Path, settings: Mapping[str, Any] | None = None) -> None:
    """Write the editable files (consent, instructions, settings) unless they exist.

    ``settings`` (keys of :data:`SETTINGS`) are set in ``study.json``: over the defaults in
    a new one, field by field in one that exists (its other fields stay as they are; the
    caller has checked it with :func:`read_settings`)."""
    settings = dict(settings or {})
    texts = (CONSENT, INSTRUCTIONS, json.dumps({**SETTINGS, **settings}, indent=2) + "\n")
    for name, text in zip(EDITABLE, texts, strict=True):
        if not (stimdir / name).exists():
            write_text(stimdir / name, text)
    if settings:
        path = stimdir / "study.json"
        got = json.loads(path.read_text())
        if {**got, **settings} != got:
            write_text(path, json.dumps({**got, **settings}, indent=2) + "\n")
        read_settings(stimdir)  # what the server will read: valid, with the new values


def read_settings(stimdir: str | Path) -> dict:
    """``study.json`` merged over the defaults (ValueError naming a bad field)."""
    p = Path(stimdir) / "study.json"
    got = json.loads(p.read_text()) if p.is_file() else {}
    if not isinstance(got, dict) or set(got) - set(SETTINGS):
        raise ValueError(f"{p}: expected an object with keys among {sorted(SETTINGS)}")
    s = {**SETTINGS, **got}
    k = s["trials_per_participant"]
    if k is not None and (not isinstance(k, int) or k < 1):
        raise ValueError(f"{p}, field 'trials_per_participant': expected null or an integer >= 1")
    if not isinstance(s["attention_checks"], int) or s["attention_checks"] < 0:
        raise ValueError(f"{p}, field 'attention_checks': expected an integer >= 0")
    if not isinstance(s["confidence"], bool):
        raise ValueError(f"{p}, field 'confidence': expected true or false")
    for key in ("title", "completion_code", "completion_url"):
        if s[key] is not None and not isinstance(s[key], str):
            raise ValueError(f"{p}, field {key!r}: expected a string or null")
    return s


def check_out_dir(out: str | Path, *, what: str = "--out") -> Path:
    """A stimulus set's folder must be new or empty (never overwrite a set)."""
    out = Path(out)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"{what} {out}: expected a new or empty folder")
    if not out.parent.is_dir():
        raise ValueError(f"{what} {out}: the parent folder does not exist")
    return out


# ------------------------------------------------------------------ writing


class Motion(NamedTuple):
    """One motion to render, as the renderer takes it."""

    q: np.ndarray  # (T, 7) joint configurations (rad)
    goals: np.ndarray  # (8, 3) goals (m)
    goal_mask: np.ndarray  # (8,) real goal slots
    t: np.ndarray | None  # (T,) time stamps, or None (normalised)
    labels: list[str]  # the real goals' labels
    target: int | None  # the target slot (None: unknown)


class Renderer(Protocol):
    """What :func:`write_stimulus_set` needs to draw and encode stimuli."""

    def frames(
        self, motion: Motion, tau: float, camera: str
    ) -> tuple[UInt8[np.ndarray, "F H W 3"], Float[np.ndarray, "G 2"]]:
        """The clip's frames cut at τ (goals labelled) and the goals' pixel positions."""
        ...

    def write_video(self, path: Path, frames: UInt8[np.ndarray, "F H W 3"]) -> None: ...
    def write_image(self, path: Path, image: UInt8[np.ndarray, "H W 3"]) -> None: ...
    def settings(self) -> dict:
        """``{"size": [W, H], "fps", "duration", "hold", "timing"}`` for the manifest."""
        ...


def write_stimulus_set(
    out: str | Path,
    *,
    q: Float[np.ndarray, "N T 7"],
    xyz: Float[np.ndarray, "N T 3"],
    goals: Float[np.ndarray, "N 8 3"],
    goal_mask: Bool[np.ndarray, "N 8"],
    ids: Sequence[str],
    specs: Sequence[StimulusSpec],
    render: Renderer,
    scenes: Sequence[str] | None = None,
    targets: Sequence[int] | None = None,
    length: Sequence[int] | None = None,
    t: Float[np.ndarray, "N T"] | None = None,
    round_: int = 0,
    source: dict | None = None,
    overwrite: bool = False,
    progress: bool = True,
    settings: Mapping[str, Any] | None = None,
) -> dict:
    """Render and write one stimulus set (a round) into the new or empty folder ``out``.

    Row n of the arrays is the motion with trajectory id ``ids[n]`` (``q`` drives the
    robot, ``xyz`` is its TCP path for the tables), ``scenes[n]`` its scene and
    ``targets[n]`` its goal slot (optional; attention checks need it). ``specs`` lists the
    stimuli (:func:`cross_specs`); ``render`` draws them (:class:`Renderer`).

    ``out`` must be new or empty, or a stimulus set (then only with ``overwrite``, which
    replaces it whole, later rounds inside it included). The set is written into a
    temporary folder beside ``out`` and renamed into place when complete, so a reader
    (the server looking for new rounds) never sees half a set. Round 0 also gets the
    editable files (consent, instructions, settings; kept from the set it replaces), with
    ``settings`` (e.g. ``{"trials_per_participant": 3}``) set in its ``study.json``.
    Returns the manifest.
    """
    out = Path(out)
    if settings:  # checked before anything is rendered
        if round_:
            raise ValueError(f"settings: round {round_} keeps round 0's study.json; edit that")
        if set(settings) - set(SETTINGS):
            raise ValueError(f"settings: expected keys among {sorted(SETTINGS)}, "
                             f"got {sorted(settings)}")  # fmt: skip
        if (out / "study.json").is_file():
            read_settings(out)  # the study.json to update is one the server reads
    check_output_dir(out, ours=lambda p: (p / MANIFEST).is_file(), overwrite=overwrite,
                     what="--out")  # fmt: skip
    n = len(ids)
    shapes = {"q": (n, None, 7), "xyz": (n, None, 3), "goals": (n, 8, 3), "goal_mask": (n, 8)}
    for name, a in (("q", q), ("xyz", xyz), ("goals", goals), ("goal_mask", goal_mask)):
        a, shape = np.asarray(a), shapes[name]
        if a.ndim != len(shape) or any(
            s is not None and s != d for s, d in zip(shape, a.shape, strict=True)
        ):
            raise ValueError(f"{name}: expected shape {shape} (N = {n} ids), got {a.shape}")
    if len(set(ids)) != n or not all(isinstance(i, str) and ID_RE.match(i) for i in ids):
        raise ValueError("ids: expected distinct ids of letters, digits and ._-")
    for i, s in enumerate(specs):
        if not 0 <= s.index < n:
            raise ValueError(f"specs[{i}]: index {s.index} outside 0..{n - 1}")
        if s.kind not in KINDS or not 0.0 < s.tau <= 1.0:
            raise ValueError(f"specs[{i}]: expected a kind of {KINDS} and tau in (0, 1]")
        if s.kind == "attention" and (targets is None or s.tau != 1.0):
            raise ValueError(f"specs[{i}]: an attention check needs tau = 1 and targets")
    cameras = check_cameras([s.camera for s in specs], goals, goal_mask)
    points, goal_tab, labels = motion_tables(xyz, goals, goal_mask, ids, length=length, t=t)
    todo: list[tuple[dict, Motion, str]] = []
    for s in specs:
        i = s.index
        L = int(np.asarray(q).shape[1] if length is None else length[i])
        sid = stimulus_id(ids[i], s.tau, world_scene.camera_label(s.camera), s.kind)
        if any(e["id"] == sid for e, _, _ in todo):
            raise ValueError(f"specs: stimulus {sid} listed twice")
        target = None if targets is None else int(targets[i])
        motion = Motion(np.asarray(q[i, :L]), np.asarray(goals[i]), np.asarray(goal_mask[i], bool),
                        None if t is None else np.asarray(t[i, :L]), labels[i], target)  # fmt: skip
        entry = {
            "id": sid, "kind": s.kind, "trajectory": ids[i], "tau": float(s.tau),
            "scene": ids[i] if scenes is None else scenes[i],
            "camera": world_scene.camera_label(s.camera),
            "goals": labels[i], "target": None if target is None else labels[i][target],
            "clip": f"clips/{sid}.mp4", "still": f"stills/{sid}.png",
        }  # fmt: skip
        todo.append((entry, motion, s.camera))
    header = {"format": FORMAT, "round": int(round_), "source": source or {},
              **render.settings(), "trajectories": TABLES[0], "goals": TABLES[1]}  # fmt: skip
    if cameras:  # the lab's cameras, as the clips show them (the files may move or change)
        header["cameras"] = cameras
    final, out = out, temp_dir_beside(out)
    try:
        write_tables(out, points, goal_tab)
        manifest = _render_into(out, header, todo, render, progress)
        if round_ == 0:
            for name in EDITABLE:
                if (final / name).is_file():
                    shutil.copy2(final / name, out / name)
            write_settings(out, settings)
        replace_dir(out, final)
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    return manifest


def _render_into(out: Path, header: dict, todo: list, render: Renderer, progress: bool) -> dict:
    """Render every stimulus into ``out``, then write the manifest (the last file).

    The stimuli of one motion and camera are drawn one after another (their manifest order
    is kept), so that a renderer that keeps the last motion's frames draws each of its
    moments once, whatever its τs."""
    (out / "clips").mkdir()
    (out / "stills").mkdir()
    order = sorted(range(len(todo)), key=lambda i: (todo[i][0]["trajectory"], todo[i][2]))
    entries: list = [None] * len(todo)
    for i in tqdm(order, desc="stimuli", disable=not progress):
        entry, motion, view = todo[i]
        frames, pixels = render.frames(motion, entry["tau"], view)
        render.write_video(out / entry["clip"], frames)
        render.write_image(out / entry["still"], frames[-1])
        entries[i] = {
            **entry,
            "goal_pixels": [[round(float(x), 1), round(float(y), 1)] for x, y in pixels],
            "clip_sha256": _sha256(out / entry["clip"]),
            "still_sha256": _sha256(out / entry["still"]),
        }
    manifest = {**header, "stimuli": entries}
    check_manifest(manifest, "manifest")
    write_text(out / MANIFEST, json.dumps(manifest, indent=1) + "\n")
    return manifest
