"""From people's answers to motion people read: the whole loop, run and measured as one.

    python -m slotv_jax.experiments.people_loop                    # quick preset, CPU
    python -m slotv_jax.experiments.people_loop --preset paper     # the paper's MLP, a GPU
    python -m slotv_jax.experiments.people_loop --population homogeneous   # the sanity row

The people are simulated: a :class:`slotv_jax.observers.population.Population` (the
``default`` one: three viewpoints, three inference rules, log-normal temperatures, a
recency-weighted memory and lapses; or ``homogeneous``: everyone the dataset's Dragan
labeler; or a JSON file of the same fields). Every result below is a result on that
model of people, and says which.

Protocol, per population, seed and strategy (every step the library's public path):

1. **Ask.** Stimuli are dataset motions (the ``train`` split's first ``pool``) shown up to
   each stop time τ in ``taus`` (:func:`slotv_jax.asking.selection.make_pool`). Each asked
   stimulus gets ``per_stimulus`` answers, each from a fresh participant of the population
   (:func:`slotv_jax.observers.population.sample_guesses`; a stimulus gets the same answers
   under every strategy of a seed). Round 0 is drawn at random; after it, ``random`` keeps
   drawing at random and an active strategy (``margin``, ``error``, …) picks by an
   ensemble of ``select_family`` observers trained on the answers so far
   (:class:`slotv_jax.asking.selection.Selector`, warm-started from round to round).
2. **Learn.** After each size in ``sizes`` (answers), every family is fitted on the
   answers so far, prefixes included: the paper MLP, SLOT-V+ and the dragan and viewpoint
   archetypes by the count likelihood of the guesses (a fresh fit of ``epochs`` passes,
   at least ``min_updates`` updates); Dragan's and Nikolaidis' labelers by their β alone
   (:func:`slotv_jax.answers.crossval.fit_beta`): the baselines a researcher would use
   without slotv_jax.
3. **Plan.** Every fitted observer plans the held-out problems (scenes of
   ``position_test`` and ``goal_count_test``, which no round showed; every real goal a
   target) with the prefix objective, the mean over τ of log P(target | ξ_{0:τ})
   (:class:`slotv_jax.planning.PlannerConfig` ``taus``); so does the population itself
   (the oracle: its exact P_pop); the straight line is the floor. One compiled planner
   serves every family (a ``lax.switch`` over families) of every population and seed; the
   population's own plans are a second program, which takes the population as arrays
   (:func:`slotv_jax.observers.population.quadrature`), so it too serves every population,
   as do the simulated answers and the evaluation. The command keeps its compiled programs
   in ``CACHE/xla`` (JAX's persistent compilation cache) for the next run and workers.
   The two picks come last, from the answers and the fits alone: every candidate's plans
   are judged by every fit; ``pick_cross`` takes the plans the other fits judge best, and
   ``pick`` plans against the log-linear pool of the candidates weighted by their
   held-out likelihood, less the one whose plans the others judge least legible
   (:mod:`slotv_jax.answers.pooling`, :func:`slotv_jax.answers.pick.trusted`).
4. **Evaluate.** Each plan's score is the population's mean P_pop(target | ξ_{0:τ}) over
   the study's τ, averaged over problems; beside it an evaluation study of fresh
   participants (``eval_participants`` guesses per plan and τ): accuracy with a 95 %
   Wilson interval. **Gain kept** = (plan − straight) / (oracle − straight).

Writes ``OUT/people_loop[_paper]_results.json`` (``summary``: rows {population, family,
strategy, answers, gain_kept (mean over seeds), seeds}; the per-seed rows; the whole-motion
against prefix comparison; config, environment, timing), the Markdown report and figures
rendered from it (:mod:`slotv_jax.experiments.people_loop.report`). A rerun with another
``--population`` adds its rows to the same document; one already there is kept.

The package: :mod:`~slotv_jax.experiments.people_loop.config` (the families, the config and
its presets), :mod:`~slotv_jax.experiments.people_loop.loop` (the loop for one population:
ask, learn, plan, evaluate), this module (the results document: seeds and populations
accumulate, the example drawn), :mod:`~slotv_jax.experiments.people_loop.report` (the report)
and ``__main__`` (the command line).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import MutableMapping, Sequence
from pathlib import Path

import jax
import numpy as np

from slotv_jax import data as data_lib
from slotv_jax.core import fileio
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.people_loop import report as report_lib
from slotv_jax.experiments.people_loop.config import (  # noqa: F401  (the package's names)
    CAMERA,
    FAMILIES,
    FITTED,
    LEARNED,
    PRESETS,
    LoopConfig,
    paper,
    quick,
    tiny,
)
from slotv_jax.experiments.people_loop.loop import eval_keys, run_population  # noqa: F401
from slotv_jax.observers import people as people_lib
from slotv_jax.planning.plans import load_plans, save_plans

# ------------------------------------------------------------------ the document


def summarise(rows: Sequence[dict]) -> list[dict]:
    """:ref:`concepts-gain-kept`'s ``summary``: gain kept per (population, family, strategy,
    answers), the mean over seeds (and the seeds)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["population"], r["family"], r["strategy"], r["answers"]), []).append(r)
    return [
        {
            "population": p,
            "family": f,
            "strategy": s,
            "answers": a,
            "gain_kept": round(float(np.mean([r["gain_kept"] for r in rs])), 6),
            "gain_kept_sd": round(float(np.std([r["gain_kept"] for r in rs])), 6),
            "accuracy": round(float(np.mean([r["accuracy"] for r in rs])), 6),
            "seeds": len(rs),
        }
        for (p, f, s, a), rs in groups.items()
    ]


def stem_of(preset: str) -> str:
    return "people_loop" if preset == "quick" else f"people_loop_{preset}"


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a results document of this experiment (ours to extend)."""
    return fileio.is_json_object_with(path, ("preset", "config", "populations", "summary"))


SEED_FIELDS = ("seeds", "first_seed")  # which seeds ran: the rows say it, not the config


def run(
    cfg: LoopConfig,
    out: Path,
    populations: Sequence[str],
    *,
    cache: Path = Path("data"),
    progress: bool = True,
    processes: int = 1,
    jobs: dict[str, list[int]] | None = None,
    worker_flags: Sequence[str] = (),
) -> dict:
    """Run the loop for every (population, seed) not yet in ``OUT/STEM_results.json``, write
    the document after each population, then the report. Seeds accumulate: a run with other
    seeds of the same config adds its rows (one GPU call per seed at the paper preset).

    ``processes > 1`` spreads the (population, seed) runs over that many worker processes,
    dealt to the visible GPUs in turn (:func:`worker_gpus`: worker i on GPU i mod G, so more
    workers than GPUs share them; on a CPU they share its cores):
    each writes its own document under ``OUT/.people_loop_parts/``, merged into the results
    document as it finishes (a stopped run's finished parts are merged by the next). The
    workers take GPU memory as they use it (:func:`share_gpu_memory`); the caller's own
    process should too, from before its first JAX operation (the command sees to it).
    ``jobs`` ({population: seeds}) is a worker's own share (the parent passes it, with
    ``worker_flags``, the command-line flags that make the same config)."""
    stem = stem_of(cfg.preset)
    path = out / f"{stem}_results.json"
    conf = {k: v for k, v in cfg.to_json().items() if k not in SEED_FIELDS}
    doc = json.loads(path.read_text()) if path.exists() else {}
    if doc.get("config") != conf:
        doc = {"preset": cfg.preset, "config": conf, "populations": [], "summary": []}
    doc["populations"] = [p for p in doc["populations"] if not p.get("partial")]
    summary_before = doc["summary"]  # new rows may change the best family the example shows
    parts = out / PARTS
    if jobs is None and parts.is_dir():  # a stopped spread run: its finished parts
        _merge_parts(doc, conf, parts, path)
    wanted = range(cfg.first_seed, cfg.first_seed + cfg.seeds)
    entries = {p["population"]: p for p in doc["populations"]}
    todo = {}
    for spec in populations:
        have = {r["seed"] for r in entries.get(population_name(spec), {}).get("rows", [])}
        want = wanted if jobs is None else jobs.get(spec, [])
        if missing := [sd for sd in want if sd not in have]:
            todo[spec] = missing
    if not todo:  # say so: a recorded document makes the command return in seconds
        if jobs is None:
            print(
                f"people loop: {path} already holds every population and seed asked for; "
                "nothing ran, the report is drawn again (other --seeds/--first-seed, "
                "--population or --out run more)",
                file=sys.stderr,
            )
    else:
        ddir = data_lib.dataset_dir(cache, cfg.data)  # made once, before any worker starts
        splits = data_lib.generate_dataset(
            cfg.data,
            ddir,
            progress=progress,
            splits=("train", "position_test", "goal_count_test"),
        )
        doc["dataset"] = str(ddir)
    if todo and processes > 1 and sum(map(len, todo.values())) > 1:
        _spread(cfg, out, todo, processes, cache, progress, worker_flags)
        _merge_parts(doc, conf, parts, path)
    elif todo:
        for spec, seeds in todo.items():
            _run_one(cfg, doc, entries, path, spec, seeds, splits, progress)
    if todo and jobs is None:  # the suite's order, whichever worker finished first
        order = {name: i for i, name in enumerate(people_lib.expand(["suite", "zoo"]))}
        doc["populations"].sort(key=lambda p: order.get(p["population"], len(order)))
        _write_doc(path, doc)
    if jobs is None:
        report_lib.render(doc, out, stem)
        draw_example(doc, out, stem, again=doc["summary"] != summary_before)
    return doc


def _write_doc(path: Path, doc: dict) -> None:
    """The results document, without indentation: data; the report is its reading."""
    write_text(path, json.dumps(doc, separators=(",", ":")))


PARTS = ".people_loop_parts"  # the workers' documents of a spread run, inside --out


def _run_one(cfg, doc, entries, path, spec, seeds, splits, progress) -> None:
    """One population's seeds, added to ``doc`` (written after it)."""
    pop = people_lib.get_people(spec)
    name = people_lib.people_name(spec, pop)

    def save_partial(rows):  # a run stopped mid-way keeps its finished sizes
        part = {"population": name, "partial": True, "rows": rows}
        write_text(path, json.dumps({**doc, "populations": [*doc["populations"], part]}))

    got = run_population(cfg, name, pop, splits, seeds, progress=progress, on_size=save_partial)
    record = {
        "seeds": seeds,
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "environment": environment(),
        "timing": got.pop("timing"),
        "stimuli": got.pop("stimuli"),  # what each run asked about (seeds apart: per run)
    }
    _add(doc, entries, {**got, "runs": [record]})
    _write_doc(path, doc)


def _add(doc: dict, entries: dict, got: dict) -> None:
    """Add one population entry's rows and runs (seeds not yet there) to ``doc``."""
    name = got["population"]
    if name in entries:  # the comparison and example do not depend on the seed
        have = {r["seed"] for r in entries[name]["rows"]}
        new = [r for r in got["rows"] if r["seed"] not in have]
        if not new:
            return
        entries[name]["rows"] += new
        entries[name]["runs"] += got["runs"]
    else:
        entries[name] = got
        doc["populations"].append(got)
    doc["summary"] = summarise([r for q in doc["populations"] for r in q["rows"]])


def _spread(cfg, out, todo: dict, processes: int, cache, progress: bool, flags) -> None:
    """Deal the runs to ``processes`` workers and wait for all: a population's seeds stay on
    one worker (they run side by side in one program and share its compilations), the
    populations with the most seeds first, each to the least-loaded worker; with fewer
    populations than workers, their seeds are dealt one by one instead."""
    if len(todo) >= processes:
        shares: list[dict[str, list[int]]] = [{} for _ in range(processes)]
        for spec, seeds in sorted(todo.items(), key=lambda kv: -len(kv[1])):
            least = min(range(processes), key=lambda i: sum(map(len, shares[i].values())))
            shares[least][spec] = list(seeds)
    else:
        jobs = [(spec, sd) for spec, seeds in todo.items() for sd in seeds]
        shares = [{} for _ in range(min(processes, len(jobs)))]
        for j, (spec, sd) in enumerate(jobs):
            shares[j % len(shares)].setdefault(spec, []).append(sd)
    procs, gpus = [], worker_gpus(len(shares), visible_gpus())
    if None not in gpus and len(shares) > len(set(gpus)):  # on a CPU they share its cores
        print(
            f"people loop: {len(shares)} workers on {len(set(gpus))} GPU(s) take turns on "
            "them: four workers on one H200 ran the suite slower than one process "
            "(experiments/BENCHMARKS.md)",
            file=sys.stderr,
        )
    for i, share in enumerate(shares):
        d = out / PARTS / f"worker{i}"
        d.mkdir(parents=True, exist_ok=True)
        argv = [sys.executable, "-m", "slotv_jax.experiments.people_loop", *flags,
                "--population", ",".join(share), "--out", str(d), "--cache", str(cache),
                "--worker-jobs", json.dumps(share)]  # fmt: skip
        if not progress:
            argv.append("--no-progress")
        env = share_gpu_memory(dict(os.environ))
        if gpus[i] is not None:
            env["CUDA_VISIBLE_DEVICES"] = gpus[i]
        log = open(d / "log.txt", "w")
        procs.append((subprocess.Popen(argv, env=env, stdout=log, stderr=log), log, d))
    failed = []
    for proc, log, d in procs:
        proc.wait()
        log.close()
        if proc.returncode != 0:
            tail = (d / "log.txt").read_text().strip().splitlines()[-1:] or ["no output"]
            failed.append(f"{d.name}: {tail[0]}")
    if failed:
        raise RuntimeError("people loop: worker(s) failed: " + "; ".join(failed))


GPU_MEMORY_VARS = (  # how JAX takes GPU memory (docs.jax.dev, "GPU memory allocation")
    "XLA_PYTHON_CLIENT_PREALLOCATE",
    "XLA_PYTHON_CLIENT_MEM_FRACTION",
    "XLA_CLIENT_MEM_FRACTION",
    "XLA_PYTHON_CLIENT_ALLOCATOR",
)


def share_gpu_memory(env: MutableMapping[str, str]) -> MutableMapping[str, str]:
    """``env`` with ``XLA_PYTHON_CLIENT_PREALLOCATE=false`` unless it already says how JAX
    takes GPU memory (:data:`GPU_MEMORY_VARS`, the user's choice is kept): a spread run's
    processes take what they use. By default JAX takes 75 % of every visible GPU at its
    first operation, so the parent (which makes the dataset) leaves its workers none: on an
    H200 every worker then failed with ``RESOURCE_EXHAUSTED`` (experiments/BENCHMARKS.md).
    The parent's own must be set before its first JAX operation (the command does so)."""
    if not any(v in env for v in GPU_MEMORY_VARS):
        env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"
    return env


def visible_gpus() -> list[str]:
    """The GPUs this process sees, as ``CUDA_VISIBLE_DEVICES`` names them (its list where
    it is set, else 0 … G−1); empty where JAX runs on another backend."""
    if jax.default_backend() != "gpu":
        return []
    n = jax.local_device_count()
    named = [s.strip() for s in os.environ.get("CUDA_VISIBLE_DEVICES", "").split(",")]
    named = [s for s in named if s]
    return named[:n] if len(named) >= n else [str(i) for i in range(n)]


def worker_gpus(processes: int, gpus: Sequence[str]) -> list[str | None]:
    """Worker i's ``CUDA_VISIBLE_DEVICES``: ``gpus[i mod G]``, the GPUs in turn (several
    workers a GPU when there are more workers than GPUs); None for every worker without a
    GPU (they share the CPU's cores)."""
    return [gpus[i % len(gpus)] if gpus else None for i in range(processes)]


def _merge_parts(doc: dict, conf: dict, parts: Path, path: Path) -> None:
    """Merge every worker document of the same config under ``parts`` into ``doc``, write
    it, then remove the merged documents (the project's own files)."""
    entries = {p["population"]: p for p in doc["populations"]}
    merged = []
    for f in sorted(parts.glob("worker*/*_results.json")):
        part = json.loads(f.read_text())
        if part.get("config") != conf:
            continue
        for p in part["populations"]:
            if not p.get("partial"):
                _add(doc, entries, p)
        doc.setdefault("dataset", part.get("dataset"))
        merged.append(f)
    _write_doc(path, doc)
    for f in merged:
        f.unlink()
    for d in parts.glob("worker*"):  # every document merged: the workers' logs go too
        if d.is_dir() and not list(d.glob("*_results.json")):
            (d / "log.txt").unlink(missing_ok=True)
            if not any(d.iterdir()):
                d.rmdir()
    if parts.is_dir() and not any(parts.iterdir()):
        parts.rmdir()


def example_plans(doc: dict) -> dict[str, np.ndarray]:
    """The first population's example problem as a plans file
    (:mod:`slotv_jax.planning.plans`; ``python -m slotv_jax.render --plans``)."""
    ex = doc["populations"][0]["example"]
    names = list(ex["q"])
    return {
        "goals": np.asarray(ex["problem"]["goals"], np.float32)[None],
        "goal_mask": np.asarray(ex["problem"]["goal_mask"], bool)[None],
        "target": np.asarray([ex["problem"]["target"]], np.int32),
        "names": np.asarray(names),
        "q": np.stack([np.asarray(ex["q"][n], np.float32) for n in names])[:, None],
    }


def draw_example(doc: dict, out: Path, stem: str, *, again: bool = False) -> None:
    """Write ``STEM_plans.npz`` and draw ``STEM_render.png`` from it with the render command
    (in its own process: the loop itself needs no OpenGL); without OpenGL, say so in one
    line and go on. A drawing beside plans equal to the document's example is kept (a
    rerun that computed nothing: drawing it again takes 10-15 s on a CPU and gives the same
    picture), unless ``again`` (``--report``, or new rows: the family that keeps the most
    gain, which the drawing shows, may have changed)."""
    plans = out / f"{stem}_plans.npz"
    example = example_plans(doc)
    if not again and (out / f"{stem}_render.png").is_file() and _same_plans(plans, example):
        return
    save_plans(plans, example)
    best = report_lib.best_family(doc, doc["populations"][0])
    cmd = [sys.executable, *report_lib.render_command(stem, out, best)[1:]]
    r = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if r.returncode != 0:
        last = (r.stderr.strip().splitlines() or ["no output"])[-1]
        print(
            f"people loop: the example was not drawn ({last}); draw it with: "
            f"{' '.join(report_lib.render_command(stem, out, best))}",
            file=sys.stderr,
        )


def _same_plans(path: Path, plans: dict[str, np.ndarray]) -> bool:
    """Whether the plans file ``path`` holds exactly ``plans`` (False if it cannot be read)."""
    try:
        held = load_plans(path)
    except (OSError, ValueError):
        return False
    want = {k: np.asarray(v) for k, v in plans.items()}
    return set(held) == set(want) and all(
        held[k].dtype == v.dtype and np.array_equal(held[k], v, equal_nan=v.dtype.kind == "f")
        for k, v in want.items()
    )


def population_name(spec: str) -> str:
    """The ``population`` value of ``spec``'s rows: ``default``, ``homogeneous``,
    ``random:K``, a JSON file's stem, or a zoo member's name
    (:func:`slotv_jax.observers.people.people_name`)."""
    return people_lib.people_name(spec, people_lib.get_people(spec))
