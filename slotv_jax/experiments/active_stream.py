"""Active selection under the paper's own protocol (Fig. 3): each label is used once.

The paper's Fig. 3 (SPEC §8) counts the examples of one pass over fresh labelled motions:
every motion is labelled, used for one update of a batch, and never seen again (5,760 to
80 % on Dragan at the paper preset, ``experiments/sample_efficiency.json``).
:mod:`slotv_jax.experiments.active` asks how few *answers* a study needs, so it reuses
each answer for as many updates as its rounds give. This experiment keeps Fig. 3's
protocol and lets a strategy choose each batch:

1. the observer (the paper's SLOT-V network, one member) starts from the seed's
   initialisation, the same for every strategy of a seed;
2. before each update, the strategy scores ``subset`` motions drawn from the not yet
   labelled part of the ``train`` split with the current observer and picks
   ``batch_size`` of them; they are labelled (the labeler's distribution) and used for
   exactly one optimiser step of the config's optimiser (SLOT-V's loss, SPEC §5), and
   never again. ``random`` is Fig. 3's protocol itself;
3. every ``every`` updates, the accuracy on ``trajectory_val`` (``eval_size`` motions from
   ``eval_offset``, SPEC §8) is recorded against the examples labelled so far; the
   examples to the target are the first such count at or above it (as Fig. 3).

Strategies: ``random``, ``uncertainty`` and ``margin`` (:mod:`slotv_jax.asking.selection`:
with one member the ensemble's criteria reduce to these) and the two oracles of the
active experiment, which read the candidates' labels (bounds, not strategies).

    python -m slotv_jax.experiments.active_stream                  # quick (CPU, ~2 min)
    python -m slotv_jax.experiments.active_stream --preset paper   # the paper's network (GPU)

Writes ``OUT/active_stream{,_paper}_results.json``, ``.md`` and ``.png`` (a rerun with
the same config only renders the report again).
"""

from __future__ import annotations

import dataclasses
import json
import os
import platform
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.asking import selection
from slotv_jax.core import cli, fileio
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import save_figure, write_text
from slotv_jax.experiments import active
from slotv_jax.experiments.active import motion_arrays, oracle_score
from slotv_jax.experiments.active_report import ORACLES, STRATEGY_COLORS
from slotv_jax.runs.curves import examples_to_reach
from slotv_jax.training import config as train_config
from slotv_jax.training import evaluate

STRATEGIES = ("random", "uncertainty", "margin")  # criteria of a single observer


@dataclasses.dataclass(frozen=True)
class StreamConfig:
    """One run of the protocol (module docstring)."""

    preset: str
    data: data_lib.DataConfig
    train_preset: str  # slotv_jax.config preset of the observer (the paper's MLP)
    strategies: tuple[str, ...] = (*STRATEGIES, *ORACLES)
    labeler: str = "dragan"
    steps: int = 250  # updates, each on batch_size newly labelled motions
    subset: int = 512  # unlabelled motions scored before each update
    every: int = 5  # updates between evaluations
    seeds: int = 3
    first_seed: int = 0
    target: float = 0.8
    eval_size: int = 1000
    eval_offset: int = 0
    stride: int = 1  # keep every stride-th point of each motion
    chunk: int = 256  # candidates per scoring chunk
    overrides: tuple[str, ...] = ()  # TrainConfig key=value overrides

    def __post_init__(self):
        bad = [s for s in self.strategies if s not in STRATEGIES + ORACLES]
        if bad or "random" not in self.strategies:
            raise ValueError(f"strategies: expected 'random' and names of {STRATEGIES + ORACLES}")
        for name in ("steps", "every", "seeds", "eval_size", "stride", "chunk"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name}: expected an integer >= 1, got {getattr(self, name)}")
        bs = self.train_config().batch_size
        if self.subset < bs:
            raise ValueError(f"subset: expected at least the batch ({bs}), got {self.subset}")
        need = (self.steps - 1) * bs + self.subset  # the last update still scores a subset
        if need > self.data.n_train:
            raise ValueError(
                f"steps: {self.steps} updates of {bs} new motions, each from {self.subset} "
                f"unlabelled ones, need a train split of {need}; the preset's has "
                f"{self.data.n_train}"
            )
        if self.eval_offset < 0 or self.eval_offset + self.eval_size > self.data.n_eval:
            raise ValueError(
                f"eval_offset, eval_size: expected held-out motions within trajectory_val's "
                f"{self.data.n_eval}, got {self.eval_offset} + {self.eval_size}"
            )

    def train_config(self) -> train_config.TrainConfig:
        cfg = train_config.preset(self.train_preset, "slotv", train_size=None)
        return train_config.apply_overrides(cfg, self.overrides)

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        d["train"] = self.train_config().to_dict()
        return json.loads(json.dumps(d))


def _from_active(a: active.ActiveConfig, **kw) -> StreamConfig:
    """The active experiment's preset ``a``: its dataset, network, points, seeds and
    held-out motions."""
    same = ("preset", "data", "train_preset", "seeds", "eval_size", "stride", "chunk", "overrides")
    return StreamConfig(**{k: getattr(a, k) for k in same}, **kw)


def quick(**overrides) -> StreamConfig:
    """CPU preset: the quick dataset and network (64/32) on every 4th point, target 75 %
    (the quick network's one-pass accuracy stays near 80 % within 8,000 examples)."""
    return dataclasses.replace(_from_active(active.quick(), target=0.75), **overrides)


def paper(**overrides) -> StreamConfig:
    """GPU preset: the paper's dataset and SLOT-V network (1536/768, bfloat16 matmuls) on
    every point, 5 seeds, 3,000 held-out motions."""
    return dataclasses.replace(_from_active(active.paper()), **overrides)


PRESETS = {"quick": quick, "paper": paper}


# ------------------------------------------------------------------- running


def run_seeds(cfg: StreamConfig, train, held_out, *, progress: bool = True) -> dict:
    """Every strategy × seed of the protocol. ``train`` and ``held_out`` are (xyz (N, T, 3),
    goals (N, G, 3), goal_mask (N, G), labels (N, G)) arrays: the pool and the motions the
    accuracy is measured on. Returns the curves (examples, per-run accuracy), the motions
    each run labelled (in order) and the observers at the end (leading axis: runs)."""
    tc = cfg.train_config()
    bs = tc.batch_size
    xyz, goals, mask, probs = train
    pool = selection.make_pool(xyz, goals, mask)
    n_pool = pool.traj.shape[0]
    if (cfg.steps - 1) * bs + cfg.subset > n_pool:
        raise ValueError(
            f"train: {cfg.steps} updates of {bs} new motions, each from {cfg.subset} "
            f"unlabelled ones, need {(cfg.steps - 1) * bs + cfg.subset} motions, got {n_pool}"
        )
    evpool = selection.make_pool(*held_out[:3])
    etarget = np.asarray(evaluate.target(jnp.asarray(held_out[3]), jnp.asarray(held_out[2])))
    seeds = range(cfg.first_seed, cfg.first_seed + cfg.seeds)
    runs = [(s, seed) for s in cfg.strategies for seed in seeds]
    sel = selection.make_selector(tc, 1, bs)  # one member: the observer itself
    ens = jax.jit(jax.vmap(sel.init))(jnp.stack([jax.random.key(1000 + sd) for _, sd in runs]))
    rows = jnp.arange(bs)

    def update(e: selection.Ensemble, ans: selection.Answers) -> selection.Ensemble:
        """One optimiser step on the batch's rows, each once (Fig. 3's epoch)."""

        def member(params, opt_state, boot):
            grads = jax.grad(sel.loss)(params, pool, ans, rows, boot)
            upd, opt_state = sel.base.tx.update(grads, opt_state, params)
            return optax.apply_updates(params, upd), opt_state

        params, opt_state = jax.vmap(member)(e.params, e.opt_state, e.boot)
        return selection.Ensemble(params, opt_state, e.boot)

    step = jax.jit(jax.vmap(update))
    score = jax.jit(jax.vmap(lambda p, c: sel.log_probs(p, pool, c, chunk=cfg.chunk)))
    evc = jnp.arange(evpool.traj.shape[0])
    predict = jax.jit(
        jax.vmap(lambda p: jnp.argmax(sel.log_probs(p, evpool, evc, chunk=cfg.chunk)[0], -1))
    )

    def picker(s):  # (key, log p (1, C, G), labels (C, G)) -> bs picks
        avail = jnp.ones((cfg.subset,), bool)
        if s in ORACLES:
            return lambda k, lp, y: selection.masked_top_k(oracle_score(s, lp[0], y), avail, bs)
        return lambda k, lp, y: selection.select(s, k, lp, avail, bs)

    pickers = {s: jax.jit(jax.vmap(picker(s))) for s in cfg.strategies}
    members = {s: np.asarray([i for i, r in enumerate(runs) if r[0] == s]) for s in pickers}
    asked = np.zeros((len(runs), n_pool), bool)
    labelled = np.zeros((len(runs), cfg.steps * bs), np.int32)
    acc, xs = [], []
    times = {"score_s": 0.0, "select_s": 0.0, "update_s": 0.0, "eval_s": 0.0}
    for u in tqdm(range(cfg.steps + 1), desc="updates", disable=not progress, leave=False):
        if u % cfg.every == 0 or u == cfg.steps:
            t0 = time.perf_counter()
            acc.append((np.asarray(predict(ens.params)) == etarget[None]).mean(-1))
            xs.append(u * bs)
            times["eval_s"] += time.perf_counter() - t0
        if u == cfg.steps:
            break
        sub = np.zeros((len(runs), cfg.subset), np.int32)
        for i, (_, sd) in enumerate(runs):
            free = np.flatnonzero(~asked[i])
            sub[i] = np.random.default_rng([sd, 2, u]).choice(free, cfg.subset, replace=False)
        t0 = time.perf_counter()
        logp = score(ens.params, jnp.asarray(sub))
        jax.block_until_ready(logp)
        t1 = time.perf_counter()
        keys = jnp.stack([jax.random.fold_in(jax.random.key(1000 + sd), u) for _, sd in runs])
        pick = np.zeros((len(runs), bs), np.int32)
        for s, fn in pickers.items():
            idx = members[s]
            y = jnp.asarray(probs[sub[idx]]) if s in ORACLES else jnp.zeros((idx.size,))
            pick[idx] = np.asarray(fn(keys[idx], logp[idx], y))
        new = np.take_along_axis(sub, pick, 1)  # (runs, bs) motions labelled now
        t2 = time.perf_counter()
        for i in range(len(runs)):
            asked[i, new[i]] = True
        labelled[:, u * bs : (u + 1) * bs] = new
        ans = selection.Answers(
            jnp.asarray(new),
            jnp.asarray(probs[new], jnp.float32),
            jnp.full((len(runs),), bs, jnp.int32),
        )
        ens = step(ens, ans)
        jax.block_until_ready(ens.params)
        times["score_s"] += t1 - t0
        times["select_s"] += t2 - t1
        times["update_s"] += time.perf_counter() - t2
    curves = np.stack(acc, 1)  # (runs, evaluations)
    return {
        "examples": xs,
        "runs": [
            {"strategy": s, "seed": sd, "accuracy": curves[i].round(6).tolist()}
            for i, (s, sd) in enumerate(runs)
        ],
        "labelled": labelled,
        "params": ens.params,
        "timing": {k: round(v, 2) for k, v in times.items()},
    }


def summarise(doc: dict) -> dict:
    """Per strategy: the examples each seed needs for the target (None: not reached), their
    mean (None unless every seed reached it) and random's mean over it."""
    target = doc["config"]["target"]
    xs = np.asarray(doc["examples"], float)
    out = []
    for s in doc["config"]["strategies"]:
        runs = [r for r in doc["runs"] if r["strategy"] == s]
        per = [examples_to_reach(xs, np.asarray(r["accuracy"]), target) for r in runs]
        mean = None if any(p is None for p in per) else float(np.mean(per))
        final = float(np.mean([r["accuracy"][-1] for r in runs]))
        out.append({"strategy": s, "seeds": [r["seed"] for r in runs], "per_seed": per,
                    "examples_to_target": mean, "final_accuracy": final})  # fmt: skip
    rnd = next(c for c in out if c["strategy"] == "random")["examples_to_target"]
    for c in out:
        m = c["examples_to_target"]
        c["ratio_random_over_this"] = None if rnd is None or m is None else rnd / m
    doc["summary"] = out
    return doc


def run(cfg: StreamConfig, out: Path, *, cache: Path = Path("data"), progress: bool = True):
    """Run the protocol (unless ``out`` holds a finished document of this config) and write
    the results document; returns it."""
    path = out / f"{stem_of(cfg.preset)}_results.json"
    if path.exists():
        doc = json.loads(path.read_text())
        if doc.get("config") == cfg.to_json() and doc.get("runs"):
            return summarise(doc)  # finished: summarised again where it ran, as it was
    t0 = time.perf_counter()
    load = {"cpus": os.cpu_count(), "start": os.getloadavg()[0]}
    dev = jax.devices()[0]
    ddir = data_lib.dataset_dir(cache, cfg.data)
    splits = data_lib.generate_dataset(
        cfg.data, ddir, progress=progress, splits=("train", "trajectory_val")
    )
    train = motion_arrays(splits["train"], cfg.labeler, cfg.stride)
    held = motion_arrays(
        splits["trajectory_val"], cfg.labeler, cfg.stride, cfg.eval_offset + cfg.eval_size
    )
    held = tuple(a[cfg.eval_offset :] for a in held)
    if held[0].shape[0] != cfg.eval_size:
        raise ValueError(
            f"eval_offset, eval_size: trajectory_val holds {cfg.eval_offset + held[0].shape[0]} "
            f"motions, asked for {cfg.eval_offset} + {cfg.eval_size}"
        )
    res = run_seeds(cfg, train, held, progress=progress)
    doc = {
        "preset": cfg.preset,
        "config": cfg.to_json(),
        "examples": res["examples"],
        "runs": res["runs"],
        "timing": {**res["timing"], "total_s": round(time.perf_counter() - t0, 2)},
        "environment": environment(),
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, "
        f"{dev.platform}: {dev.device_kind}",
        "xla": slotv_jax.XLA_CONFIG.summary(),
        "dataset": str(ddir),
        "load": {**load, "end": os.getloadavg()[0]},
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
    }
    summarise(doc)
    write_text(path, json.dumps(doc, indent=1))
    return doc


# ------------------------------------------------------------------- the report


def stem_of(preset: str) -> str:
    return "active_stream" if preset == "quick" else f"active_stream_{preset}"


def _fmt(x: float | None) -> str:
    return "not reached" if x is None else f"{x:,.0f}"


def report(doc: dict, command: str) -> str:
    cfg, env = doc["config"], doc["environment"]
    tc = cfg["train"]
    versions = ", ".join(
        f"{k} {env[k]}" for k in ("python", "jax", "flax", "optax", "numpy") if k in env
    )
    lines = [
        f"# Active selection under the paper's Fig. 3 protocol ({doc['preset']} preset)",
        "",
        f"```bash\n{command}\n```",
        "",
        f"- Date: {doc['date']}; machine: {doc['machine']}; versions: {versions}",
        f"- Protocol (`slotv_jax/experiments/active_stream.py`): {cfg['seeds']} seeds (from "
        f"seed {cfg['first_seed']}) × strategies {', '.join(cfg['strategies'])}; the "
        f"SLOT-V network (hidden {tuple(tc['hidden'])}, {tc['optimizer']} lr "
        f"{tc['learning_rate']}, batch {tc['batch_size']}); before each of {cfg['steps']} "
        f"updates the strategy picks {tc['batch_size']} of {cfg['subset']:,} unlabelled "
        f"motions, which are labelled ({cfg['labeler']}) and used for that one update only; "
        f"accuracy every {cfg['every']} updates on {cfg['eval_size']:,} motions of "
        f"`trajectory_val` from motion {cfg['eval_offset']:,}; target {cfg['target']:.0%}.",
        f"- Time: {doc['timing']['total_s'] / 60:.1f} min (dataset included); 1-minute load "
        f"average {doc['load']['start']:.1f} at the start and {doc['load']['end']:.1f} at the "
        f"end on {doc['load']['cpus']} CPUs.",
        "",
        f"![learning curves]({stem_of(doc['preset'])}.png)",
        "",
        "## Examples to the target",
        "",
        "| strategy | per seed | mean | random / this | final accuracy |",
        "|---|---|---|---|---|",
    ]
    for c in doc["summary"]:
        r = c["ratio_random_over_this"]
        lines.append(
            f"| {c['strategy']}{' (oracle)' if c['strategy'] in ORACLES else ''} | "
            f"{', '.join(_fmt(p) for p in c['per_seed'])} | {_fmt(c['examples_to_target'])} | "
            f"{'—' if r is None else f'{r:.2f}'} | {c['final_accuracy']:.3f} |"
        )
    lines += [
        "",
        "Examples to the target: per seed, the first evaluation at or above it (as Fig. 3); "
        "the mean only when every seed reaches it. 'random / this' > 1: fewer labelled "
        "examples than random selection in the same run.",
        "",
        "## Notes",
        "",
        "- `random` is Fig. 3's protocol (one pass, batches of fresh motions). In this "
        "protocol a label is worth one gradient step. A likely reading of the table: what "
        "bounds the examples to the target is the number of updates the optimiser needs, "
        "which selection does not change, only the gradient of each (the batches it picks "
        "are near the decision, or hard, but each still moves the network one step).",
        "- The oracles read the labels: `oracle_loss` updates on the batch the observer gets "
        "most wrong (loss-prioritised training), `oracle_margin` on the motions nearest the "
        "labeler's own decision.",
        "- Where a study pays for answers rather than updates, "
        "`python -m slotv_jax.experiments.active` reuses every answer, and random selection "
        "itself needs far fewer labelled motions (`experiments/active_paper.md`).",
        "",
    ]
    return "\n".join(lines)


def plot(doc: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    xs = np.asarray(doc["examples"])
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for s in doc["config"]["strategies"]:
        a = np.asarray([r["accuracy"] for r in doc["runs"] if r["strategy"] == s])
        m, sd = a.mean(0), a.std(0)
        style = "--" if s in ORACLES else "-"
        ax.plot(xs, m, style, color=STRATEGY_COLORS[s], label=s)
        ax.fill_between(xs, m - sd, m + sd, color=STRATEGY_COLORS[s], alpha=0.12)
    ax.axhline(doc["config"]["target"], color="0.5", lw=0.8, ls=":")
    ax.set_xlabel("labelled examples (each used for one update)")
    ax.set_ylabel(f"accuracy on trajectory_val ({doc['config']['labeler']})")
    ax.set_title(f"One pass, selected batches ({doc['preset']}; mean ± SD over seeds)")
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path, dpi=120)
    plt.close(fig)


def render(doc: dict, out: Path, command: str) -> None:
    stem = stem_of(doc["preset"])
    write_text(out / f"{stem}.md", report(doc, command))
    plot(doc, out / f"{stem}.png")


# ------------------------------------------------------------------- the command


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a results document of this experiment."""
    return fileio.is_json_object_with(path, ("preset", "config", "runs"))


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    ap = active.parser(
        "python -m slotv_jax.experiments.active_stream", __doc__.split("\n\n")[0], PRESETS
    )
    ap.add_argument("--steps", type=int, default=None, help="updates (each on a new batch)")
    args = ap.parse_args(argv)
    kw = active.config_overrides(args, ("steps",))
    cfg = PRESETS[args.preset](**kw)
    out = Path(args.out)
    active.prepare_out(out, stem_of(cfg.preset), is_results)
    print(slotv_jax.XLA_CONFIG.summary(), flush=True)
    doc = run(cfg, out, cache=Path(args.cache), progress=not args.no_progress)
    command = " ".join(
        ["python -m slotv_jax.experiments.active_stream", *(sys.argv[1:] if argv is None else argv)]
    )
    render(doc, out, command)
    for c in doc["summary"]:
        r = c["ratio_random_over_this"]
        print(
            f"{c['strategy']}: {_fmt(c['examples_to_target'])} examples to "
            f"{cfg.target:.0%}" + ("" if r is None else f" (random / this {r:.2f})")
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
