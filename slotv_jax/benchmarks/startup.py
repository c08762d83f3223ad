"""What a process pays before its first useful work: a command's start, and the scene's
constants (the cameras' poses, the home TCP), each against the way it was done before.

    python -m slotv_jax.benchmarks.startup [--repeats 5] [--commands train,study,...]

Every figure is a fresh interpreter (a subprocess), as a user's command or a test's
subprocess is; the two columns of a row take turns within each repeat, so that a change in
the machine's speed reaches both. Printed: the median and the best wall time of each, and
their ratio (baseline / now).

1. **A command's start**, ``python -m slotv_jax.X --help``, against the same command with
   the libraries it used to load at start imported first (``toppra``, which brings SciPy's
   interpolation and matplotlib, and ``mujoco.mjx``): they now load when a plan is first
   timed (:mod:`slotv_jax.execution.topp`) or the MJX reference is asked for.
2. **The scene's cameras** (:func:`slotv_jax.scene.camera`), posed by MuJoCo C
   (``mj_kinematics`` + ``mj_camlight``), against the same poses from one compiled
   ``mjx.kinematics`` + ``mjx.camlight`` call on the CPU (how they were posed before): with
   an empty JAX compilation cache, as on a user's first run.
3. **The home TCP** (:func:`slotv_jax.kinematics.home_tcp`), from MuJoCo C, against one
   jitted call of the chain (:func:`slotv_jax.kinematics.tcp_state`), empty cache too.

Rows 2 and 3 time the whole process, and the constant with the imports it needs.
"""

from __future__ import annotations

import datetime
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

import slotv_jax
from slotv_jax.benchmarks._machine import cpu_model
from slotv_jax.core import cli

COMMANDS = ("train", "study", "render", "execution", "data", "labelers")
RESULT_TAG = "STARTUP_CONSTANT_SECONDS "

# the libraries a command loaded at start before they were deferred
OLD_IMPORTS = (
    "import contextlib, io\n"
    "import toppra.algorithm, toppra.constraint\n"
    "with contextlib.redirect_stdout(io.StringIO()):\n"
    "    from mujoco import mjx\n"
)

CAMERAS_NOW = "from slotv_jax.world import scene\nposes = scene.camera_poses()\n"
CAMERAS_MJX = (
    "from slotv_jax.robot import kinematics as K\n"
    "mjx = K.mjx\n"
    "def pose(mx):\n"
    "    d = mjx.camlight(mx, mjx.kinematics(mx, mjx.make_data(mx)))\n"
    "    return d.cam_xpos, d.cam_xmat\n"
    "poses = K.host_eval(pose, K.mj_model(K.SCENE_XML))\n"
)
HOME_NOW = "from slotv_jax.robot import kinematics as K\nhome = K.home_tcp()\n"
HOME_CHAIN = (
    "import jax, numpy as np\n"
    "from slotv_jax.robot import kinematics as K\n"
    "with jax.default_device(jax.devices('cpu')[0]):\n"
    "    home = np.asarray(jax.jit(K.tcp_state)(np.asarray(K.Q_HOME, np.float32)).pos)\n"
)


def _timed_constant(body: str) -> str:
    """A script that times ``body`` (its imports included) and prints the seconds."""
    return (
        "import time\n"
        "t0 = time.perf_counter()\n"
        + body
        + f"print({RESULT_TAG!r} + repr(time.perf_counter() - t0))\n"
    )


def _run(argv: list[str], env: dict) -> tuple[float, float | None]:
    """Wall seconds of one subprocess, and the seconds it printed after RESULT_TAG."""
    t0 = time.perf_counter()
    r = subprocess.run(argv, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(argv[:4])}...: exit {r.returncode}\n{r.stderr[-2000:]}")
    inner = [line for line in r.stdout.splitlines() if line.startswith(RESULT_TAG)]
    return wall, (float(inner[-1][len(RESULT_TAG) :]) if inner else None)


def _row(name: str, now: list[float], before: list[float]) -> str:
    mn, mb = statistics.median(now), statistics.median(before)
    return (
        f"{name:46s} {mn:7.2f} {min(now):7.2f}   {mb:7.2f} {min(before):7.2f}   "
        f"{mb / mn:5.1f}x {min(before) / min(now):5.1f}x"
    )


@cli.command
def main(argv=None) -> int:
    p = cli.ArgumentParser(prog="python -m slotv_jax.benchmarks.startup", description=__doc__)
    p.add_argument("--repeats", type=int, default=5, help="fresh processes per figure")
    p.add_argument(
        "--commands",
        default=",".join(COMMANDS),
        help=f"the commands whose start is timed (comma-separated, of {','.join(COMMANDS)})",
    )
    args = p.parse_args(argv)
    if args.repeats < 1:
        p.error(f"--repeats {args.repeats}: expected at least 1")
    commands = [c for c in args.commands.split(",") if c]
    unknown = sorted(set(commands) - set(COMMANDS))
    if unknown or not commands:
        p.error(f"--commands {args.commands!r}: expected some of {','.join(COMMANDS)}")

    print(slotv_jax.XLA_CONFIG.summary())
    print(
        f"# {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M} UTC  {cpu_model()}, "
        f"{os.cpu_count()} cores, load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}\n"
        f"# python {platform.python_version()}, {args.repeats} fresh processes per figure; "
        "seconds: median, best"
    )
    print(f"{'':46s} {'now':>15s}   {'before':>15s}   {'ratio (before/now)':>12s}")
    py = sys.executable
    with tempfile.TemporaryDirectory() as cache:
        env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
        for c in commands:
            now, before = [], []
            for _ in range(args.repeats):
                now.append(_run([py, "-m", f"slotv_jax.{c}", "--help"], env)[0])
                old = OLD_IMPORTS + (
                    f"import runpy, sys\nsys.argv = ['slotv_jax.{c}', '--help']\n"
                    f"runpy.run_module('slotv_jax.{c}', run_name='__main__', alter_sys=True)\n"
                )
                before.append(_run([py, "-c", old], env)[0])
            print(_row(f"python -m slotv_jax.{c} --help", now, before))
        for k, (name, a, b) in enumerate((
            ("cameras: MuJoCo C / MJX", CAMERAS_NOW, CAMERAS_MJX),
            ("home TCP: MuJoCo C / jit(chain)", HOME_NOW, HOME_CHAIN),
        )):  # fmt: skip
            walls, inner = ([], []), ([], [])
            for i in range(args.repeats):
                for j, body in enumerate((a, b)):
                    # an empty compilation cache every time: a user's first run
                    d = os.path.join(cache, f"{k}-{i}-{j}")
                    e = {**env, "JAX_COMPILATION_CACHE_DIR": d}
                    w, s = _run([py, "-c", _timed_constant(body)], e)
                    walls[j].append(w)
                    inner[j].append(s)
            print(_row(f"{name}, with imports", *inner))
            print(_row(f"{name}, the process", *walls))
    return 0


if __name__ == "__main__":
    sys.exit(main())
