"""The people loop (slotv_jax.experiments.people_loop): the whole loop on a tiny config, its
numbers re-derived from the document, the one compiled planner against the planner called
directly, and every bad flag refused before any work."""

from __future__ import annotations

import dataclasses
import json
import math
import os
import shutil
import subprocess
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from slotv_jax import planning
from slotv_jax.asking import selection
from slotv_jax.experiments import people_loop as exp
from slotv_jax.experiments.people_loop.__main__ import main
from slotv_jax.observers import population as population_lib
from slotv_jax.planning import evaluation

pytestmark = pytest.mark.xdist_group("people_loop")


_TINY_RUN: list = []  # the run, kept for the process: CI's log showed it set up twice


@pytest.fixture(scope="session")  # the tests share one xdist group: one worker builds it
def tiny_run(tmp_path_factory):
    if not _TINY_RUN:
        out = tmp_path_factory.mktemp("loop")
        cache = tmp_path_factory.mktemp("data")
        argv = ["--preset", "tiny", "--out", str(out), "--cache", str(cache), "--no-progress"]
        assert main(argv) == 0
        doc = json.loads((out / "people_loop_tiny_results.json").read_text())
        _TINY_RUN.append((out, cache, argv, doc))
    return _TINY_RUN[0]


def test_the_tests_of_the_tiny_run_share_one_worker(request):
    """Under ``--dist loadgroup`` (pyproject's addopts) this module's tests run on one xdist
    worker, which builds the tiny run once: xdist marks their ids with the group. (pytest
    9.2 with pytest-xdist 3.8 lost the mark silently and both workers built it.)"""
    if getattr(request.config.option, "loadgroup", False):  # set on xdist workers
        assert request.node.nodeid.endswith("@people_loop"), request.node.nodeid


@pytest.mark.slow
def test_the_document_holds_spec_rows_and_its_own_numbers(tiny_run):
    out, _, _, doc = tiny_run
    cfg = exp.tiny()
    assert doc["preset"] == "tiny" and [p["population"] for p in doc["populations"]] == ["default"]
    keys = {"population", "family", "strategy", "answers", "gain_kept", "seeds"}
    assert all(keys <= set(r) for r in doc["summary"])
    want = {(f, s, a) for f in cfg.families for s in cfg.strategies for a in cfg.sizes}
    assert {(r["family"], r["strategy"], r["answers"]) for r in doc["summary"]} == want
    pop = doc["populations"][0]
    cmp_ = pop["comparison"]
    lo, hi = cmp_["straight"]["score"], cmp_["oracle"]["score"]
    assert hi > lo  # the population's own plan reads better than the straight line
    for r in pop["rows"]:  # gain kept = (plan − straight) / (oracle − straight)
        assert r["gain_kept"] == pytest.approx((r["score"] - lo) / (hi - lo), rel=1e-9, abs=1e-12)
        assert r["score"] == pytest.approx(np.mean(r["score_per_tau"]), abs=1e-6)
        a, (lo95, hi95) = r["accuracy"], r["accuracy_95"]
        assert lo95 <= a + 1e-4 and a - 1e-4 <= hi95
    for s in doc["summary"]:  # the summary is the mean over seeds of the rows
        rows = [r for r in pop["rows"] if (r["family"], r["strategy"], r["answers"])
                == (s["family"], s["strategy"], s["answers"])]  # fmt: skip
        assert s["seeds"] == len(rows) == cfg.seeds
        assert s["gain_kept"] == pytest.approx(np.mean([r["gain_kept"] for r in rows]), abs=1e-6)
    # the fitted temperatures are what fit_beta finds: positive and finite
    assert all(math.isfinite(r["beta"]) and r["beta"] > 0 for r in pop["rows"] if "beta" in r)
    for name in ("people_loop_tiny.md", "people_loop_tiny.png", "people_loop_tiny_render.png"):
        assert (out / name).stat().st_size > 0, name
    text = (out / "people_loop_tiny.md").read_text()
    assert "simulated people" in text and "Population `default`" in text
    assert "less the family whose plans" in text and "the pool left out" in text


@pytest.mark.slow
def test_a_rerun_keeps_the_document(tiny_run):
    out, _, argv, _ = tiny_run
    before = (out / "people_loop_tiny_results.json").read_bytes()
    assert main(argv) == 0  # the population is there: nothing runs again
    assert (out / "people_loop_tiny_results.json").read_bytes() == before


@pytest.mark.slow
def test_the_pick_by_plans_and_the_pool_read_the_plans_the_other_fits_judge(tiny_run):
    """Each run's pick by plans: every candidate's plans judged by every candidate's fit
    (``judged_by``), each scored by the others' mean judgment, the best one's plans taken
    as they were evaluated (re-derived from the document)."""
    _, _, _, doc = tiny_run
    cands = exp.tiny().candidates
    by: dict = {}
    for r in doc["populations"][0]["rows"]:
        by.setdefault((r["strategy"], r["seed"], r["answers"]), {})[r["family"]] = r
    assert by and all("pick_cross" in fams for fams in by.values())
    for fams in by.values():
        for f in cands:
            assert set(fams[f]["judged_by"]) == set(cands)
            assert all(0 < v <= 1 for v in fams[f]["judged_by"].values())
        want = {f: np.mean([fams[f]["judged_by"][g] for g in cands if g != f]) for f in cands}
        cross = fams["pick_cross"]
        assert cross["cross_scores"] == pytest.approx(want, abs=2e-6)
        assert cross["chosen"] == max(want, key=want.get)
        for k in ("score", "gain_kept", "accuracy", "feasible"):
            assert cross[k] == fams[cross["chosen"]][k], k
        # The pool leaves out the candidate whose plans the others judge least legible, and
        # any that predicts held-out answers no better than guessing, but never the best fit.
        pick = fams["pick"]
        h = {f: fams[f]["heldout_nll"] for f in cands}
        best, least = min(h, key=h.get), min(want, key=want.get)
        expect = {f for f in cands if f != best and (f == least or h[f] >= pick["uniform_nll"])}
        assert set(pick["left_out"]) == expect, (h, want, pick["uniform_nll"])
        assert all(pick["weights"][f] == 0 for f in expect) and pick["weights"][best] >= 0
        assert sum(pick["weights"].values()) > 0
        assert pick["poor_fit"] == (
            (pick["uniform_nll"] - min(h.values())) / pick["uniform_nll"] < 0.05
        )
        assert set(pick["weights_likelihood"]) == set(cands)


def test_the_cautious_pick_plans_the_picks_pool_of_every_fold_for_its_lower_bound(tiny_run):
    """Each run's cautious pick row: the pick's pool and weights (the same answers, the same
    report fields), its κ and K + 1 members recorded, plans of its own (the bound moves
    them off the pick's where the members disagree) and a report column."""
    out, _, _, doc = tiny_run
    cfg = exp.tiny()
    by: dict = {}
    for r in doc["populations"][0]["rows"]:
        by.setdefault((r["strategy"], r["seed"], r["answers"]), {})[r["family"]] = r
    same = ("weights", "left_out", "heldout_nll", "uniform_nll", "picked", "poor_fit")
    for fams in by.values():
        pick, cautious = fams["pick"], fams["pick_cautious"]
        assert {k: cautious[k] for k in same} == {k: pick[k] for k in same}
        assert cautious["caution"] == cfg.caution and cautious["members"] == cfg.pick_folds + 1
        assert cautious["feasible"] == 1.0
    assert any(f["pick_cautious"]["score"] != f["pick"]["score"] for f in by.values())
    text = (out / "people_loop_tiny.md").read_text()
    assert "| **cautious pick** (its folds' lower bound) |" in text


def test_another_seed_adds_its_rows_to_the_document(tmp_path, monkeypatch, capsys):
    """A run with another seed of the same config (one GPU call per seed) keeps the rows it
    finds, runs only the seeds missing, adds their rows and records the run; the summary
    and the report count every seed. (The loop itself is replaced by a stand-in that
    returns one row per (family, strategy, size, seed): this tests the document.)"""
    cfg = exp.tiny()
    calls = []

    def fake_run_population(cfg, name, pop, splits, seeds, *, progress=True, on_size=None):
        calls.append(list(seeds))
        rows = [
            {"population": name, "family": f, "strategy": st, "seed": sd, "answers": a,
             "score": 0.5 + 0.01 * sd, "gain_kept": 0.1 * (sd + 1), "accuracy": 0.4}
            for f in cfg.families for st in cfg.strategies for a in cfg.sizes for sd in seeds
        ]  # fmt: skip
        cmp_ = {o: {"score": 0.3, "per_tau": [0.3, 0.3], "accuracy": 0.3}
                for o in ("straight", "oracle", "oracle_whole")}  # fmt: skip
        return {"population": name, "population_config": {}, "rows": rows, "comparison": cmp_,
                "example": {}, "timing": {"total_s": 1.0}, "stimuli": []}  # fmt: skip

    monkeypatch.setattr(exp, "run_population", fake_run_population)
    monkeypatch.setattr(exp.data_lib, "generate_dataset", lambda *a, **k: {})
    monkeypatch.setattr(exp.report_lib, "render", lambda *a, **k: None)
    drawn = []  # whether the example was drawn again: after new rows only
    monkeypatch.setattr(exp, "draw_example", lambda *a, again=False: drawn.append(again))
    path = tmp_path / "people_loop_tiny_results.json"
    exp.run(cfg, tmp_path, ["default"], cache=tmp_path / "data", progress=False)
    first = json.loads(path.read_text())
    exp.run(dataclasses.replace(cfg, first_seed=1, seeds=2), tmp_path, ["default"],
            cache=tmp_path / "data", progress=False)  # fmt: skip
    doc = json.loads(path.read_text())
    assert calls == [[0], [1, 2]]  # seed 0 was there: only 1 and 2 ran
    (before,), (after,) = first["populations"], doc["populations"]
    assert after["rows"][: len(before["rows"])] == before["rows"]
    assert [r["seeds"] for r in after["runs"]] == [[0], [1, 2]]
    assert all("environment" in r and "date" in r for r in after["runs"])
    for s in doc["summary"]:
        assert s["seeds"] == 3 and s["gain_kept"] == pytest.approx(0.2)  # mean of .1, .2, .3
    exp.run(dataclasses.replace(cfg, seeds=3), tmp_path, ["default"],
            cache=tmp_path / "data", progress=False)  # fmt: skip
    assert calls == [[0], [1, 2]]  # every seed is there: nothing runs again, and it says so
    assert "nothing ran" in capsys.readouterr().err
    assert drawn == [True, True, False]  # the best family may change with new rows only
    other = dataclasses.replace(cfg, problems=2)  # another config starts a new document
    exp.run(other, tmp_path, ["default"], cache=tmp_path / "data", progress=False)
    assert calls[-1] == [0] and len(json.loads(path.read_text())["populations"][0]["runs"]) == 1
    # evaluation keys depend on a run's strategy and seed alone, not on the runs beside it
    both = exp.eval_keys([("random", 0), ("margin", 1)])
    alone = exp.eval_keys([("margin", 1)])
    assert np.array_equal(jax.random.key_data(both[1]), jax.random.key_data(alone[0]))


def test_every_run_has_its_own_evaluation_key():
    """eval_keys: a key from the run's strategy and seed alone, so each strategy's evaluation
    study (and each seed's) draws its own participants, and a run's key is the same
    whichever runs stand beside it."""
    runs = [(st, sd) for st in selection.STRATEGIES for sd in (0, 1, 7)]
    keys = np.asarray(jax.random.key_data(exp.eval_keys(runs)))
    assert len({k.tobytes() for k in keys}) == len(runs)  # no two runs share a study
    for run, key in zip(runs, keys, strict=True):
        np.testing.assert_array_equal(jax.random.key_data(exp.eval_keys([run])[0]), key)


@pytest.mark.slow
def test_random_and_active_share_round_zero_and_its_answers(tiny_run):
    """Round 0 is the same random draw for every strategy of a seed, so at the first size the
    families fitted on it plan the same (the same answers, the same keys)."""
    _, _, _, doc = tiny_run
    first = doc["config"]["sizes"][0]
    rows = [r for r in doc["populations"][0]["rows"] if r["answers"] == first]
    for f in exp.tiny().families:
        scores = {r["strategy"]: r["score"] for r in rows if r["family"] == f}
        assert len(set(np.round(list(scores.values()), 6))) == 1, (f, scores)


@pytest.mark.slow
def test_one_compiled_planner_plans_as_the_planner_does(tiny_run):
    """The experiment's planner of the population (the program the tiny run compiled), at
    the oracle's index, gave the plan of planning.plan with the population observer: the
    document's example problem planned again, directly (the run's own output, so no second
    compilation of the switch)."""
    _, _, _, doc = tiny_run
    cfg = exp.tiny()
    ex = doc["populations"][0]["example"]
    pop = population_lib.get_population(doc["populations"][0]["population"])
    problem = planning.straight_line(
        jnp.asarray(ex["problem"]["goals"], jnp.float32),
        jnp.asarray(ex["problem"]["goal_mask"], bool),
        jnp.int32(ex["problem"]["target"]),
        cfg=cfg.planner,
    )
    np.testing.assert_allclose(np.asarray(problem.q), ex["q"]["straight"], atol=2e-5)
    want = planning.plan(population_lib.population_observer(pop), problem, cfg.planner)
    np.testing.assert_allclose(np.asarray(want.q), ex["q"]["oracle"], atol=2e-5)


def test_a_rerun_that_computes_nothing_keeps_the_example_drawing(tmp_path, monkeypatch):
    """The example drawn beside the same plans is kept (drawing it again, in a render
    process, was 14 of the 20 s of a rerun of a finished document on a 2-core CPU); a
    missing or outdated drawing is drawn, and --report draws it again."""
    recorded = Path(__file__).resolve().parents[1] / "experiments" / "people_loop_results.json"
    shutil.copy(recorded, tmp_path / recorded.name)
    doc = json.loads(recorded.read_text())
    drawn = []

    def render(cmd, **kw):  # stands in for python -m slotv_jax.render
        drawn.append(cmd)
        Path(cmd[cmd.index("--out") + 1]).write_bytes(b"a picture")
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(exp.subprocess, "run", render)
    for _ in range(2):  # what run() does after the loop: a rerun that computed nothing
        exp.draw_example(doc, tmp_path, "people_loop")
    assert len(drawn) == 1  # the first found no drawing; the second kept it
    q = doc["populations"][0]["example"]["q"]
    q["straight"] = (np.asarray(q["straight"]) + 0.01).tolist()  # another example: drawn
    exp.draw_example(doc, tmp_path, "people_loop")
    assert len(drawn) == 2
    assert main(["--report", "--out", str(tmp_path)]) == 0  # --report draws it again
    assert len(drawn) == 3


def test_report_of_a_stopped_run_leaves_out_the_population_it_stopped_in(
    tmp_path, monkeypatch, capsys
):
    """A run stopped mid-population leaves that population's finished sizes in the document
    (``partial``); --report draws the finished ones and names the stopped one, and a
    document with nothing finished is one line, exit 2."""
    recorded = Path(__file__).resolve().parents[1] / "experiments" / "people_loop_results.json"
    doc = json.loads(recorded.read_text())
    first = doc["populations"][0]
    smallest = min(r["answers"] for r in first["rows"])  # the first size: what a stop leaves
    rows = [{**r, "population": "random:9"} for r in first["rows"] if r["answers"] == smallest]
    doc["populations"].append({"population": "random:9", "partial": True, "rows": rows})
    (tmp_path / recorded.name).write_text(json.dumps(doc))

    def render(cmd, **kw):  # stands in for python -m slotv_jax.render
        Path(cmd[cmd.index("--out") + 1]).write_bytes(b"a picture")
        return subprocess.CompletedProcess(cmd, 0, "", "")

    monkeypatch.setattr(exp.subprocess, "run", render)
    assert main(["--report", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "people_loop.md").read_text()
    assert "**Stopped mid-way, not in this report:** random:9" in text
    assert "random:9" not in text.split("**Stopped mid-way")[0]
    doc["populations"] = doc["populations"][-1:]
    (tmp_path / recorded.name).write_text(json.dumps(doc))
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        main(["--report", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "no finished population yet (random:9 stopped" in err
    assert len(err.strip().splitlines()) == 1


def test_wilson_interval_by_hand():
    # k = 8 of n = 10: p = 0.8, z = 1.96 (Wilson 1927), computed by hand
    z, n, p = 1.96, 10, 0.8
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    assert evaluation.wilson(8, 10) == pytest.approx((centre - half, centre + half))
    assert evaluation.wilson(8, 10) == pytest.approx((0.4902, 0.9433), abs=1e-4)


@pytest.mark.parametrize(
    ("flags", "needle"),
    [
        (["--sizes", "20,x"], "--sizes"),
        (["--sizes", "30,20"], "sizes"),
        (["--sizes", "21,40"], "multiples of per_stimulus"),
        (["--strategies", "margin"], "strategies"),
        (["--strategies", "random,bogus"], "strategies"),
        (["--families", "mlp,nope"], "families"),
        (["--seeds", "0"], "seeds"),
        (["--problems", "0"], "problems"),
        (["--plan-share", "1.5"], "plan_share"),
        (["--plan-share", "half"], "--plan-share"),
        (["--population", "no_such_population.json"], "population"),
        (["--preset", "huge"], "--preset"),
    ],
)
def test_bad_flags_are_one_line_errors_before_any_work(tmp_path, capsys, flags, needle):
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as e:
        main(["--preset", "tiny", "--out", str(out), *flags])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) >= 1 and needle in err[-1], err
    assert not out.exists()  # nothing was written


@pytest.fixture
def no_work(monkeypatch):
    """The loop itself (dataset, fits, plans) must not start: a bad input is refused first."""
    import slotv_jax.experiments.people_loop.__main__ as loop_main

    def run(*args, **kwargs):
        raise AssertionError("the run started")

    monkeypatch.setattr(loop_main, "run", run)


def test_bad_population_inputs_are_named_before_any_work(tmp_path, capsys, no_work):
    """Nested 100,000 deep (a RecursionError traceback), values whose use overflows float32
    (P_pop was NaN), a directory (reported as no such file) and a name that is none of the
    forms: one line naming the file and the field, or the forms, exit code 2."""
    deep, big, wide = (tmp_path / f"{n}.json" for n in ("deep", "big", "wide"))
    deep.write_text("[" * 100_000 + "]" * 100_000)
    pop = population_lib.default().to_dict()
    big.write_text(json.dumps({**pop, "beta": {**pop["beta"], "cost_to_go": 1e300}}))
    wide.write_text(json.dumps({**pop, "beta_sigma_log": 1000}))
    for spec, needle in (
        (deep, f"error: {deep}: not a JSON document this program reads: arrays or objects "
               "nested too deeply"),
        (big, f"error: {big}: field 'beta': 'cost_to_go': expected a number in (0, "),
        (wide, f"error: {wide}: field 'beta_sigma_log': expected a number in [0, 5]"),
        (tmp_path, f"error: population {tmp_path}: is a directory; expected a population JSON"),
        ("nosuch", "error: population: expected default, homogeneous, random:K (the K-th draw), "
                   "suite, a population JSON file, a zoo member (inverse_planning, "
                   "extrapolation, accumulator, descent, salience, anchor, hesitant), zoo, or "
                   "module:function (your own people), got 'nosuch'"),
        ("no_such_module_xyz:people", "error: population: cannot import module "
                                      "'no_such_module_xyz'"),
        ("json:loads", "error: population: json:loads() failed: "),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main(["--preset", "tiny", "--out", str(tmp_path / "o"), "--population", str(spec)])
        err = capsys.readouterr().err
        assert e.value.code == 2 and err.startswith(needle) and err.count("\n") == 1, err
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("flags", "line"),
    [
        (["--families", "mlp,mlp"], "--families mlp,mlp: expected each name once, 'mlp' is twice"),
        (["--strategies", "random,random"],
         "--strategies random,random: expected each name once, 'random' is twice"),
        (["--first-seed", str(2**32)], "--first-seed 4294967296: expected a seed in 0..4294967295"),
        (["--first-seed", str(2**63)], f"--first-seed {2**63}: expected a seed in 0..4294967295"),
        (["--first-seed", str(2**32 - 1), "--seeds", "2"],
         "--first-seed 4294967295, --seeds 2: the last seed, 4294967296, is beyond 2**32 - 1"),
    ],
)  # fmt: skip
def test_repeated_families_and_seeds_beyond_32_bits_are_refused(
    flags, line, tmp_path, capsys, no_work
):
    """--families mlp,mlp was accepted (--strategies random,random was refused); --first-seed
    2**32 drew what 0 draws and 2**63 failed inside JAX after the dataset work."""
    with pytest.raises(SystemExit) as e:
        main(["--preset", "tiny", "--out", str(tmp_path / "o"), *flags])
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.startswith(f"error: {line}") and err.count("\n") == 1, err
    assert not (tmp_path / "o").exists()
    with pytest.raises(ValueError, match=r"^families: expected distinct names"):
        dataclasses.replace(exp.tiny(), families=("mlp", "mlp"))


def test_a_bad_population_file_is_named(tmp_path, capsys):
    bad = tmp_path / "people.json"
    bad.write_text(json.dumps({**population_lib.default().to_dict(), "lapse": 2.0}))
    with pytest.raises(SystemExit) as e:
        main(["--preset", "tiny", "--out", str(tmp_path / "o"), "--population", str(bad)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "people.json" in err and "lapse" in err, err
    assert not (tmp_path / "o").exists()


def test_workers_are_dealt_to_the_visible_gpus_in_turn(monkeypatch):
    """More workers than GPUs share them (i mod G), the CUDA_VISIBLE_DEVICES list where it is
    set; without a GPU no worker is given one (they share the CPU)."""
    assert exp.worker_gpus(5, ["0", "1"]) == ["0", "1", "0", "1", "0"]
    assert exp.worker_gpus(3, ["2"]) == ["2", "2", "2"]
    assert exp.worker_gpus(2, []) == [None, None]
    assert exp.visible_gpus() == []  # the tests run on the CPU backend
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    monkeypatch.setattr(jax, "local_device_count", lambda: 2)
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "3, 5")
    assert exp.visible_gpus() == ["3", "5"]
    monkeypatch.delenv("CUDA_VISIBLE_DEVICES")
    assert exp.visible_gpus() == ["0", "1"]


def test_a_spread_run_lets_its_processes_share_a_gpu(tmp_path, monkeypatch, capsys):
    """Every worker of a spread run, and the command itself before its first JAX operation,
    takes GPU memory as it needs it (XLA_PYTHON_CLIENT_PREALLOCATE=false: JAX's default
    takes 75 % of every GPU, and on an H200 every worker beside such a parent failed),
    unless the user said how to take it; a population's seeds stay on one worker, and more
    workers than GPUs get one line saying that they take turns."""
    from slotv_jax.experiments.people_loop import __main__ as cmd

    started = []

    class Worker:  # what subprocess.Popen would start: its command line and environment
        returncode = 0

        def __init__(self, argv, env, stdout, stderr):
            started.append((argv, env))

        def wait(self):
            return 0

    monkeypatch.setattr(exp.subprocess, "Popen", Worker)
    monkeypatch.setattr(exp, "visible_gpus", lambda: ["0"])
    for v in exp.GPU_MEMORY_VARS:  # set, then removed: monkeypatch restores them after
        monkeypatch.setenv(v, "")
        monkeypatch.delenv(v)
    todo = {"default": [0, 1, 2], "homogeneous": [0, 1], "random:0": [0, 1]}
    exp._spread(exp.tiny(), tmp_path, todo, 2, tmp_path / "data", False, [])
    jobs = [json.loads(argv[argv.index("--worker-jobs") + 1]) for argv, _ in started]
    assert jobs == [{"default": [0, 1, 2]}, {"homogeneous": [0, 1], "random:0": [0, 1]}]
    assert [
        (e["CUDA_VISIBLE_DEVICES"], e["XLA_PYTHON_CLIENT_PREALLOCATE"]) for _, e in started
    ] == [
        ("0", "false"),
        ("0", "false"),
    ]
    assert "2 workers on 1 GPU(s) take turns" in capsys.readouterr().err
    assert "XLA_PYTHON_CLIENT_PREALLOCATE" not in os.environ  # the parent's is the command's
    monkeypatch.setenv("XLA_CLIENT_MEM_FRACTION", ".3")  # the user's choice is kept
    started.clear()
    exp._spread(exp.tiny(), tmp_path, todo, 2, tmp_path / "data", False, [])
    assert [e["XLA_CLIENT_MEM_FRACTION"] for _, e in started] == [".3", ".3"]
    assert not any("XLA_PYTHON_CLIENT_PREALLOCATE" in e for _, e in started)
    monkeypatch.delenv("XLA_CLIENT_MEM_FRACTION")
    monkeypatch.setattr(exp, "visible_gpus", lambda: [])  # a CPU: no GPU, nothing said of one
    started.clear()
    capsys.readouterr()
    exp._spread(exp.tiny(), tmp_path, todo, 2, tmp_path / "data", False, [])
    mine = os.environ.get("CUDA_VISIBLE_DEVICES")
    assert [e.get("CUDA_VISIBLE_DEVICES") for _, e in started] == [mine, mine]
    assert "GPU" not in capsys.readouterr().err

    seen = []
    monkeypatch.setattr(cmd, "run", lambda *a, **k: seen.append(dict(os.environ)))
    out = ["--preset", "tiny", "--no-progress", "--out"]
    assert cmd.main([*out, str(tmp_path / "one")]) == 0
    assert cmd.main([*out, str(tmp_path / "two"), "--processes", "2"]) == 0
    assert [e.get("XLA_PYTHON_CLIENT_PREALLOCATE") for e in seen] == [None, "false"]


def test_the_command_keeps_its_compiled_programs_beside_its_datasets(monkeypatch):
    """The entry point's compilation cache is CACHE/xla of its own --cache (the default where
    the flag is missing or malformed); a $JAX_COMPILATION_CACHE_DIR of the user's is kept."""
    from slotv_jax.experiments.people_loop import __main__ as cmd

    assert cmd.data_cache(["--preset", "paper", "--cache", "/tmp/d"]) == Path("/tmp/d")
    assert cmd.data_cache(["--data-cache=/tmp/e"]) == Path("/tmp/e")
    assert cmd.data_cache(["--preset", "paper"]) == Path("data")
    assert cmd.data_cache(["--cache"]) == Path("data")
    set_to = []
    monkeypatch.setattr(jax.config, "update", lambda k, v: set_to.append((k, v)))
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    assert cmd.use_compilation_cache(Path("/tmp/d/xla")) == "/tmp/d/xla"
    assert set_to == [("jax_compilation_cache_dir", "/tmp/d/xla")]
    monkeypatch.setenv("JAX_COMPILATION_CACHE_DIR", "/mine")
    assert cmd.use_compilation_cache(Path("/tmp/d/xla")) == "/mine" and len(set_to) == 1


def test_a_file_where_the_compiled_programs_go_is_left_alone(tmp_path, monkeypatch, capsys):
    """A user's file named CACHE/xla: the cache is not used, one line says so, the file is
    unchanged."""
    from slotv_jax.experiments.people_loop import __main__ as cmd

    mine = tmp_path / "xla"
    mine.write_text("my notes")
    monkeypatch.delenv("JAX_COMPILATION_CACHE_DIR", raising=False)
    monkeypatch.setattr(jax.config, "update", lambda k, v: pytest.fail("cache set"))
    assert cmd.use_compilation_cache(mine) is None
    assert mine.read_text() == "my notes"
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a folder" in err[0], err


def test_the_loop_figure_keeps_every_line_apart_and_labels_the_0_8_line():
    """The recorded people loop's figure, redrawn from its results: in every panel each line
    has its own (colour, dashes, marker), the picks lie under SLOT-V's line, the 0.8 line
    is labelled, and the one figure legend names every line of every panel."""
    from slotv_jax.experiments.people_loop import report as report_lib

    root = Path(__file__).resolve().parent.parent / "experiments"
    doc = report_lib.finished(json.loads((root / "people_loop_results.json").read_text()))[0]
    fig = report_lib.figure(doc)
    (legend,) = fig.legends
    named = {t.get_text() for t in legend.get_texts()}
    panels = [ax for ax in fig.axes if ax.get_visible() and ax.axison]
    assert len(panels) == len(doc["populations"])
    for ax in panels:
        lines = ax.get_lines()
        styles = [(ln.get_color(), ln.get_linestyle(), ln.get_marker(), ln.get_linewidth())
                  for ln in lines]  # fmt: skip
        assert len(set(styles)) == len(styles)
        assert {ln.get_label() for ln in lines} <= named
        good = [ln for ln in lines if list(ln.get_ydata()) == [0.8, 0.8]]
        assert len(good) == 1 and "0.8" in good[0].get_label()
        z = {ln.get_label().split(",")[0]: ln.get_zorder() for ln in lines}
        assert z["pick (answers alone)"] < z["SLOT-V (paper MLP)"]


@pytest.mark.slow
def test_the_loop_runs_on_a_zoo_member(tiny_run, tmp_path):
    """A zoo member (people outside the population model) through the whole loop: its rows
    carry its own name and fields, its oracle (planned with the member's own P) beats the
    straight line on that P, and the report says nothing of the suite's populations."""
    from slotv_jax.observers import zoo

    _, cache, _, _ = tiny_run
    out = tmp_path / "zoo"
    argv = ["--preset", "tiny", "--population", "descent", "--families", "dragan_fitted",
            "--out", str(out), "--cache", str(cache), "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    doc = json.loads((out / "people_loop_tiny_results.json").read_text())
    (entry,) = doc["populations"]
    assert entry["population"] == "descent" and entry["population_config"]["zoo"] == "descent"
    assert entry["population_config"]["view"] == zoo.MEMBERS["descent"].view
    cmp_ = entry["comparison"]
    assert cmp_["oracle"]["score"] > cmp_["straight"]["score"]
    assert {r["population"] for r in doc["summary"]} == {"descent"}
    text = (out / "people_loop_tiny.md").read_text()
    assert "descent" in text and "Of the suite's" not in text


@pytest.mark.slow
def test_rounds_of_plans_never_show_an_evaluation_scene_and_count_in_the_budget(tiny_run):
    """The tiny preset asks half of its second round about plans (``plan_share`` 0.5). Every
    row of every run is counted (the budget's last size), the first round is dataset motions
    only, the second holds round(0.5 · k) plans, the planned families in turn, and every
    stimulus (motion or plan) is of a ``train`` scene, none of whose goal sets is that of
    an evaluation problem (compared coordinate by coordinate, from the dataset itself)."""
    from slotv_jax import data as data_lib

    _, cache, _, doc = tiny_run
    cfg = exp.tiny()
    splits = data_lib.generate_dataset(
        cfg.data, data_lib.dataset_dir(cache, cfg.data), progress=False,
        splits=("train", "position_test", "goal_count_test"),
    )  # fmt: skip
    held = exp.loop.held_out_problems(cfg, splits)
    train_goals = splits["train"].scene_goals
    train_mask = splits["train"].scene_mask
    (run,) = doc["populations"][0]["runs"]
    rows = [s // cfg.per_stimulus for s in cfg.sizes]
    assert len(run["stimuli"]) == len(cfg.strategies) * cfg.seeds
    for st in run["stimuli"]:
        assert st["split"] == "train" and st["rows_per_size"] == rows
        assert len(st["scene"]) == len(st["plan"]) == rows[-1]  # every round's rows
        first, second = st["plan"][: rows[0]], st["plan"][rows[0] :]
        assert set(first) == {""}
        k_plan = round(cfg.plan_share * (rows[1] - rows[0]))
        planned = [f for f in second if f]
        assert len(planned) == k_plan
        assert planned == [cfg.planned[j % len(cfg.planned)] for j in range(k_plan)]
        for e in set(st["scene"]):
            goals = train_goals[e][train_mask[e]]
            for g, m in zip(held["goals"], held["goal_mask"], strict=True):
                same = goals.shape == g[m].shape and np.allclose(goals, g[m], atol=1e-6)
                assert not same, f"train scene {e} is an evaluation problem's scene"
    assert run["timing"]["study_plan_s"] > 0


def test_rounds_of_plans_are_refused_where_they_cannot_run():
    cfg = exp.tiny()
    with pytest.raises(ValueError, match="plan_share: expected a share"):
        dataclasses.replace(cfg, plan_share=1.5)
    assert dataclasses.replace(cfg, sizes=(40,)).plan_share == 0.5  # one round: no plans asked
    with pytest.raises(ValueError, match="plan stimuli in a round"):
        dataclasses.replace(cfg, sizes=(20, 200), subset=200, plan_share=1.0)
    assert "plan_share" not in dataclasses.replace(cfg, plan_share=0.0).to_json()


def test_plans_are_resampled_in_time_not_by_arc_length():
    from slotv_jax.experiments.people_loop import rounds

    x = np.zeros((3, 3), np.float32)
    x[:, 0] = [0.0, 1.0, 4.0]  # at t = 0, 0.5, 1: slow, then fast
    got = rounds.resample_time(x, 5)[:, 0]  # t = 0, 0.25, 0.5, 0.75, 1, by hand
    np.testing.assert_allclose(got, [0.0, 0.5, 1.0, 2.5, 4.0], atol=1e-6)
    np.testing.assert_array_equal(rounds.resample_time(x, 3), x)  # already at 3 times


def test_each_run_and_round_has_its_own_plans_and_draws_every_family_in_turn():
    from slotv_jax.experiments.people_loop import rounds

    slots = rounds.PlanSlots(100, ("a", "b", "c"), (5, 6, 7, 8), runs=2, rounds=2, n_taus=2)
    blocks = [slots.block(i, r) for i in range(2) for r in range(2)]
    every = np.concatenate(blocks)
    assert every.min() == 100 and every.size == np.unique(every).size == slots.motions == 48
    assert slots.describe(99) is None
    assert slots.describe(int(slots.block(1, 0)[0])) == ("a", 0)
    assert slots.describe(int(slots.block(1, 0)[-1])) == ("c", 3)
    c = slots.draw(1, 1, 24, np.random.default_rng(0))  # all 3 × 4 × 2 of that block
    motions = c // 2
    assert np.unique(c).size == 24 and set(motions) == set(slots.block(1, 1))
    fams = [slots.describe(int(m))[0] for m in motions]
    assert fams[:6] == ["a", "b", "c"] * 2
    with pytest.raises(ValueError, match=r"k: expected 0\.\.24"):
        slots.draw(0, 0, 25, np.random.default_rng(0))
