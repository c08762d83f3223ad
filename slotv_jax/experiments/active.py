"""Active selection of stimuli: how many answers does each strategy need?

The paper's second limitation (§VI): SLOT-V needs "about 10,000 unique examples" for
80 %, and "it would be interesting to see if this number can be reduced … by more
intelligently sampling trajectories". This experiment runs pool-based active learning
(:mod:`slotv_jax.asking.selection`) with each strategy, side by side, in two settings:

- ``labels`` (the paper's): the pool is the ``train`` split, an answer is the
  hand-crafted labeler's distribution of a whole motion (Dragan, Nikolaidis), the
  observer the paper's SLOT-V network, the target 80 % on ``trajectory_val`` (its first
  ``eval_size`` trajectories, SPEC §8 accuracy);
- ``study`` (simulated participants, as in ``study_size``): each selected motion is
  shown to ``participants`` simulated people who guess by sampling the labeler's
  distribution (Dragan); the observers are the paper's MLP, SLOT-V+ (start term and time
  weights) and the Dragan archetype; the target a held-out accuracy on ``position_test``
  against the noise-free labeler.

Protocol (every strategy and seed of a group in one vmapped call per step):

1. round 0: ``sizes[0]`` motions drawn at random, the same for every strategy of a seed;
2. each round trains the ensemble (E = ``members``: member 0 a plain run, the others
   bootstrapped; warm start) more updates of ``batch_size`` answer rows: blocks of
   ``updates`` (study: ``study_updates``), as many as pass ``round_epochs`` times over the
   answers so far (:meth:`ActiveConfig.round_updates`), and records member 0's held-out
   accuracy against the number of answers so far;
3. the strategy scores ``subset`` motions drawn from the unasked part of the pool (the
   same draw for every strategy of a seed) and asks about the next ``sizes[r+1] −
   sizes[r]``.

Strategies and seeds share what they can (initialisation, seed set, candidate subsets,
the participants' answers to each motion), so the curves differ by the selection. The
answers a run needs for the target: the first round whose accuracy reaches it,
interpolated linearly in log answers from the round before; the mean over seeds is
``answers_to_target`` (null when a seed never reaches it within the largest size).
Choices of protocol are tried on other seeds and held-out motions than the reported
ones (``--first-seed``, ``--eval-offset``).

    python -m slotv_jax.experiments.active                  # quick (CPU, minutes)
    python -m slotv_jax.experiments.active --preset paper   # the paper's network (GPU)

Writes ``OUT/active{,_paper}_results.json`` (config, curves, ``comparisons``, timings;
a rerun resumes finished groups), ``.md`` and ``.png``, rendered from the JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import math
import os
import platform
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.asking import selection
from slotv_jax.core import cli, fileio
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.active_report import ORACLES, fmt_answers, render, stem_of, summarise
from slotv_jax.training import config as train_config
from slotv_jax.training import evaluate
from slotv_jax.training import trainer as train

# Oracles (ORACLES, defined beside the report, which keeps them apart): criteria that read
# the labels of the candidates (the labeler's noise-free guess distribution y), which no
# study has before it asks. They are not strategies but bounds on what a criterion of the
# observer's own could reach:
# - ``oracle_loss``: the k candidates of largest cross-entropy −Σ_g y_g log p_g of member 0
#   (the observer's worst mistakes, known);
# - ``oracle_margin``: the k candidates of smallest gap between the labeler's two most likely
#   goals (the true decision boundary, known).


def oracle_score(
    name: str, logp0: Float[Array, "C G"], labels: Float[Array, "C G"]
) -> Float[Array, " C"]:
    """Score of an oracle (higher: ask first) from member 0's log probabilities log p_g
    (−∞ on padded goals) and the labeler's distributions y (0 on padded goals):
    ``oracle_loss`` the cross-entropy −Σ_g y_g log p_g, ``oracle_margin`` the labeler's
    margin 1 − (y_(1) − y_(2)) (Scheffer et al. 2001, with the true distribution)."""
    if name == "oracle_loss":
        return -jnp.sum(jnp.where(labels > 0, labels * logp0, 0.0), -1)
    if name == "oracle_margin":
        top2 = jax.lax.top_k(labels, 2)[0]
        return 1.0 - (top2[:, 0] - top2[:, 1])
    raise ValueError(f"strategy: expected one of {ORACLES}, got {name!r}")


@dataclasses.dataclass(frozen=True)
class ActiveConfig:
    """One active-selection experiment (module docstring)."""

    preset: str
    data: data_lib.DataConfig
    train_preset: str  # slotv_jax.config preset of the observers
    labels_labelers: tuple[str, ...]  # the labels setting's labelers (paper MLP)
    study_models: tuple[str, ...]  # the study setting's observers: mlp, slotv_plus, dragan
    label_sizes: tuple[int, ...]  # labelled motions after each round (labels setting)
    study_sizes: tuple[int, ...]  # motions asked after each round (study setting)
    updates: int  # least updates per round of the labels setting (warm start), a block
    study_updates: int  # the same for the study setting (one guess per answer: noisier)
    participants: int  # simulated answers per motion (study setting)
    study_targets: tuple[tuple[str, float], ...]  # held-out accuracy target per model
    strategies: tuple[str, ...] = selection.STRATEGIES + ORACLES  # oracles: bounds
    seeds: int = 3
    first_seed: int = 0  # seeds first_seed … first_seed + seeds − 1 (tuning runs use others)
    round_epochs: float = 0.0  # each round passes this often over the answers so far (≥ updates)
    members: int = 4  # ensemble size E
    subset: int = 1000  # candidates scored per run and round
    stride: int = 1  # keep every stride-th point of each motion (1: all)
    study_labeler: str = "dragan"
    labels_target: float = 0.8
    eval_size: int = 1000
    eval_offset: int = 0  # held-out motions eval_offset … + eval_size (tuning runs use others)
    chunk: int = 256  # candidates per scoring chunk
    overrides: tuple[str, ...] = ()  # TrainConfig key=value overrides (MLP models)

    def __post_init__(self):
        for name in ("label_sizes", "study_sizes"):
            sizes = getattr(self, name)
            if len(sizes) < 2 or list(sizes) != sorted(set(sizes)) or sizes[0] < 1:
                raise ValueError(f"{name}: expected at least 2 increasing sizes, got {sizes}")
            k_max = max(b - a for a, b in itertools.pairwise(sizes))
            if self.subset < 2 * k_max:
                raise ValueError(
                    f"subset: expected at least twice the largest batch ({k_max} in {name}), "
                    f"got {self.subset}"
                )
        bad = [s for s in self.strategies if s not in selection.STRATEGIES + ORACLES]
        if bad or "random" not in self.strategies:
            raise ValueError(
                f"strategies: expected 'random' and names of {selection.STRATEGIES + ORACLES}"
            )
        if self.round_epochs < 0 or self.updates < 1 or self.study_updates < 1:
            raise ValueError("updates, study_updates: expected >= 1; round_epochs: >= 0")
        missing = [m for m in self.study_models if m not in dict(self.study_targets)]
        if missing:
            raise ValueError(f"study_targets: no target for {missing}")

    def train_config(self, model: str) -> train_config.TrainConfig:
        if model == "dragan":
            return train_config.archetype(self.train_preset, "dragan", train_size=None)
        cfg = train_config.preset(self.train_preset, "slotv", train_size=None)
        if model == "slotv_plus":
            cfg = dataclasses.replace(cfg, start_term=True, time_weight=True)
        elif model != "mlp":
            raise ValueError(f"model: expected mlp, slotv_plus or dragan, got {model!r}")
        return train_config.apply_overrides(cfg, self.overrides)

    def round_updates(self, setting: str, size: int) -> int:
        """Updates of round with ``size`` answer rows: the smallest multiple of the block
        (``updates``, study ``study_updates``) that passes ``round_epochs`` times over the
        rows (warm start: every round trains until the answers so far are fitted, not a
        fixed budget that the largest sizes outgrow)."""
        block = self.updates if setting == "labels" else self.study_updates
        batch = self.train_config("mlp").batch_size
        return block * max(1, math.ceil(self.round_epochs * size / (batch * block)))

    def groups(self) -> list[tuple[str, str, str]]:
        """(setting, labeler, model) of every group, in run order."""
        return [("labels", lab, "mlp") for lab in self.labels_labelers] + [
            ("study", self.study_labeler, m) for m in self.study_models
        ]

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["train"] = {m: self.train_config(m).to_dict() for m in {"mlp", *self.study_models}}
        return json.loads(json.dumps(d))


def geometric(start: int, stop: int, ratio: float) -> tuple[int, ...]:
    """Sizes start, ≈ start·ratio, … up to stop (rounded, distinct)."""
    n = math.floor(math.log(stop / start) / math.log(ratio) + 1e-9) + 1
    return tuple(sorted({round(start * ratio**i) for i in range(n)}))


def up_to(sizes: Sequence[int], stop: int) -> tuple[int, ...]:
    """``sizes`` cut at ``stop``, or continued by their last ratio up to it.

    >>> up_to((8, 11, 16), 23), up_to((16, 32, 64), 300), up_to((16, 32, 64), 40)
    ((8, 11, 16, 23), (16, 32, 64, 128, 256), (16, 32))
    """
    out = [s for s in sizes if s <= stop]
    if len(out) == len(sizes):
        ratio = sizes[-1] / sizes[-2]
        while round(out[-1] * ratio) <= stop:
            out.append(round(out[-1] * ratio))
    return tuple(out)


def quick(**overrides) -> ActiveConfig:
    """CPU preset: the quick dataset, hidden 64/32 networks on every 4th point, E = 3, up to
    256 motions; study targets 75 % (the quick network's budget, ``study_size``)."""
    base = ActiveConfig(
        preset="quick",
        data=data_lib.quick(),
        train_preset="quick",
        labels_labelers=("dragan", "nikolaidis"),
        study_models=("mlp", "slotv_plus", "dragan"),
        label_sizes=geometric(16, 256, 2.0),
        study_sizes=geometric(16, 256, 2.0),
        updates=100,
        study_updates=100,
        participants=20,
        study_targets=(("mlp", 0.75), ("slotv_plus", 0.75), ("dragan", 0.9)),
        members=3,
        stride=4,
        subset=1024,
        round_epochs=4.0,
    )
    return dataclasses.replace(base, **overrides)


def paper(**overrides) -> ActiveConfig:
    """GPU preset: the paper's dataset and SLOT-V network (1536/768, bfloat16 matmuls) on
    every point, E = 3."""
    base = ActiveConfig(
        preset="paper",
        data=data_lib.paper(),
        train_preset="paper",
        labels_labelers=("dragan", "nikolaidis"),
        study_models=("mlp", "slotv_plus", "dragan"),
        label_sizes=geometric(8, 1024, math.sqrt(2)),
        study_sizes=geometric(8, 2048, math.sqrt(2))[:-1],  # 8 … 1,448
        updates=100,
        study_updates=300,
        round_epochs=4.0,
        participants=20,
        study_targets=(("mlp", 0.8), ("slotv_plus", 0.8), ("dragan", 0.9)),
        strategies=("random", "uncertainty", "margin", "bald", "bald_cluster", "epig", *ORACLES),
        seeds=5,
        members=3,
        subset=8192,
        eval_size=3000,
        chunk=64,
        overrides=("compute_dtype=bfloat16",),
    )
    return dataclasses.replace(base, **overrides)


PRESETS = {"quick": quick, "paper": paper}


# ------------------------------------------------------------------- running


def motion_arrays(split, labeler: str, stride: int, n: int | None = None):
    """(xyz (N, T', 3), goals (N, G, 3), goal_mask (N, G), labels (N, G)) of the first ``n``
    motions of a split (all: None), on every ``stride``-th point and always the last."""
    d = train.prepare(split, labeler)
    cut = slice(None) if n is None else slice(0, n)
    xyz = np.asarray(d.xyz[cut])
    # every stride-th point, always keeping the last (the motion's end)
    pts = np.unique(np.r_[np.arange(0, xyz.shape[1], stride), xyz.shape[1] - 1])
    return (
        xyz[:, pts],
        np.asarray(d.goals[cut]),
        np.asarray(d.goal_mask[cut]),
        np.asarray(d.labels[cut]),
    )


def _guesses(seed: int, probs: np.ndarray, mask: np.ndarray, participants: int) -> np.ndarray:
    """(C, G) counts: ``participants`` guesses per motion sampled from ``probs`` (one
    random stream per seed: every strategy of a seed gets the same answers)."""
    rng = np.random.default_rng([seed, 7])
    u = rng.random((probs.shape[0], participants))
    cdf = np.cumsum(np.where(mask, probs, 0.0), -1)
    cdf = cdf / cdf[:, -1:]
    guess = np.minimum((u[..., None] >= cdf[:, None, :]).sum(-1), mask.sum(-1)[:, None] - 1)
    counts = np.zeros(probs.shape, np.float32)
    np.add.at(counts, (np.arange(probs.shape[0])[:, None], guess), 1.0)
    return counts


def run_group(
    cfg: ActiveConfig, splits, setting: str, labeler: str, model: str, *, progress: bool = True
) -> dict:
    """Every strategy × seed of one (setting, labeler, model) group; returns its curves."""
    tc = cfg.train_config(model)
    sizes = cfg.label_sizes if setting == "labels" else cfg.study_sizes
    eval_split = "trajectory_val" if setting == "labels" else "position_test"
    xyz, goals, mask, probs = motion_arrays(splits["train"], labeler, cfg.stride)
    pool = selection.make_pool(xyz, goals, mask)
    exyz, egoals, emask, elabels = motion_arrays(
        splits[eval_split], labeler, cfg.stride, cfg.eval_offset + cfg.eval_size
    )
    exyz, egoals, emask, elabels = (a[cfg.eval_offset :] for a in (exyz, egoals, emask, elabels))
    if exyz.shape[0] != cfg.eval_size:
        raise ValueError(
            f"eval_offset, eval_size: {eval_split} holds {cfg.eval_offset + exyz.shape[0]} "
            f"motions, asked for {cfg.eval_offset} + {cfg.eval_size}"
        )
    evpool = selection.make_pool(exyz, egoals, emask)
    etarget = np.asarray(evaluate.target(jnp.asarray(elabels), jnp.asarray(emask)))
    n_pool, per = pool.traj.shape[0], 1 if setting == "labels" else cfg.participants
    if sizes[-1] > n_pool:
        raise ValueError(f"sizes: {sizes[-1]} motions asked, the pool holds {n_pool}")
    seeds = range(cfg.first_seed, cfg.first_seed + cfg.seeds)
    runs = [(s, seed) for s in cfg.strategies for seed in seeds]
    n_runs, cap, g = len(runs), sizes[-1], probs.shape[1]
    sel = selection.make_selector(tc, cfg.members, cap)
    seed_keys = {seed: jax.random.key(1000 + seed) for seed in seeds}
    ens = jax.jit(jax.vmap(sel.init))(jnp.stack([seed_keys[sd] for _, sd in runs]))
    answers_all = {
        sd: probs.astype(np.float32)
        if setting == "labels"
        else _guesses(sd, probs, mask, cfg.participants)
        for sd in seeds
    }
    cand = np.zeros((n_runs, cap), np.int32)
    counts = np.zeros((n_runs, cap, g), np.float32)
    asked = np.zeros((n_runs, n_pool), bool)
    for i, (_, sd) in enumerate(runs):
        first = np.random.default_rng([sd, 1]).choice(n_pool, sizes[0], replace=False)
        cand[i, : sizes[0]] = first
        asked[i, first] = True
    updates = cfg.updates if setting == "labels" else cfg.study_updates  # one block
    fit = jax.jit(jax.vmap(lambda e, a, k: sel.fit(e, pool, a, k, updates=updates)))
    evc = jnp.arange(evpool.traj.shape[0])
    acc_fn = jax.jit(
        jax.vmap(
            lambda p: jnp.argmax(
                sel.log_probs(jax.tree.map(lambda x: x[:1], p), evpool, evc, chunk=cfg.chunk)[0], -1
            )
        )
    )
    score = jax.jit(jax.vmap(lambda p, c: sel.log_probs(p, pool, c, chunk=cfg.chunk)))
    k_max = max(b - a for a, b in itertools.pairwise(sizes))

    def picker(s):  # (key, log p (E, C, G), available (C,), labels (C, G)) -> k_max picks
        if s in ORACLES:
            return lambda k, lp, av, y: selection.masked_top_k(oracle_score(s, lp[0], y), av, k_max)
        return lambda k, lp, av, y: selection.select(s, k, lp, av, k_max)

    pickers = {s: jax.jit(jax.vmap(picker(s))) for s in cfg.strategies}
    acc = np.zeros((n_runs, len(sizes)))
    times = {"fit_s": 0.0, "score_s": 0.0, "select_s": 0.0, "eval_s": 0.0}
    bar = tqdm(
        total=len(sizes),
        desc=f"{setting}/{labeler}/{model}",
        unit="round",
        disable=not progress,
        leave=False,
    )
    for r, size in enumerate(sizes):
        for i, (_, sd) in enumerate(runs):
            counts[i, :size] = answers_all[sd][cand[i, :size]]
        ans = selection.Answers(
            jnp.asarray(cand), jnp.asarray(counts), jnp.full((n_runs,), size, jnp.int32)
        )
        keys = jnp.stack([jax.random.fold_in(seed_keys[sd], 100 + r) for _, sd in runs])
        t0 = time.perf_counter()
        for j in range(cfg.round_updates(setting, size) // updates):
            kj = keys if j == 0 else jax.vmap(lambda k, j=j: jax.random.fold_in(k, 10 + j))(keys)
            ens, _ = fit(ens, ans, kj)
        jax.block_until_ready(ens.params)
        t1 = time.perf_counter()
        pred = np.asarray(acc_fn(ens.params))
        acc[:, r] = (pred == etarget[None]).mean(-1)
        t2 = time.perf_counter()
        times["fit_s"] += t1 - t0
        times["eval_s"] += t2 - t1
        bar.update(1)
        if r + 1 == len(sizes):
            break
        k = sizes[r + 1] - size
        sub = np.zeros((n_runs, cfg.subset), np.int32)
        for i, (_, sd) in enumerate(runs):  # the same subset for every strategy of a seed
            free = np.flatnonzero(~asked[i])
            sub[i] = np.random.default_rng([sd, 2, r]).choice(
                free, min(cfg.subset, free.size), replace=False
            )
        t0 = time.perf_counter()
        logp = score(ens.params, jnp.asarray(sub))
        jax.block_until_ready(logp)
        t1 = time.perf_counter()
        pick = np.zeros((n_runs, k_max), np.int32)
        for s, fn in pickers.items():
            idx = [i for i, run in enumerate(runs) if run[0] == s]
            pk = jnp.stack([jax.random.fold_in(keys[i], 1) for i in idx])
            avail = jnp.ones((len(idx), cfg.subset), bool)
            y = jnp.asarray(probs[sub[idx]]) if s in ORACLES else jnp.zeros((len(idx),))
            pick[idx] = np.asarray(fn(pk, logp[np.asarray(idx)], avail, y))
        times["score_s"] += t1 - t0
        times["select_s"] += time.perf_counter() - t1
        for i in range(n_runs):
            new = sub[i, pick[i, :k]]
            assert not asked[i, new].any() and np.unique(new).size == k
            cand[i, size : size + k] = new
            asked[i, new] = True
    bar.close()
    return {
        "setting": setting,
        "labeler": labeler,
        "model": model,
        "answers": [int(s * per) for s in sizes],
        "motions": list(sizes),
        "runs": [
            {"strategy": s, "seed": sd, "accuracy": acc[i].round(6).tolist()}
            for i, (s, sd) in enumerate(runs)
        ],
        "timing": {k: round(v, 2) for k, v in times.items()},
    }


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a results document of this experiment (ours to resume)."""
    return fileio.is_json_object_with(path, ("preset", "config", "groups"))


def run(
    cfg: ActiveConfig,
    out: Path,
    *,
    cache: Path = Path("data"),
    progress: bool = True,
    only: Sequence[tuple[str, str, str]] | None = None,
):
    """Run (or resume) every group (or the groups ``only``); returns the results document
    (also written after each group)."""
    stem = stem_of(cfg.preset)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{stem}_results.json"
    conf = cfg.to_json()
    doc = json.loads(path.read_text()) if path.exists() else {}
    if doc.get("config") != conf:
        doc = {"preset": cfg.preset, "config": conf, "groups": [], "timing": {}}
    done = {(g["setting"], g["labeler"], g["model"]) for g in doc["groups"]}
    todo = [g for g in cfg.groups() if g not in done and (only is None or g in only)]
    t_start = time.perf_counter()
    load = {"cpus": os.cpu_count(), "start": os.getloadavg()[0]}
    if todo:  # a finished document is only summarised again (where it ran, as it was)
        doc["environment"] = environment()
        dev = jax.devices()[0]
        doc["machine"] = (
            f"{platform.machine()}, {os.cpu_count()} CPUs, {dev.platform}: {dev.device_kind}"
        )
        doc["xla"] = slotv_jax.XLA_CONFIG.summary()
        ddir = data_lib.dataset_dir(cache, cfg.data)
        splits = data_lib.generate_dataset(
            cfg.data, ddir, progress=progress, splits=("train", "trajectory_val", "position_test")
        )
        doc["dataset"] = str(ddir)
    for setting, labeler, model in tqdm(todo, desc="active groups", disable=not progress):
        t0 = time.perf_counter()
        grp = run_group(cfg, splits, setting, labeler, model, progress=progress)
        grp["timing"]["total_s"] = round(time.perf_counter() - t0, 2)
        doc["groups"].append(grp)
        summarise(doc)
        write_text(path, json.dumps(doc, indent=1))
    summarise(doc)
    if todo:
        doc["timing"]["total_s"] = doc["timing"].get("total_s", 0.0) + time.perf_counter() - t_start
        doc["load"] = {**load, "end": os.getloadavg()[0]}
        doc["date"] = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    write_text(path, json.dumps(doc, indent=1))
    return doc


def parser(prog: str, description: str, presets: Sequence[str]) -> argparse.ArgumentParser:
    """The command line both active-selection experiments share (``experiments.active``
    and ``active_stream``): preset, output and cache folders, seeds, held-out motions,
    strategies; :func:`config_overrides` reads it back."""
    ap = argparse.ArgumentParser(prog=prog, description=description)
    ap.add_argument("--preset", default="quick", choices=tuple(presets))
    ap.add_argument("--out", default="experiments", help="output folder (default: experiments)")
    ap.add_argument("--cache", default="data", help="dataset cache folder")
    ap.add_argument("--seeds", type=int, default=None)
    ap.add_argument("--first-seed", type=int, default=None, help="seeds from this one (tuning)")
    ap.add_argument(
        "--eval-offset", type=int, default=None, help="held-out motions from this one (tuning)"
    )
    ap.add_argument("--strategies", default=None, help="comma-separated, random among them")
    ap.add_argument("--no-progress", action="store_true")
    return ap


def config_overrides(args: argparse.Namespace, names: Sequence[str] = ()) -> dict:
    """The preset's fields the command line sets: seeds, first_seed, eval_offset, the
    strategies, and the integer flags ``names``."""
    kw = {n: getattr(args, n) for n in ("seeds", "first_seed", "eval_offset", *names)}
    kw = {n: v for n, v in kw.items() if v is not None}
    if args.strategies:
        kw["strategies"] = tuple(s.strip() for s in args.strategies.split(","))
    return kw


def prepare_out(out: Path, stem: str, is_ours) -> None:
    """Before any work: ``OUT/STEM_results.json``, ``.md`` and ``.png`` can be written, and
    the results document, if there, is ours (``is_ours``; it is resumed and the report and
    figure rewritten from it); then make ``out``."""
    names = [f"{stem}{s}" for s in ("_results.json", ".md", ".png")]
    fileio.check_output_files(out, names, ours={names[0]: is_ours})
    out.mkdir(parents=True, exist_ok=True)


def _parse_args(argv):
    ap = parser("python -m slotv_jax.experiments.active", __doc__.split("\n\n")[0], PRESETS)
    ap.add_argument("--updates", type=int, default=None, help="updates per round (labels)")
    ap.add_argument("--study-updates", type=int, default=None, help="updates per round (study)")
    ap.add_argument("--members", type=int, default=None, help="ensemble size E")
    ap.add_argument(
        "--study-max",
        type=int,
        default=None,
        metavar="MOTIONS",
        help="study setting: continue the preset's geometric sizes up to this many motions",
    )
    ap.add_argument(
        "--groups",
        default=None,
        help="run only these groups (setting/labeler/model, comma-separated, e.g. "
        "labels/dragan/mlp); the results document is shared",
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="TrainConfig override of the MLP models, e.g. compute_dtype=bfloat16",
    )
    return ap.parse_args(argv)


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    args = _parse_args(argv)
    kw = config_overrides(args, ("updates", "study_updates", "members"))
    if args.study_max is not None:
        base = PRESETS[args.preset]().study_sizes
        if args.study_max < base[1]:
            raise cli.InputError(f"--study-max: expected at least {base[1]} motions")
        kw["study_sizes"] = up_to(base, args.study_max)
    cfg = PRESETS[args.preset](**kw)
    if args.set:
        cfg = dataclasses.replace(cfg, overrides=cfg.overrides + tuple(args.set))
        cfg.train_config("mlp")
    only = None
    if args.groups:
        only = [tuple(g.strip().split("/")) for g in args.groups.split(",")]
        bad = [g for g in only if g not in cfg.groups()]
        if bad:
            raise cli.InputError(
                f"--groups: {'/'.join(bad[0])} is not a group of this preset; expected some "
                f"of {', '.join('/'.join(g) for g in cfg.groups())}"
            )
    out = Path(args.out)
    prepare_out(out, stem_of(cfg.preset), is_results)
    print(slotv_jax.XLA_CONFIG.summary(), flush=True)
    doc = run(cfg, out, cache=Path(args.cache), progress=not args.no_progress, only=only)
    command = " ".join(
        ["python -m slotv_jax.experiments.active", *(sys.argv[1:] if argv is None else argv)]
    )
    render(doc, out, command)
    for c in doc["comparisons"] + doc["oracles"]:
        print(
            f"{c['setting']}/{c['labeler']}/{c['model']} {c['strategy']}: "
            f"{fmt_answers(c['answers_to_target'])} answers"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
