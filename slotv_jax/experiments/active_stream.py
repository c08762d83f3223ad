"""Active selection under the paper's own protocol (Fig. 3): each label is used once.

The paper's Fig. 3 (:ref:`concepts-metrics`) counts the examples of one pass over fresh labelled
motions: every motion is labelled, used for one update of a batch, and never seen again (5,760 to
80 % on Dragan at the paper preset, ``experiments/sample_efficiency.json``).
:mod:`slotv_jax.experiments.active` asks how few *answers* a study needs, so it reuses
each answer for as many updates as its rounds give. This experiment keeps Fig. 3's
protocol and lets a strategy choose each batch:

1. the observer (the paper's SLOT-V network, one member) starts from the seed's
   initialisation, the same for every strategy of a seed;
2. before each update, the strategy scores ``subset`` motions drawn from the not yet
   labelled part of the ``train`` split with the current observer and picks
   ``batch_size`` of them; they are labelled (the labeler's distribution) and used for
   exactly one optimiser step of the config's optimiser (SLOT-V's loss, :ref:`concepts-slotv`), and
   never again. ``random`` is Fig. 3's protocol itself;
3. every ``every`` updates, the accuracy on ``trajectory_val`` (``eval_size`` motions from
   ``eval_offset``, :ref:`concepts-metrics`) is recorded against the examples labelled so far; the
   examples to the target are the first such count at or above it (as Fig. 3).

Strategies: ``random``, ``uncertainty`` and ``margin`` (:mod:`slotv_jax.asking.selection`:
with one member the ensemble's criteria reduce to these) and the two oracles of the
active experiment, which read the candidates' labels (bounds, not strategies).

    python -m slotv_jax.experiments.active_stream                  # quick (CPU, ~2 min)
    python -m slotv_jax.experiments.active_stream --preset paper   # the paper's network (GPU)

Writes ``OUT/active_stream{,_paper}_results.json``, ``.md`` and ``.png`` (a rerun with
the same config only renders the report again; so does ``--report``, from the results
document alone).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.asking import replay
from slotv_jax.asking.replay import ORACLES
from slotv_jax.core import cli, fileio, validation
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments import active
from slotv_jax.runs import command, figures, record
from slotv_jax.runs.summary import examples_to_reach
from slotv_jax.training import config as train_config

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
        validation.check_seeds("first_seed", self.first_seed, self.seeds, count_name="seeds")
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
PROG = "python -m slotv_jax.experiments.active_stream"


# ------------------------------------------------------------------- running


def run_seeds(cfg: StreamConfig, train, held_out, *, progress: bool = True) -> dict:
    """Every strategy × seed of the protocol (:func:`slotv_jax.asking.replay.run_one_pass`).
    ``train`` and ``held_out`` are (xyz (N, T, 3), goals (N, G, 3), goal_mask (N, G), labels
    (N, G)) arrays: the pool and the motions the accuracy is measured on. Returns the
    curves (examples, per-run accuracy), the motions each run labelled (in order) and the
    observers at the end (leading axis: runs)."""
    seeds = range(cfg.first_seed, cfg.first_seed + cfg.seeds)
    return replay.run_one_pass(
        cfg.train_config(), train, held_out, strategies=cfg.strategies, seeds=seeds,
        steps=cfg.steps, subset=cfg.subset, every=cfg.every, chunk=cfg.chunk, progress=progress,
    )  # fmt: skip


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
    load = record.load_start()
    ddir = data_lib.dataset_dir(cache, cfg.data)
    splits = data_lib.generate_dataset(
        cfg.data, ddir, progress=progress, splits=("train", "trajectory_val")
    )
    train = replay.motion_arrays(splits["train"], cfg.labeler, cfg.stride)
    held = replay.held_out_motions(
        splits["trajectory_val"], "trajectory_val", cfg.labeler, cfg.stride, cfg.eval_offset,
        cfg.eval_size,
    )  # fmt: skip
    res = run_seeds(cfg, train, held, progress=progress)
    doc = {
        "preset": cfg.preset,
        "config": cfg.to_json(),
        "examples": res["examples"],
        "runs": res["runs"],
        "timing": {**res["timing"], "total_s": round(time.perf_counter() - t0, 2)},
        "environment": environment(),
        "machine": record.machine(),
        "xla": slotv_jax.XLA_CONFIG.summary(),
        "dataset": str(ddir),
        "load": record.load_end(load),
        "date": record.utc_now(),
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
    versions = record.versions(env)
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
    plt = figures.pyplot()
    xs = np.asarray(doc["examples"])
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for s in doc["config"]["strategies"]:
        a = np.asarray([r["accuracy"] for r in doc["runs"] if r["strategy"] == s])
        style = "--" if s in ORACLES else "-"
        figures.band(ax, xs, *figures.mean_sd(a), style, color=figures.STRATEGY_COLORS[s],
                     label=s, alpha=0.12, outline=True)  # fmt: skip
    ax.axhline(doc["config"]["target"], color="0.5", lw=0.8, ls=":")
    ax.set_xlabel("labelled examples (each used for one update)")
    ax.set_ylabel(f"accuracy on trajectory_val ({doc['config']['labeler']})")
    ax.set_title(f"One pass, selected batches ({doc['preset']}; mean ± SD over seeds)")
    ax.legend(loc="lower right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    figures.save(fig, path, dpi=120)


def render(doc: dict, out: Path, command: str) -> None:
    stem = stem_of(doc["preset"])
    write_text(out / f"{stem}.md", report(doc, command))
    plot(doc, out / f"{stem}.png")


# ------------------------------------------------------------------- the command


def is_results(path: Path) -> bool:
    """Whether ``path`` holds a results document of this experiment."""
    return fileio.is_json_object_with(path, ("preset", "config", "runs"))


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    ap = command.seeded_parser(PROG, __doc__.split("\n\n")[0], PRESETS)
    ap.add_argument("--steps", type=int, default=None, help="updates (each on a new batch)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.report:
        again = lambda doc, cmd: render(summarise(doc), out, cmd)  # noqa: E731
        return command.render_again(
            out, stem_of(args.preset), is_results, again, f"{PROG} --preset {args.preset}"
        )
    cfg = PRESETS[args.preset](**command.seeded_overrides(args, ("steps",)))
    command.prepare_out(out, stem_of(cfg.preset), is_results)
    print(slotv_jax.XLA_CONFIG.summary(), flush=True)
    doc = run(cfg, out, cache=Path(args.cache), progress=not args.no_progress)
    render(doc, out, record.command_line(PROG, argv))
    for c in doc["summary"]:
        r = c["ratio_random_over_this"]
        hit = c["examples_to_target"]
        reach = (f"{hit:,.0f} examples to {cfg.target:.0%}" if hit is not None
                 else f"does not reach {cfg.target:.0%}")  # fmt: skip
        print(f"{c['strategy']}: {reach}" + ("" if r is None else f" (random / this {r:.2f})"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
