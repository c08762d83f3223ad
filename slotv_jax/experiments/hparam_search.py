"""Random hyperparameter search of the paper (:ref:`concepts-hparam-search`), resumable.

Search spaces (paper preset):

- SLOT-V, phase ``slotv_large_batch``: lr ~ U[0.0004, 0.02], ρ ~ U[0.7, 0.999],
  momentum ~ U[0, 1], batch ∈ {64, 128, 256, 512}; 5 epochs. Phase
  ``slotv_small_batch``: the same with batch ∈ {8, 16, 32, 64}.
- T-REX, phase ``trex``: lr ~ U[1e-5, 1e-3], β1, β2 ~ U[0.7, 1), batch ∈ {64, 128, 256};
  15 epochs.
- Both: hidden layer 1 ∈ {1280, 1536, 1792}, layer 2 ∈ {256, 512, 768, 1024}, and
  in 20% of rollouts an extra hidden layer (its width drawn from the layer-2 set).

The score of a rollout is its accuracy (:ref:`concepts-accuracy`) on ``trajectory_val`` for the
chosen labeler (Dragan by default). The ``quick`` preset keeps the ranges of
the optimiser hyperparameters but divides the widths by 16, trains on the
first 4,000 trajectories for 1 (SLOT-V) or 3 (T-REX) epochs, and runs 8
rollouts per phase **[choice]**, so it finishes on a CPU in minutes.

Rollout ``i`` of a phase draws its hyperparameters from ``default_rng([seed,
phase, i])`` and trains with key ``i``, so every rollout is reproducible on its
own. Each finished rollout is appended atomically to ``OUT/rollouts.json``; a
rerun skips finished ones. ``OUT/summary.md`` ranks the rollouts and reports
which hyperparameters mattered (Spearman rank correlation with the score).

    python -m slotv_jax.experiments.hparam_search                    # quick, CPU
    python -m slotv_jax.experiments.hparam_search --preset paper --rollouts 25
    python -m slotv_jax.experiments.hparam_search --report-only --out DIR   # re-render

The summary is rendered from ``rollouts.json`` alone
(:mod:`slotv_jax.experiments.hparam_search_report`).
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
from jax.sharding import Mesh
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.core import cli, distributed, fileio, validation
from slotv_jax.core.defaults import LABELER_NAMES
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.hparam_search_report import summarise
from slotv_jax.runs import presets
from slotv_jax.training import config as train_config
from slotv_jax.training import evaluate, parallel
from slotv_jax.training import trainer as train

PHASES = {
    "slotv_large_batch": ("slotv", (64, 128, 256, 512)),
    "slotv_small_batch": ("slotv", (8, 16, 32, 64)),
    "trex": ("trex", (64, 128, 256)),
}
HIDDEN1 = (1280, 1536, 1792)
HIDDEN2 = (256, 512, 768, 1024)
EXTRA_LAYER_P = 0.2


@dataclasses.dataclass(frozen=True)
class SearchConfig:
    """Scale of the search."""

    preset: str = "quick"
    rollouts: int = 8  # per phase
    width_divisor: int = 16  # hidden widths are the paper's divided by this
    slotv_epochs: int = 1
    trex_epochs: int = 3
    train_size: int | None = 4000  # first n training trajectories (None: all)
    seed: int = 0
    compute_dtype: str = "float32"  # matmul dtype of the hidden layers (TrainConfig)

    def __post_init__(self):
        for f in ("rollouts", "width_divisor", "slotv_epochs", "trex_epochs"):
            if getattr(self, f) < 1:
                raise ValueError(f"SearchConfig.{f}: expected an integer >= 1")


def quick(**kw) -> SearchConfig:
    return SearchConfig(**{"preset": "quick", **kw})


def paper(**kw) -> SearchConfig:
    base = {"preset": "paper", "rollouts": 25, "width_divisor": 1, "slotv_epochs": 5}
    return SearchConfig(**{**base, "trex_epochs": 15, "train_size": None, **kw})


def tiny(**kw) -> SearchConfig:
    """Seconds-scale search for tests (not a result)."""
    base = {"preset": "tiny", "rollouts": 2, "width_divisor": 64, "train_size": None}
    return SearchConfig(**{**base, **kw})


PRESETS = {"quick": quick, "paper": paper, "tiny": tiny}


def sample_hparams(phase: str, i: int, cfg: SearchConfig) -> dict:
    """Hyperparameters of rollout ``i`` of ``phase`` (deterministic)."""
    method, batches = PHASES[phase]
    rng = np.random.default_rng([cfg.seed, list(PHASES).index(phase), i])
    hidden = [int(rng.choice(HIDDEN1)), int(rng.choice(HIDDEN2))]
    if rng.random() < EXTRA_LAYER_P:
        hidden.append(int(rng.choice(HIDDEN2)))
    hidden = [max(1, h // cfg.width_divisor) for h in hidden]
    hp: dict = {"hidden": hidden, "batch_size": int(rng.choice(batches))}
    if method == "slotv":
        hp["learning_rate"] = float(rng.uniform(0.0004, 0.02))
        hp["rho"] = float(rng.uniform(0.7, 0.999))
        hp["momentum"] = float(rng.uniform(0.0, 1.0))
        hp["epochs"] = cfg.slotv_epochs
    else:
        hp["learning_rate"] = float(rng.uniform(1e-5, 1e-3))
        hp["b1"] = float(rng.uniform(0.7, 1.0))
        hp["b2"] = float(rng.uniform(0.7, 1.0))
        hp["epochs"] = cfg.trex_epochs
    return hp


def rollout_config(cfg: SearchConfig, phase: str, i: int) -> train_config.TrainConfig:
    """The training config of rollout ``i`` of ``phase``: the paper preset with its
    sampled hyperparameters (and the search's compute dtype)."""
    method = PHASES[phase][0]
    hp = sample_hparams(phase, i, cfg)
    return train_config.preset(
        "paper", method, **{**hp, "hidden": tuple(hp["hidden"])}, compute_dtype=cfg.compute_dtype
    )


def run(
    cfg: SearchConfig,
    out: Path,
    *,
    labeler: str = "dragan",
    phases: Sequence[str] = tuple(PHASES),
    cache: Path = Path("data"),
    progress: bool = True,
    time_limit_s: float | None = None,
    command: str | None = None,
) -> dict:
    """Run (or resume) the search; returns the rollouts document.

    Rollouts have different widths and batch sizes, so they cannot share one compiled,
    vmapped function; instead each device (every process's, under ``jax.distributed``)
    trains one rollout at a time (:func:`slotv_jax.training.parallel.map_on_devices`): the host
    dispatches a round of one rollout per device and, while they run, traces and compiles
    the next round (JAX dispatch is asynchronous, so no threads). Pending rollouts are
    ordered by (phase, batch size, widths) so that a round's rollouts take similar times.
    On one device this is the old loop, with the compilation of rollout r + 1 overlapping
    the training of rollout r. Finished rollouts are written (by process 0) as their round
    is read back; with ``time_limit_s`` no round is started that would, at the last round's
    pace, end after that many seconds: a rerun continues.
    """

    t_start = time.perf_counter()
    writer = distributed.is_writer()
    if writer:
        out.mkdir(parents=True, exist_ok=True)
    path = out / "rollouts.json"
    doc = {"search": dataclasses.asdict(cfg), "labeler": labeler, "rollouts": []}
    if path.exists():
        old = json.loads(path.read_text())
        if (old.get("search"), old.get("labeler")) != (doc["search"], labeler):
            raise ValueError(f"{path}: results of another search config; use another --out")
        doc = old
    doc["environment"] = environment()
    doc.setdefault("invocations", [])
    dcfg = presets.PRESETS[cfg.preset]().data
    dataset = data_lib.cached_dataset(
        dcfg, cache, splits=["train", "trajectory_val"], progress=progress
    )
    t_data = time.perf_counter() - t_start
    tdata = train.trim_goals(train.prepare(dataset["train"], labeler, size=cfg.train_size))
    vdata = train.trim_goals(train.prepare(dataset["trajectory_val"], labeler))
    everything = [(p, i) for p in phases for i in range(cfg.rollouts)]
    finished = {(r["phase"], r["index"]) for r in doc["rollouts"]}
    done = distributed.broadcast(np.array([job in finished for job in everything]))
    todo = [job for job, d in zip(everything, done, strict=True) if not d]

    def order(job):
        tc = rollout_config(cfg, *job)
        return (list(PHASES).index(job[0]), tc.batch_size, tc.hidden, job[1])

    todo.sort(key=order)
    devices = jax.devices()
    me = jax.process_index()
    placed = {d: jax.device_put((tdata, vdata), d) for d in devices if d.process_index == me}
    host_s: dict[tuple[str, int], float] = {}
    started: dict[tuple[str, int], float] = {}

    def start(job, device):
        """Dispatch training and scoring of one rollout to ``device``, without waiting."""
        t0 = time.perf_counter()
        started[job] = t0
        tc = rollout_config(cfg, *job)
        mesh = Mesh(np.array([device]), ("data",))
        td, vd = placed[device]
        keys = train.trial_keys([job[1]])
        trainer = train.make_train(tc, mesh=mesh, progress=False)
        trainer = train.packed_trainer(
            trainer, jax.vmap(train.Trainer.state_key)(keys), td, range(tc.epochs)
        )
        args = (keys[0], td, None)
        state, metrics = train._trials_program(trainer, False, args)(*args)
        ratio, _ = evaluate.start_accuracy(tc, state.params, vd, mesh=mesh)
        loss = metrics.loss
        finite = jnp.all(jnp.isfinite(loss)).astype(jnp.float32)
        host_s[job] = time.perf_counter() - t0
        return jnp.stack([jnp.reshape(ratio, ()), loss[-1].mean(), finite])

    calls: list[float] = []

    def keep_going() -> bool:
        """Called before each round is dispatched, i.e. about one round apart; a round
        dispatched now ends about two rounds from now (the running one goes first)."""
        now = time.perf_counter()
        calls.append(now)
        pace = float(np.max(np.diff(calls), initial=0.0))
        return time_limit_s is None or now - t_start + 2 * pace <= time_limit_s

    n_val = vdata.xyz.shape[0]
    bar = tqdm(total=len(todo), desc="rollouts", unit="rollout", disable=not (progress and writer))
    left = len(todo)
    for (phase, i), (ratio, final_loss, finite) in parallel.map_on_devices(
        todo, start, 3, keep_going=keep_going
    ):
        now = time.perf_counter()
        doc["rollouts"].append(
            {
                "phase": phase,
                "index": i,
                "method": PHASES[phase][0],
                "hparams": sample_hparams(phase, i, cfg),
                "val_accuracy": float(evaluate.exact_fraction(np.float32(ratio), n_val)),
                "final_loss": float(final_loss),
                "finite": bool(finite),
                "dispatch_to_result_s": now - started[(phase, i)],
                "host_dispatch_s": host_s.get((phase, i)),
                "side_by_side": len(devices),
            }
        )
        doc["rollouts"].sort(key=lambda r: (list(PHASES).index(r["phase"]), r["index"]))
        left -= 1
        if writer:
            write_text(path, json.dumps(doc, indent=1))
        bar.update(1)
    bar.close()
    wall = time.perf_counter() - t_start
    doc["invocations"].append(
        {
            "command": command,
            "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
            "wall_s": round(wall, 1),
            "data_s": round(t_data, 1),
            "rollouts_run": len(todo) - left,
            "rollouts_left": left,
            "devices": [str(d) for d in devices],
            "device_kind": devices[0].device_kind,
            "processes": jax.process_count(),
        }
    )
    if writer:
        write_text(path, json.dumps(doc, indent=1))
        write_text(out / "summary.md", summarise(doc))
    return doc


def report_again(out: Path, also: Path | None) -> int:
    """Render ``OUT/summary.md`` (and ``also``) again from ``OUT/rollouts.json`` alone."""
    path = out / "rollouts.json"
    if not fileio.is_json_object_with(path, ("search", "labeler", "rollouts")):
        raise cli.InputError(f"--report-only: {path} is not the rollouts document of a search")
    if also is not None:
        fileio.check_output_files(also.parent, [also.name], what="--report")
    summary = summarise(json.loads(path.read_text()))
    for target in (out / "summary.md", also):
        if target is not None:
            write_text(target, summary)
    print(summary)
    return 0


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.hparam_search",
        description="The SLOT-V paper's random hyperparameter search.",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--rollouts", type=int, help="rollouts per phase (default: the preset's)")
    p.add_argument("--labeler", choices=LABELER_NAMES, default="dragan")
    p.add_argument("--phases", nargs="+", choices=list(PHASES), default=list(PHASES))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path, help="default: runs/hparam_search_<preset>")
    p.add_argument("--cache", type=Path, default=Path("data"))
    p.add_argument("--compute-dtype", choices=("float32", "bfloat16"),
                   help="matmul dtype of the hidden layers (default float32)")  # fmt: skip
    p.add_argument("--time-limit", type=float, metavar="SECONDS",
                   help="start no round of rollouts that would end after this many seconds; "
                   "rerun the same command to continue")  # fmt: skip
    p.add_argument("--report", type=Path,
                   help="also write the Markdown summary here (e.g. "
                   "experiments/hparam_search_paper.md)")  # fmt: skip
    p.add_argument("--report-only", action="store_true",
                   help="only render OUT/summary.md (and --report) again from "
                   "OUT/rollouts.json")  # fmt: skip
    distributed.add_cli_args(p)
    args = p.parse_args(argv)
    validation.check_seeds("--seed", args.seed)
    if args.report_only:
        return report_again(args.out or Path("runs") / f"hparam_search_{args.preset}", args.report)
    distributed.init_from_args(args)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)
    if args.time_limit is not None and not args.time_limit >= 0:
        p.error("--time-limit: expected a number of seconds >= 0")
    kw = {"seed": args.seed}
    if args.rollouts is not None:
        kw["rollouts"] = args.rollouts
    if args.compute_dtype is not None:
        kw["compute_dtype"] = args.compute_dtype
    cfg = PRESETS[args.preset](**kw)
    out = args.out or Path("runs") / f"hparam_search_{args.preset}"
    fileio.check_output_dir(out, ours=fileio.is_results_dir, resume=True)  # a rerun resumes
    if args.report is not None:
        fileio.check_output_files(args.report.parent, [args.report.name], what="--report")
    command = "python -m slotv_jax.experiments.hparam_search " + " ".join(
        sys.argv[1:] if argv is None else argv
    )
    t0 = time.perf_counter()
    doc = run(cfg, out, labeler=args.labeler, phases=args.phases, cache=args.cache,
              time_limit_s=args.time_limit, command=command.strip())  # fmt: skip
    if not distributed.is_writer():
        return 0
    summary = (out / "summary.md").read_text()
    if args.report is not None:
        write_text(args.report, summary)
    print(summary)
    left = doc["invocations"][-1]["rollouts_left"]
    status = f"{left} rollouts left: rerun the same command" if left else "search complete"
    print(f"this run took {time.perf_counter() - t0:.0f} s; {status}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
