"""Experiments: Table 1 results schema, resume after a kill, sample efficiency, search."""

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from slotv_jax import data
from slotv_jax.core.defaults import LABELER_NAMES, TEST_SPLITS
from slotv_jax.experiments import fidelity_report, hparam_search, table1
from slotv_jax.runs import curves, grid, presets, record, summary

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def cache(tiny_data, tmp_path_factory):
    """The tiny preset's dataset, stored where the experiments look for it."""
    cfg = presets.tiny()
    assert cfg.data == data.DataConfig(preset="tiny", chunk_size=512, **_tiny_kw())
    root = tmp_path_factory.mktemp("cache")
    d = data.dataset_dir(root, cfg.data)
    d.mkdir(parents=True)
    for split in tiny_data.values():
        data.save_split(d, split, cfg.data)
    return root


def _tiny_kw():
    from conftest import TINY

    return TINY


def _check_schema(doc: dict) -> None:
    """:ref:`concepts-table1`'s results.json schema."""
    assert set(doc) >= {"preset", "config", "environment", "cells", "summary", "timing"}
    assert isinstance(doc["preset"], str) and isinstance(doc["config"], dict)
    assert {"jax", "devices", "mujoco", "flax"} <= set(doc["environment"])
    for c in doc["cells"]:
        assert set(c) == {"labeler", "method", "split", "trial", "accuracy"}
        assert c["labeler"] in LABELER_NAMES and c["method"] in presets.METHODS
        assert c["split"] in TEST_SPLITS and isinstance(c["trial"], int)
        assert 0.0 <= c["accuracy"] <= 1.0
    for s in doc["summary"]:
        assert set(s) == {"labeler", "method", "split", "mean", "sd", "n"}
        assert s["n"] >= 1 and s["sd"] >= 0
    assert isinstance(doc["timing"], dict)


@pytest.mark.slow
def test_table1_results_schema_and_report(cache, tmp_path):
    cfg = presets.tiny()
    doc = table1.run(
        cfg, tmp_path, labelers=["effdist"], methods=["slotv", "trex"], cache=cache, progress=False
    )
    _check_schema(doc)
    on_disk = json.loads((tmp_path / "results.json").read_text())
    _check_schema(on_disk)
    assert len(on_disk["cells"]) == 2 * cfg.trials * len(TEST_SPLITS)
    assert {(s["method"], s["split"]) for s in on_disk["summary"]} == {
        (m, s) for m in ("slotv", "trex") for s in TEST_SPLITS
    }
    md = (tmp_path / "table1.md").read_text()
    assert "0.996 (0.005)" in md and "EffDist" in md  # the paper's value beside ours
    # Summary statistics agree with the cells.
    for s in on_disk["summary"]:
        accs = [
            c["accuracy"]
            for c in on_disk["cells"]
            if (c["labeler"], c["method"], c["split"]) == (s["labeler"], s["method"], s["split"])
        ]
        assert s["n"] == len(accs) == cfg.trials
        np.testing.assert_allclose(s["mean"], np.mean(accs))
        np.testing.assert_allclose(s["sd"], np.std(accs, ddof=1))


def test_summarise_hand_case():
    cells = [
        {"labeler": "dragan", "method": "slotv", "split": "train", "trial": t, "accuracy": a}
        for t, a in enumerate([0.5, 0.7, 0.9])
    ]
    (s,) = grid.summarise(cells)
    assert s["n"] == 3 and s["mean"] == pytest.approx(0.7) and s["sd"] == pytest.approx(0.2)


@pytest.mark.slow
def test_killed_run_resumes_without_recomputing(cache, tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "slotv_jax.experiments.table1", "--preset", "tiny"]
    cmd += ["--labelers", "dragan", "effdist", "--trials", "2", "--out", str(out)]
    cmd += ["--cache", str(cache)]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)  # fmt: skip
    results = out / "results.json"
    deadline = time.monotonic() + 240
    first = None
    while time.monotonic() < deadline and proc.poll() is None:
        if results.exists():
            first = json.loads(results.read_text())
            if first["cells"]:
                break
        time.sleep(0.2)
    assert first and first["cells"], "no cell finished before the deadline"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed = json.loads(results.read_text())  # a complete document, never a torn write
    n_done = len(killed["timing"]["cells"])
    assert 1 <= n_done < 8, "the run should have been killed midway"

    rerun = subprocess.run(cmd, cwd=REPO, env=env, check=True, capture_output=True, text=True)
    assert f"reusing {n_done} finished trial(s) of 8" in rerun.stdout  # it says so
    final = json.loads(results.read_text())
    _check_schema(final)
    # Finished cells were kept as they were, and only the missing ones were trained.
    assert final["timing"]["cells"][:n_done] == killed["timing"]["cells"]
    assert final["cells"][: len(killed["cells"])] == killed["cells"]
    keys = [(c["labeler"], c["method"], c["trial"]) for c in final["timing"]["cells"]]
    assert len(keys) == len(set(keys)) == 2 * 2 * 2
    assert len(final["cells"]) == 8 * len(TEST_SPLITS)
    assert (out / "table1.md").exists()
    assert not list(out.glob(".*tmp"))


def test_each_cell_shows_its_training(cache, tmp_path, monkeypatch):
    """With progress, every cell trains with the trainer's bar (which says when it
    compiles): the cells' bar alone stood still for minutes on the first cell."""
    shown = []
    real = grid.train.train_trials

    def spy(*a, progress=True, **kw):
        shown.append(progress)
        return real(*a, progress=False, **kw)

    monkeypatch.setattr(grid.train, "train_trials", spy)
    cfg = presets.tiny()
    table1.run(cfg, tmp_path, labelers=["effdist"], methods=["trex"], cache=cache, progress=True)
    assert shown == [True] * cfg.trials


def test_resume_refuses_another_config(cache, tmp_path):
    cfg = presets.tiny()
    table1.run(cfg, tmp_path, labelers=["effdist"], methods=["trex"], cache=cache, progress=False)
    other = presets.RunConfig(
        "tiny", 2, cfg.data, {**cfg.train, "trex": cfg.train["trex"].__class__(method="trex")}
    )
    with pytest.raises(ValueError, match="another configuration"):
        table1.run(other, tmp_path, labelers=["effdist"], cache=cache, progress=False)


@pytest.mark.slow
def test_sample_efficiency_outputs(cache, tmp_path):
    doc = curves.run("tiny", tmp_path, repeats=2, every=2, val_size=50, cache=cache, progress=False)
    rows = (tmp_path / "sample_efficiency.csv").read_text().splitlines()
    assert rows[0] == "method,repeat,updates,examples,accuracy"
    assert (tmp_path / "sample_efficiency.png").stat().st_size > 10_000
    for method, s in doc["summary"].items():
        cfg = presets.tiny().train[method]
        steps = 300 // cfg.batch_size
        mine = [r.split(",") for r in rows[1:] if r.startswith(method)]
        assert len(mine) == 2 * (steps // 2 + 1)  # start + every 2 updates, per repeat
        ex = sorted({int(r[3]) for r in mine})
        assert ex[0] == 0 and ex[-1] == (steps // 2) * 2 * cfg.batch_size
        assert s["examples_per_epoch"] == ex[-1]
    assert curves.examples_to_reach(np.array([0, 10, 20]), np.array([0.1, 0.85, 0.9]),
                                               0.8) == 10  # fmt: skip
    assert curves.examples_to_reach(np.array([0, 10]), np.array([0.1, 0.5]), 0.8) is None


@pytest.mark.slow
def test_hparam_search_is_resumable_and_reproducible(cache, tmp_path):
    cfg = hparam_search.tiny()
    doc = hparam_search.run(cfg, tmp_path, phases=["slotv_small_batch", "trex"], cache=cache,
                            progress=False)  # fmt: skip
    assert len(doc["rollouts"]) == 4
    again = hparam_search.run(cfg, tmp_path, phases=["slotv_small_batch", "trex"], cache=cache,
                              progress=False)  # fmt: skip
    assert again["rollouts"] == doc["rollouts"]  # nothing recomputed
    hp = hparam_search.sample_hparams("slotv_large_batch", 3, hparam_search.paper())
    assert hp == hparam_search.sample_hparams("slotv_large_batch", 3, hparam_search.paper())
    assert hp["hidden"][0] in hparam_search.HIDDEN1 and hp["batch_size"] in (64, 128, 256, 512)
    assert 0.0004 <= hp["learning_rate"] <= 0.02 and 0.7 <= hp["rho"] <= 0.999
    extra = [
        len(hparam_search.sample_hparams("trex", i, hparam_search.paper())["hidden"]) > 2
        for i in range(400)
    ]
    assert 0.14 < np.mean(extra) < 0.26
    assert "Spearman" in (tmp_path / "summary.md").read_text()


def test_spearman_hand_cases():
    x = np.array([1.0, 2, 3, 4])
    assert summary.spearman(x, x**3) == pytest.approx(1.0)
    assert summary.spearman(x, -x) == pytest.approx(-1.0)
    assert np.isnan(summary.spearman(x, np.ones(4)))
    # ties share their average rank: ranks (0.5, 0.5, 2, 3) against (0, 1, 2, 3)
    assert summary.spearman(np.array([1.0, 1, 2, 3]), x) == pytest.approx(np.sqrt(0.9))


@pytest.mark.slow
def test_vmapped_trials_match_one_by_one(cache, tmp_path):
    cfg = presets.tiny()
    kw = {"labelers": ["fastapp"], "methods": ["slotv"], "cache": cache, "progress": False}
    one = table1.run(cfg, tmp_path / "one", **kw)
    together = table1.run(cfg, tmp_path / "together", vmap_trials=True, **kw)
    assert [c["trained_together"] for c in together["timing"]["cells"]] == [2, 2]
    a = {(c["trial"], c["split"]): c["accuracy"] for c in one["cells"]}
    b = {(c["trial"], c["split"]): c["accuracy"] for c in together["cells"]}
    assert a == b


def _four_cpu_devices_env(n: int = 4) -> dict:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env["XLA_FLAGS"] = (
        env.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={n}"
    ).strip()
    return env


FOUR_DEVICE_RESUME = textwrap.dedent(
    """
    import json
    from pathlib import Path
    import jax
    from slotv_jax.training import parallel
    from slotv_jax.experiments import table1
    from slotv_jax.runs import presets
    assert jax.device_count() == 4
    out, cache = Path({out!r}), Path({cache!r})
    kw = dict(labelers=["dragan", "effdist"], cache=cache, progress=False)
    real, calls = parallel.train_group, []

    def train_group(cfg, data, seeds, mesh, **k):
        calls.append([cfg.method, list(seeds), dict(mesh.shape)])
        if len(calls) == 2 and crash:
            raise KeyboardInterrupt("interrupted")
        return real(cfg, data, seeds, mesh, **k)

    parallel.train_group, crash = train_group, True
    try:
        table1.run(presets.tiny(), out, **kw)
    except KeyboardInterrupt:
        pass
    killed, first_calls = json.loads((out / "results.json").read_text()), list(calls)
    calls.clear()
    crash = False
    final = table1.run(presets.tiny(), out, **kw)
    print("RESULT" + json.dumps(dict(killed=killed, final=final, first=first_calls, calls=calls)))
    """
)


@pytest.mark.slow
def test_interrupted_multi_device_run_resumes_without_recomputing(cache, tmp_path):
    """Table 1 on 4 CPU devices: the 4 pending trials of a method (2 labelers × 2 trials)
    train as one group, one per device; a run interrupted in its second group has written
    the first, and the rerun trains only the second."""
    code = FOUR_DEVICE_RESUME.format(out=str(tmp_path / "out"), cache=str(cache))
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=_four_cpu_devices_env(),
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr[-4000:]
    res = json.loads(r.stdout.split("RESULT", 1)[1])
    slotv_group = ["slotv", [0, 1, 0, 1], {"trial": 4, "data": 1}]
    trex_group = ["trex", [0, 1, 0, 1], {"trial": 4, "data": 1}]
    assert res["first"] == [slotv_group, trex_group]  # the second group was interrupted
    killed, final = res["killed"], res["final"]
    assert [(c["labeler"], c["method"], c["trial"]) for c in killed["timing"]["cells"]] == [
        ("dragan", "slotv", 0), ("dragan", "slotv", 1), ("effdist", "slotv", 0),
        ("effdist", "slotv", 1),
    ]  # fmt: skip
    assert all(c["trained_together"] == 4 for c in killed["timing"]["cells"])
    assert res["calls"] == [trex_group]  # only the missing units were trained
    _check_schema(final)
    assert final["timing"]["cells"][:4] == killed["timing"]["cells"]
    assert final["cells"][: len(killed["cells"])] == killed["cells"]
    assert len(final["cells"]) == 8 * len(TEST_SPLITS)


MULTI_PROCESS = [
    "-m", "slotv_jax.experiments.table1", "--preset", "tiny", "--labelers", "effdist",
    "--methods", "slotv", "--trials", "4",
]  # fmt: skip


@pytest.mark.slow
def test_two_processes_split_a_group_and_one_writes(cache, tmp_path):
    """jax.distributed with two CPU processes of 2 devices each on 127.0.0.1: one group of
    4 trials spans both processes, process 0 alone writes, and the accuracies equal a
    single-process run's (to the one or two near-tied predictions float rounding may flip)."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**_four_cpu_devices_env(2), "JAX_PLATFORMS": "cpu"}
    outs = [tmp_path / "p0", tmp_path / "p1"]
    procs = [
        subprocess.Popen(
            [
                sys.executable,
                *MULTI_PROCESS,
                "--out",
                str(outs[i]),
                "--cache",
                str(cache),
                "--coordinator",
                f"127.0.0.1:{port}",
                "--num-processes",
                "2",
                "--process-id",
                str(i),
            ],
            cwd=REPO,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for i in range(2)
    ]
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err[-4000:]
    assert not outs[1].exists()  # process 1 wrote nothing
    doc = json.loads((outs[0] / "results.json").read_text())
    _check_schema(doc)
    assert len(doc["environment"]["devices"]) == 4
    assert [c["trained_together"] for c in doc["timing"]["cells"]] == [4] * 4
    ref = table1.run(presets.tiny(), tmp_path / "ref", labelers=["effdist"], methods=["slotv"],
                     cache=cache, progress=False)  # fmt: skip
    ref = {(c["trial"], c["split"]): c["accuracy"] for c in ref["cells"] if c["trial"] < 2}
    got = {(c["trial"], c["split"]): c["accuracy"] for c in doc["cells"] if c["trial"] < 2}
    assert got.keys() == ref.keys()
    for k in ref:
        assert abs(got[k] - ref[k]) <= 2 / 100, (k, got[k], ref[k])


def test_study_size_report_renders_again(tmp_path):
    """``study_size --report`` renders the recorded report again from its results alone:
    every table row (the numbers) of the recorded report, in order, and the figure."""
    plt = pytest.importorskip("matplotlib.pyplot")
    folder = REPO / "experiments"
    for name in ("study_size.json", "study_size.md"):
        (tmp_path / name).write_bytes((folder / name).read_bytes())
    from slotv_jax.experiments.study_size.__main__ import main

    assert main(["--report", "--out", str(tmp_path)]) == 0
    rows = [x for x in (tmp_path / "study_size.md").read_text().splitlines() if x.startswith("|")]
    recorded = [x for x in (folder / "study_size.md").read_text().splitlines() if x.startswith("|")]
    assert len(rows) > 20 and rows == recorded[: len(rows)]
    got, want = (plt.imread(d / "study_size.png") for d in (tmp_path, folder))
    assert got.shape == want.shape and np.abs(got - want).mean() < 0.01
    with pytest.raises(SystemExit) as e:
        main(["--report", "--out", str(tmp_path / "empty")])
    assert e.value.code == 2


def test_study_size_rerun_of_the_finished_record_changes_nothing(tmp_path, monkeypatch):
    """The recorded quick run, rerun on its defaults: every cell is there, so no dataset is
    loaded or made and the results document stays byte for byte (its machine and times);
    the report is drawn again with the same rows and the run's date."""
    folder = REPO / "experiments"
    for name in ("study_size.json", "study_size.md"):
        (tmp_path / name).write_bytes((folder / name).read_bytes())
    from slotv_jax.experiments.study_size.__main__ import main

    def no_data(*a, **k):
        raise AssertionError("a finished record loaded its dataset")

    monkeypatch.setattr(data, "cached_dataset", no_data)
    argv = ["--out", str(tmp_path), "--cache", str(tmp_path / "cache"), "--no-progress"]
    assert main(argv) == 0
    assert (tmp_path / "study_size.json").read_bytes() == (folder / "study_size.json").read_bytes()
    assert not (tmp_path / "cache").exists()
    rows = [x for x in (tmp_path / "study_size.md").read_text().splitlines() if x.startswith("|")]
    recorded = [x for x in (folder / "study_size.md").read_text().splitlines() if x.startswith("|")]
    assert rows == recorded
    dates = [
        [x for x in (d / "study_size.md").read_text().splitlines() if x.startswith("- Date:")]
        for d in (tmp_path, folder)
    ]
    assert dates[0] == dates[1] and len(dates[0]) == 1  # the run's date, not today's
    # the command that made it, less display-only flags (a rerun with them changes nothing)
    assert record.command_line("p", ["--preset", "quick", "--no-progress"]) == "p --preset quick"


def test_hparam_summary_renders_again(tmp_path, capsys):
    """``hparam_search --report-only`` renders the summary again from the recorded rollouts
    alone: every table row of the recorded summary (the scores and rank correlations), in
    order; a folder without a rollouts document is refused."""
    folder = REPO / "experiments"
    (tmp_path / "rollouts.json").write_bytes(
        (folder / "hparam_search_quick_rollouts.json").read_bytes()
    )
    assert hparam_search.main(["--report-only", "--out", str(tmp_path)]) == 0
    rows = [x for x in (tmp_path / "summary.md").read_text().splitlines() if x.startswith("|")]
    recorded = [x for x in (folder / "hparam_search_quick.md").read_text().splitlines()
                if x.startswith("|")]  # fmt: skip
    assert len(recorded) > 40 and rows[: len(recorded)] == recorded
    with pytest.raises(SystemExit) as e:
        hparam_search.main(["--report-only", "--out", str(tmp_path / "empty")])
    assert e.value.code == 2


@pytest.mark.parametrize("stem", ["explainable_quick", "explainable_paper"])
def test_explainable_record_holds_the_tables_its_results_render(stem):
    """``experiments/explainable.md`` (a written document around both runs) holds every
    table row that its recorded results render to: no number typed by hand."""
    from slotv_jax.experiments.explainable_report import report

    folder = Path(__file__).resolve().parent.parent / "experiments"
    doc = json.loads((folder / f"{stem}_results.json").read_text())
    rows = [line for line in report(doc).splitlines() if line.startswith("|")]
    assert len(rows) > 20
    lines = set((folder / "explainable.md").read_text().splitlines())
    assert [row for row in rows if row not in lines] == []


@pytest.mark.parametrize(
    "stem, render",
    [
        ("table1_quick", lambda doc: table1.report(doc)),
        ("table1_paper", lambda doc: table1.report(doc)),
        ("fidelity", lambda doc: fidelity_report.render_markdown(doc)),
    ],
)
def test_written_records_hold_the_table_rows_their_results_render(stem, render):
    """Table 1's and the fidelity ablation's records (written documents around the runs:
    how they ran, what they mean) hold every table row their recorded results render to:
    no number typed by hand."""
    folder = Path(__file__).resolve().parent.parent / "experiments"
    name = "fidelity_results.json" if stem == "fidelity" else f"{stem}_results.json"
    doc = json.loads((folder / name).read_text())
    rows = [line for line in render(doc).splitlines() if line.startswith("|")]
    assert len(rows) > 15
    lines = set((folder / f"{stem}.md").read_text().splitlines())
    assert [row for row in rows if row not in lines] == []


def test_a_people_loop_report_names_its_own_folder_and_part_of_the_suite():
    """Written elsewhere than experiments/, the report's command and its drawing's command
    name that folder; a run of part of the suite says which of its populations it has."""
    from slotv_jax.experiments.people_loop import report

    folder = Path(__file__).resolve().parent.parent / "experiments"
    doc = json.loads((folder / "people_loop_results.json").read_text())
    text = report.report(doc, "people_loop", Path("/tmp/mine"))
    assert "--population suite,zoo --out /tmp/mine`" in text
    assert "--plans /tmp/mine/people_loop_plans.npz" in text and "experiments/" not in text
    assert "## The suite: the pick on every population" in text
    one = {
        **doc,
        "populations": doc["populations"][:1],
        "summary": [r for r in doc["summary"] if r["population"] == "default"],
    }
    text = report.report(one, "people_loop")
    assert "## The pick on every population" in text and "The suite:" not in text
    assert "Of the suite's 10 populations this run has 1 (not yet run: `homogeneous`, " in text


@pytest.mark.parametrize("stem", ["people_loop", "people_loop_paper"])
def test_people_loop_records_are_their_results_rendered(stem):
    """The people loop's recorded reports are exactly what their results render to."""
    from slotv_jax.experiments.people_loop import report

    folder = Path(__file__).resolve().parent.parent / "experiments"
    doc = json.loads((folder / f"{stem}_results.json").read_text())
    # the records were written with --out experiments, which their command line names
    assert report.report(doc, stem, Path("experiments")) == (folder / f"{stem}.md").read_text()


def test_the_main_job_says_what_good_looks_like_on_the_quick_preset(tmp_path, monkeypatch, capsys):
    """Under the quick table the main job prints one line: what good looks like (the
    record's ranges) and this run's own, here the recorded run's: its Δ ranges and SLOT-V
    above T-REX in 16 of 16 pairs, read back from the recorded Markdown table, not from
    the code's paper values. The paper preset has no such line."""
    import re

    root = Path(__file__).resolve().parent.parent / "experiments"
    doc = json.loads((root / "table1_quick_results.json").read_text())
    monkeypatch.setattr(table1, "run", lambda *a, **k: doc)
    assert table1.main(["--out", str(tmp_path / "t1")]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if "good looks like" in ln]
    assert len(lines) == 1
    rows = [ln.split(" | ") for ln in (root / "table1_quick.md").read_text().splitlines()
            if re.match(r"\| [A-Za-z]* \| [a-z ]+ \| \d", ln)]  # fmt: skip
    assert len(rows) == 16
    slotv, trex = [float(r[4]) for r in rows], [float(r[7].rstrip(" |")) for r in rows]
    above = sum(float(r[2].split()[0]) > float(r[5].split()[0]) for r in rows)
    want = (
        f"this run: SLOT-V Δ {min(slotv):+.3f} to {max(slotv):+.3f}, T-REX Δ "
        f"{min(trex):+.3f} to {max(trex):+.3f}, SLOT-V above T-REX in {above} of 16 pairs"
    )
    assert want in lines[0] and "SLOT-V 0.01-0.19 below the paper in every cell" in lines[0]
    assert -0.19 <= round(min(slotv), 2) and round(max(slotv), 2) <= -0.01  # the record's claim
    paper = json.loads((root / "table1_paper_results.json").read_text())
    assert table1.expectation(paper) is None
