"""The package as a user installs it: an sdist and a wheel built from it, the wheel installed
into a fresh venv, and the library used from a folder outside the repository.

The venv reuses the running interpreter's installed dependencies (a ``.pth`` line naming its
site-packages), so nothing is downloaded; a ``.pth`` line only adds a folder to ``sys.path``
and runs none of the ``.pth`` files in it, so the editable install's finder of the running
venv stays out and the ``slotv_jax`` imported is the wheel's (checked by its ``__file__``).
"""

import json
import os
import shutil
import site
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest
import ref_labelers as ref

from slotv_jax import data
from slotv_jax.core.defaults import TEST_SPLITS
from slotv_jax.runs import presets

REPO = Path(__file__).resolve().parents[1]
# what the sdist packs (pyproject's package data and setuptools' defaults: tests/ among them)
SDIST_INPUTS = ("pyproject.toml", "README.md", "LICENSE", "slotv_jax", "tests")
_SKIP = shutil.ignore_patterns("__pycache__", "*.egg-info")

# Run by the wheel's interpreter: the robot, a scene and a labelled straight line to goal 0.
USE = """
import json, jax, numpy as np, slotv_jax
from slotv_jax import kinematics, labelers, scene
tcp = np.asarray(kinematics.tcp_position(kinematics.Q_HOME))
s = scene.sample_scene(jax.random.key(3), 4)
xyz = np.linspace(tcp, np.asarray(s.goals[0]), 30)
y = labelers.dragan(xyz, s.goals, s.goal_mask)
print(json.dumps({"file": slotv_jax.__file__, "tcp": tcp.tolist(), "xyz": xyz.tolist(),
                  "goals": np.asarray(s.goals).tolist(), "mask": np.asarray(s.goal_mask).tolist(),
                  "y": np.asarray(y).tolist(), "beta": labelers.DEFAULT_BETAS["dragan"]}))
"""


def _env() -> dict:
    """This process's environment without PYTHONPATH (which names the repository)."""
    return {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}


def _run(cmd: list, cwd: Path) -> subprocess.CompletedProcess:
    proc = subprocess.run(cmd, cwd=cwd, env=_env(), capture_output=True, text=True)
    assert proc.returncode == 0, f"{cmd} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-4000:]}"
    return proc


@pytest.fixture(scope="module")
def venv(tmp_path_factory) -> Path:
    """A fresh venv holding the wheel built from the repository's sdist: its site-packages."""
    root = tmp_path_factory.mktemp("wheel")
    dist = root / "dist"
    # The sdist is staged in its source folder: build from a copy of what it packs, so that
    # the staging never sits in the repository while the other worker's tests run there.
    src = root / "src"
    src.mkdir()
    for name in SDIST_INPUTS:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, src / name, ignore=_SKIP)
        else:
            shutil.copy2(REPO / name, src / name)
    # sdist first, then the wheel from the unpacked sdist: both must carry the robot's files
    _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", dist, src], root)
    (wheel,) = dist.glob("slotv_jax-*.whl")
    _run([sys.executable, "-m", "venv", "--without-pip", root / "venv"], root)
    paths = {"base": str(root / "venv"), "platbase": str(root / "venv")}
    purelib = Path(sysconfig.get_path("purelib", vars=paths))
    (purelib / "host.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    py = root / "venv" / "bin" / "python"
    _run([py, "-m", "pip", "install", "-q", "--no-deps", "--no-index", "--ignore-installed",
          wheel], root)  # fmt: skip
    return purelib


@pytest.mark.slow
def test_wheel_loads_the_robot_and_labels_from_another_folder(venv, tmp_path):
    py = venv.parents[2] / "bin" / "python"
    got = json.loads(_run([py, "-c", USE], tmp_path).stdout)
    assert Path(got["file"]) == venv / "slotv_jax" / "__init__.py"  # the wheel's, not the tree's
    np.testing.assert_allclose(got["tcp"], [0.3069, 0.0, 0.4869], atol=1e-4)
    want = ref.dragan(
        np.array(got["xyz"]), np.array(got["goals"]), np.array(got["mask"]), beta=got["beta"]
    )
    np.testing.assert_allclose(got["y"], want, atol=1e-5)


@pytest.mark.slow
def test_wheel_runs_table1_tiny_from_another_folder(venv, tiny_cfg, tiny_data, tmp_path):
    cfg = presets.tiny()
    assert cfg.data == tiny_cfg  # the conftest dataset is the preset's: the command reuses it
    cache = tmp_path / "cache"
    d = data.dataset_dir(cache, cfg.data)
    d.mkdir(parents=True)
    for split in tiny_data.values():
        data.save_split(d, split, cfg.data)
    py = venv.parents[2] / "bin" / "python"
    cmd = [py, "-m", "slotv_jax.experiments.table1", "--preset", "tiny", "--labelers", "dragan"]
    cmd += ["--methods", "slotv", "--trials", "1", "--out", "out", "--cache", cache]
    _run(cmd, tmp_path)
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    assert sorted(c["split"] for c in doc["cells"]) == sorted(TEST_SPLITS)
    assert all(0.0 <= c["accuracy"] <= 1.0 for c in doc["cells"])
    assert (tmp_path / "out" / "table1.md").is_file()


@pytest.mark.slow
def test_wheel_carries_the_licence_and_the_links(venv):
    (info,) = venv.glob("slotv_jax-*.dist-info")
    assert (info / "licenses" / "LICENSE").read_text() == (REPO / "LICENSE").read_text()
    meta = (info / "METADATA").read_text()
    assert "License-Expression: Apache-2.0" in meta
    urls = {line.split(": ", 1)[1].split(",")[0] for line in meta.splitlines()
            if line.startswith("Project-URL: ")}  # fmt: skip
    assert {"Homepage", "Documentation", "Repository", "Issues", "Paper"} <= urls
