"""Records stay records: no command writes into ``experiments/`` (the recorded documents)
unless its ``--out`` names that folder; on its defaults each writes to ``runs/``."""

import importlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from slotv_jax.core import fileio
from slotv_jax.runs import command, record

REPO = Path(__file__).resolve().parents[1]
LOOP_RESULTS = REPO / "experiments" / "people_loop_results.json"

# Every command that writes a report or results into a folder, with the fewest arguments it
# takes (its defaults otherwise).
COMMANDS = {
    "slotv_jax.experiments.active": [],
    "slotv_jax.experiments.active_stream": [],
    "slotv_jax.experiments.study_size.__main__": [],
    "slotv_jax.experiments.people_loop.__main__": [],
    "slotv_jax.experiments.people_loop.suite": [],
    "slotv_jax.experiments.people_loop.evaluation_round": [str(LOOP_RESULTS), "--draws", "1"],
    "slotv_jax.experiments.execution": [],
    "slotv_jax.experiments.fidelity": ["--preset", "paper"],
    "slotv_jax.experiments.table1": [],
    "slotv_jax.experiments.planning.__main__": [],
    "slotv_jax.experiments.sample_efficiency": [],
    "slotv_jax.experiments.explainable": [],
    "slotv_jax.experiments.hparam_search": [],
}


class FirstWrite(BaseException):
    """Raised where a command would first create a folder: its outputs are resolved."""


@pytest.mark.parametrize("module", sorted(COMMANDS))
def test_default_outputs_are_not_the_records(module, tmp_path, monkeypatch):
    """The folders a command checks its outputs in, and the first one it would create, on
    its defaults (in an empty working folder: nothing is written), lie outside experiments/."""
    seen: list[Path] = []
    main = importlib.import_module(module).main
    real_mkdir = Path.mkdir

    def checked(folder, *args, **kwargs):
        seen.append(Path(folder))

    def mkdir(self, *args, **kwargs):
        if not Path(os.path.abspath(self)).is_relative_to(tmp_path):
            return real_mkdir(self, *args, **kwargs)  # a library's cache, say
        seen.append(Path(self))
        raise FirstWrite

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(fileio, "check_output_dir", checked)
    monkeypatch.setattr(fileio, "check_output_files", checked)
    monkeypatch.setattr(Path, "mkdir", mkdir)
    with pytest.raises((FirstWrite, SystemExit)):
        main(COMMANDS[module])
    assert seen, f"{module} resolved no output folder"
    for folder in seen:
        rel = Path(os.path.relpath(tmp_path / folder, tmp_path))
        assert rel.parts[0] != "experiments", f"{module} writes to {folder} by default"


def test_recorded_commands_name_their_folder():
    """A report rendered into experiments/ names --out experiments on each command line, so
    that the line run again rewrites that record; one in runs/ (the default) names none."""
    block = "python -m m --preset paper --groups a\npython -m m --groups b  # resumes"
    assert record.with_out(block, "experiments", command.DEFAULT_OUT) == (
        "python -m m --preset paper --groups a --out experiments\n"
        "python -m m --groups b --out experiments  # resumes"
    )
    assert record.with_out(block, "runs", command.DEFAULT_OUT) == block
    assert record.with_out("python -m m --out x", "experiments", "runs") == "python -m m --out x"


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-C", repo, *args], check=True, capture_output=True, text=True
    ).stdout


def test_a_command_on_its_defaults_leaves_git_status_clean(tmp_path):
    """The evaluation round (seconds) on its defaults, from a repository holding the
    records it would rewrite, leaves ``git status`` clean and writes into runs/."""
    repo = tmp_path / "repo"
    (repo / "experiments").mkdir(parents=True)
    shutil.copy(REPO / ".gitignore", repo)
    for f in (REPO / "experiments").glob("evaluation_round_quick.*"):
        shutil.copy(f, repo / "experiments")
    shutil.copy(LOOP_RESULTS, repo / "experiments")
    _git(repo, "init", "-q")
    _git(repo, "add", "-A")
    _git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "records")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "slotv_jax.experiments.people_loop.evaluation_round"]
    cmd += ["experiments/people_loop_results.json", "--draws", "20"]
    subprocess.run(cmd, cwd=repo, env=env, check=True, capture_output=True)
    assert _git(repo, "status", "--porcelain", "--untracked-files=all") == ""
    assert (repo / "runs" / "evaluation_round_quick.md").is_file()
