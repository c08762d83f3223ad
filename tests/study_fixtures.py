"""Small stimulus sets for the study server's tests, and a participant that answers over HTTP.

:class:`DotRenderer` draws a motion as dots (no OpenGL): the server's tests need real
files with real checksums, not pictures of a robot. The browser test renders real ones.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import av
import httpx
import numpy as np
from PIL import Image

from slotv_jax import kinematics, render
from slotv_jax.webstudy import stimuli

SIZE = (64, 48)
ROOT = str(Path(__file__).resolve().parents[1])
SERVE_MODULE = "slotv_jax.study"


class DotRenderer:
    """Frames with the goals as grey dots and the TCP (x, y) as a red dot; H.264 clips."""

    fps = 10
    timing = None  # clips at the plans' own times (a renderer's --timed setting)

    def frames(self, motion: stimuli.Motion, tau: float, camera: str):
        n = len(motion.labels)
        w, h = SIZE
        px = np.array([[8 + 48 * k / max(n - 1, 1), 12.0] for k in range(n)])
        s = np.linspace(0.0, tau, 5)
        frames = np.full((len(s), h, w, 3), 240, np.uint8)
        for x, y in px.astype(int):
            frames[:, y - 2 : y + 3, x - 2 : x + 3] = 90
        for f, sk in enumerate(s):
            x, y = int(8 + 48 * sk), int(40 - 20 * sk)
            frames[f, y - 2 : y + 3, x - 2 : x + 3] = (220, 30, 30)
        return frames, px

    def write_video(self, path: Path, frames) -> None:
        with av.open(str(path), "w") as out:
            st = out.add_stream("libx264", rate=self.fps)
            st.width, st.height, st.pix_fmt = SIZE[0], SIZE[1], "yuv420p"
            for f in frames:
                out.mux(st.encode(av.VideoFrame.from_ndarray(f, format="rgb24")))
            out.mux(st.encode())

    def write_image(self, path: Path, image) -> None:
        Image.fromarray(image).save(path)

    def settings(self) -> dict:
        return {"size": list(SIZE), "fps": self.fps, "duration": 0.5, "hold": 0.0}


def motions(n: int, seed: int = 0, n_goals: int = 3):
    """n straight motions of T = 6 points towards one of ``n_goals`` goals."""
    rng = np.random.default_rng(seed)
    goals = np.zeros((n, 8, 3), np.float32)
    mask = np.zeros((n, 8), bool)
    goals[:, :n_goals] = rng.uniform(-0.3, 0.3, (n, n_goals, 3)) + np.array([0.5, 0.0, 0.05])
    mask[:, :n_goals] = True
    target = rng.integers(0, n_goals, n)
    start = np.array([0.3, 0.0, 0.5])
    s = np.linspace(0, 1, 6)[None, :, None]
    xyz = (start + s * (goals[np.arange(n), target][:, None] - start)).astype(np.float32)
    q = np.zeros((n, 6, 7), np.float32)
    return q, xyz, goals, mask, target


def write_dot_set(out: Path, *, n: int = 4, taus=(0.5, 1.0), round_: int = 0, first: int = 0):
    """A set of ``n`` trial motions at ``taus``, one attention check and one practice."""
    q, xyz, goals, mask, target = motions(n + 2, seed=round_)
    ids = [f"m{first + i}" for i in range(n)] + [f"check{round_}", f"practice{round_}"]
    specs = stimuli.cross_specs(
        range(n), taus=taus, cameras=("observer",), attention=[n], practice=[n + 1]
    )
    return stimuli.write_stimulus_set(
        out, q=q, xyz=xyz, goals=goals, goal_mask=mask, ids=ids, specs=specs,
        render=DotRenderer(), targets=target, round_=round_, progress=False,
    )  # fmt: skip


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class ServerProcess:
    """``python -m slotv_jax.study serve`` in a subprocess; ``.url``, ``.admin_token``."""

    def __init__(self, stimdir: Path, db: Path, port: int | None = None, *, timeout: float = 60):
        self.port = port or free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        cmd = [sys.executable, "-m", SERVE_MODULE, "serve", "--stimuli", str(stimdir),
               "--db", str(db), "--port", str(self.port)]  # fmt: skip
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, env={**os.environ, "PYTHONPATH": ROOT})  # fmt: skip
        self.admin_token = None
        deadline = time.monotonic() + timeout
        for line in self.proc.stdout:
            if line.startswith("admin token: "):
                self.admin_token = line.split(": ", 1)[1].strip()
                break
        if self.admin_token is None:
            raise RuntimeError(f"server did not start: {self.proc.stderr.read()[-2000:]}")
        while time.monotonic() < deadline:  # uvicorn binds after printing
            try:
                if httpx.get(self.url + "/healthz", timeout=1).status_code == 200:
                    return
            except httpx.TransportError:
                time.sleep(0.05)
        raise RuntimeError("server did not answer /healthz")

    def kill9(self) -> None:
        os.kill(self.proc.pid, signal.SIGKILL)
        self.proc.wait(10)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.kill9()
        for f in (self.proc.stdout, self.proc.stderr):
            f.close()


def robot_motions(n: int, seed: int = 0):
    """n joint-space motions of the Panda from home; goal A..C on the table, one under the
    motion's end (the target), TCP paths from MuJoCo C (no JAX compilation)."""
    rng = np.random.default_rng(seed)
    home = np.asarray(kinematics.Q_HOME, np.float64)
    s = np.linspace(0.0, 1.0, 12)[:, None]
    low, high = [-0.6, 0.2, -0.3, 0.3, -0.3, -0.2, -0.3], [0.6, 0.5, 0.3, 0.6, 0.3, 0.2, 0.3]
    q = np.stack([home + s * rng.uniform(low, high) for _ in range(n)])
    with render.MotionRenderer((32, 32)) as r:
        xyz = np.stack([r.tcp_path(qi) for qi in q]).astype(np.float32)
    goals = np.zeros((n, 8, 3), np.float32)
    mask = np.zeros((n, 8), bool)
    target = rng.integers(0, 3, n)
    for i in range(n):
        end = np.array([xyz[i, -1, 0], xyz[i, -1, 1], 0.025])
        others = [end + np.array([0.0, dy, 0.0]) for dy in (-0.22, 0.22, 0.44)]
        others[target[i]] = end
        goals[i, :3] = others
        mask[i, :3] = True
    return q.astype(np.float32), xyz, goals, mask, target
