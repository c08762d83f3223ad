"""How much of people's answers each family learns: ``python -m
slotv_jax.experiments.people_loop.learned``.

The people loop scores plans; this scores fits. For each people (a population, a zoo
member, your own ``module:function``) and seed, the loop's simulated study asks random
stimuli of its pool (the first draws of
:func:`slotv_jax.experiments.people_loop.loop.run_population`'s protocol); every trained
family of the preset is fitted on the first 1,000 and 2,000 answers as the loop fits it
(:func:`~slotv_jax.experiments.people_loop.loop.fit_family`; the motion reader from its
prior, :mod:`slotv_jax.answers.prior`), and each fit predicts :data:`TEST_MOTIONS` pool
motions no answer was about, seen up to every stop time. The measure is the expected NLL
per answer under the people's own guess distribution P (exact: no sampled answers),

    NLL(f) = −mean over test stimuli of Σ_k P(k | ξ_{0:τ}) log p_f(k | ξ_{0:τ}),

against uniform guessing's (Σ_k P log n_goals) and the people's own, H(P) (the least any
fit can reach), as the share of the way closed:

    closed(f) = (NLL(uniform) − NLL(f)) / (NLL(uniform) − H(P))

``reader_prior`` is the reader's prior alone, before any answer. Writes
``OUT/answers_learned_PRESET.json`` and ``.md``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from tqdm.auto import tqdm

from slotv_jax import data as data_lib
from slotv_jax.asking import selection, simulated
from slotv_jax.core import cli, fileio, validation
from slotv_jax.core.environment import environment
from slotv_jax.experiments.people_loop import loop
from slotv_jax.experiments.people_loop.config import PRESETS, READER, TRAINED, LoopConfig
from slotv_jax.observers import people as people_lib
from slotv_jax.observers import population as population_lib
from slotv_jax.observers import zoo

TEST_MOTIONS = 1000  # pool motions held out of every answer, each at every stop time
PRIOR = "reader_prior"  # the reader's prior alone


def people_observer(people: people_lib.People):
    """The people's own ``prefix(xyz, goals, goal_mask, seen) -> log P``."""
    if isinstance(people, zoo.ZooMember):
        return people
    return population_lib.population_observer(people)


def expected_nll(p: np.ndarray, logq: np.ndarray, mask: np.ndarray) -> float:
    """−mean_rows Σ_k p_k log q_k over the real goals (float64)."""
    logq = np.where(mask, np.asarray(logq, np.float64), 0.0)
    return float(-np.mean(np.sum(np.where(mask, p * logq, 0.0), -1)))


def measure(cfg: LoopConfig, name: str, people, splits, seed: int, sizes: Sequence[int]) -> list:
    """The rows of one people and seed (module docstring)."""
    xyz, goals, mask = loop.pool_motions(cfg, splits["train"])
    pool = selection.make_pool(xyz, goals, mask, cfg.taus)
    n_taus, per, g = len(cfg.taus), cfg.per_stimulus, int(pool.goals.shape[1])
    rows = [s // per for s in sizes]
    n_c = int(pool.traj.shape[0])
    order = np.random.default_rng([seed, 1]).choice(n_c, rows[-1], replace=False)
    asked = set(np.asarray(pool.traj)[order].tolist())
    free = np.setdiff1d(np.arange(xyz.shape[0]), np.fromiter(asked, int))
    test_m = np.random.default_rng([seed, 4]).choice(free, min(TEST_MOTIONS, free.size), False)
    test = (test_m[:, None] * n_taus + np.arange(n_taus)).ravel().astype(np.int32)
    counts = simulated.population_answers(people, seed, pool, order, per)
    t_idx = np.asarray(pool.traj)[test]
    m_test = np.asarray(pool.goal_mask)[t_idx][:, :g]
    own = people_observer(people)
    p_own = np.asarray(
        jax.jit(jax.vmap(lambda x, gg, m, s: jax.nn.softmax(own.prefix(x, gg, m, s))))(
            pool.xyz[t_idx], pool.goals[t_idx], pool.goal_mask[t_idx], pool.seen[test]
        ),
        np.float64,
    )[:, :g]
    n_goals = m_test.sum(-1, keepdims=True)
    uniform = expected_nll(p_own, np.broadcast_to(-np.log(n_goals), p_own.shape), m_test)
    entropy = expected_nll(p_own, np.log(np.maximum(p_own, 1e-300)), m_test)
    inits = {}
    if READER in cfg.families:
        camera = people_lib.study_camera(people)
        inits[READER] = loop.reader_prior(cfg, splits["train"], name, camera)
    cand = order[None].astype(np.int32)
    c_all = counts[None].astype(np.float32)
    out = []

    def row(family, n_ans, logq):
        nll = expected_nll(p_own, logq, m_test)
        return {
            "people": name, "seed": seed, "answers": n_ans, "family": family,
            "nll": round(nll, 6), "uniform_nll": round(uniform, 6),
            "own_nll": round(entropy, 6),
            "closed": round((uniform - nll) / (uniform - entropy), 6),
        }  # fmt: skip

    def scores(family, params):
        sel = selection.make_selector(cfg.train_config(family), 1, 1)
        p1 = jax.tree.map(lambda x: x[None], params)
        return np.asarray(loop._scorer(sel)(p1, pool, jnp.asarray(test))[0])[:, :g]

    if READER in cfg.families:
        out.append(row(PRIOR, 0, scores(READER, inits[READER])))
    for n_rows, n_ans in zip(rows, sizes, strict=True):
        for fam in [f for f in cfg.families if f in TRAINED]:
            params = loop.fit_family(cfg, fam, pool, cand, c_all, n_rows, [seed], inits)
            out.append(row(fam, n_ans, scores(fam, jax.tree.map(lambda x: x[0], params))))
    return out


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a document of this experiment (ours to write again)."""
    return fileio.is_json_object_with(path, ("preset", "sizes", "families", "rows"))


def report(rows: Sequence[dict], preset: str, seconds: float) -> str:
    """The Markdown table: each people's share closed by each family at each size."""
    fams = list(dict.fromkeys(r["family"] for r in rows))
    people = list(dict.fromkeys(r["people"] for r in rows))
    sizes = sorted({r["answers"] for r in rows if r["answers"]})
    lines = [
        f"# How much of the answers each family learns ({preset} preset)",
        "",
        "Share of the way from uniform guessing's expected NLL to the people's own (their "
        "entropy) that each fit closes on held-out stimuli, mean over seeds "
        "(`python -m slotv_jax.experiments.people_loop.learned`). "
        f"{seconds:.0f} s in all.",
        "",
    ]
    for n in sizes:
        lines += [f"## {n} answers", "", "| people | " + " | ".join(fams) + " |",
                  "|---|" + "---|" * len(fams)]  # fmt: skip
        for p in people:
            cells = []
            for f in fams:
                v = [r["closed"] for r in rows if r["people"] == p and r["family"] == f
                     and r["answers"] in (n, 0)]  # fmt: skip
                cells.append(f"{100 * np.mean(v):.0f} %" if v else "")
            lines.append(f"| {p} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    ap = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.people_loop.learned",
        description="How much of people's answers each observer family learns: held-out "
        "expected NLL against uniform guessing and the people's own model.",
    )
    ap.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    ap.add_argument("--population", default="zoo", help="as the people loop's --population")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument(
        "--families",
        default=None,
        help="comma-separated trained families (default: the preset's: "
        + ", ".join(f for f in PRESETS["quick"]().families if f in TRAINED)
        + ")",
    )
    ap.add_argument("--sizes", default="1000,2000", help="answers of the fits, comma-separated")
    ap.add_argument("--out", default="experiments")
    ap.add_argument("--cache", default="data", help="where datasets are cached")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    cfg = PRESETS[args.preset]()
    if args.families is not None:
        fams = tuple(f.strip() for f in args.families.split(",") if f.strip())
        bad = [f for f in fams if f not in TRAINED]
        if bad or not fams:
            raise ValueError(f"--families: expected names of {TRAINED}, got {args.families!r}")
        cfg = dataclasses.replace(cfg, families=fams)
    try:
        sizes = tuple(int(s) for s in args.sizes.split(",") if s.strip())
    except ValueError:
        raise ValueError(f"--sizes: expected integers, got {args.sizes!r}") from None
    per = cfg.per_stimulus
    if (
        not sizes
        or list(sizes) != sorted(set(sizes))
        or min(sizes) < per
        or any(s % per for s in sizes)
    ):
        raise ValueError(f"--sizes: expected increasing multiples of {per}, got {sizes}")
    validation.check_seeds("--seeds", 0, args.seeds, count_name="--seeds")
    specs = people_lib.expand(args.population.split(","))
    people = {s: people_lib.get_people(s) for s in specs}  # every name checked first
    out = Path(args.out)
    stem = f"answers_learned_{args.preset}"
    names = [f"{stem}.json", f"{stem}.md"]  # another's file of these names is refused
    fileio.check_output_files(out, names, ours={names[0]: is_results}, beside=names[0])
    splits = data_lib.generate_dataset(
        cfg.data, data_lib.dataset_dir(args.cache, cfg.data), progress=not args.no_progress,
        splits=("train",),
    )  # fmt: skip
    out.mkdir(parents=True, exist_ok=True)
    t0, rows = time.perf_counter(), []
    todo = [(s, sd) for s in specs for sd in range(args.seeds)]
    for s, sd in tqdm(todo, desc="answers learned", disable=args.no_progress):
        name = people_lib.people_name(s, people[s])
        rows += measure(cfg, name, people[s], splits, sd, sizes)
        seconds = time.perf_counter() - t0  # the document so far, after every people and seed
        doc = {"preset": args.preset, "sizes": list(sizes), "families": list(cfg.families),
               "rows": rows, "seconds": round(seconds, 1),
               "environment": environment()}  # fmt: skip
        fileio.write_text(out / f"{stem}.json", json.dumps(doc, indent=1))
        fileio.write_text(out / f"{stem}.md", report(rows, args.preset, seconds))
    print(report(rows, args.preset, time.perf_counter() - t0))
    return 0


if __name__ == "__main__":
    sys.exit(main())
