"""Table 1 of the paper: accuracy of SLOT-V and T-REX on every labeler and split (SPEC §8).

    python -m slotv_jax.experiments.table1                      # quick preset, CPU, minutes
    python -m slotv_jax.experiments.table1 --preset paper       # paper sizes (GPU)
    python -m slotv_jax.experiments.table1 --labelers dragan --methods slotv --trials 3

Steps: generate (or reuse) the seven dataset splits, cached by config digest;
train each (labeler, method, trial) cell; evaluate it on the four Table 1
splits; write the cell to ``OUT/results.json`` atomically as soon as it
finishes. A rerun with the same ``--out`` skips finished cells, so an
interrupted run loses at most the cell in flight. The end of the run prints
the table in the paper's layout (mean ± SD over trials, the paper's values and
the difference) and writes ``OUT/table1.md``.

On several devices (and hosts, with ``--coordinator``/``--num-processes``/
``--process-id`` or ``--distributed``) the pending trials of each method, all
labelers together, train side by side, one per device
(:mod:`slotv_jax.training.parallel`); each group is written as it finishes.
``--time-limit SECONDS`` stops before a group that would end later; the same
command resumes.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.core import cli, distributed, fileio
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.training import config as train_config
from slotv_jax.training import evaluate, parallel, schedule, types
from slotv_jax.training import trainer as train

LABELERS = ("dragan", "effdist", "fastapp", "nikolaidis")
METHODS = ("slotv", "trex")
SPLITS = ("train", "trajectory_test", "position_test", "goal_count_test")
SPLIT_TITLES = {
    "train": "train",
    "trajectory_test": "trajectory",
    "position_test": "position",
    "goal_count_test": "goal count",
}
LABELER_TITLES = {
    "dragan": "Dragan",
    "effdist": "EffDist",
    "fastapp": "FastApp",
    "nikolaidis": "Nikolaidis",
}
METHOD_TITLES = {"slotv": "SLOT-V", "trex": "T-REX"}

# The paper's Table 1: mean (SD) accuracy over 10 trials (Wallkötter et al. 2022).
PAPER = {
    ("dragan", "slotv"): [(0.940, 0.064), (0.938, 0.065), (0.895, 0.083), (0.922, 0.064)],
    ("dragan", "trex"): [(0.795, 0.182), (0.792, 0.180), (0.783, 0.170), (0.749, 0.198)],
    ("effdist", "slotv"): [(1.000, 0.000), (1.000, 0.000), (1.000, 0.000), (0.996, 0.005)],
    ("effdist", "trex"): [(0.796, 0.032), (0.798, 0.034), (0.782, 0.033), (0.772, 0.031)],
    ("fastapp", "slotv"): [(0.973, 0.008), (0.972, 0.008), (0.972, 0.013), (0.954, 0.017)],
    ("fastapp", "trex"): [(0.869, 0.034), (0.866, 0.034), (0.879, 0.024), (0.860, 0.006)],
    ("nikolaidis", "slotv"): [(0.911, 0.029), (0.910, 0.031), (0.875, 0.054), (0.893, 0.041)],
    ("nikolaidis", "trex"): [(0.845, 0.033), (0.844, 0.034), (0.841, 0.039), (0.796, 0.040)],
}
PAPER_TABLE = {
    (lab, meth, split): PAPER[(lab, meth)][i]
    for (lab, meth) in PAPER
    for i, split in enumerate(SPLITS)
}


@dataclasses.dataclass(frozen=True)
class Table1Config:
    """What one Table 1 run does."""

    preset: str
    trials: int
    data: data_lib.DataConfig
    train: dict[str, train_config.TrainConfig]  # method -> training config

    def to_json(self) -> dict:
        return {
            "preset": self.preset,
            "trials": self.trials,
            "data": self.data.to_json(),
            "data_digest": self.data.digest(),
            "train": {m: c.to_dict() for m, c in self.train.items()},
        }


def quick() -> Table1Config:
    """CPU preset: quick data, small networks, 2 trials **[choice]**."""
    return Table1Config("quick", 2, data_lib.quick(), {m: train_config.quick(m) for m in METHODS})


def paper() -> Table1Config:
    """The paper's sizes and hyperparameters, 10 trials."""
    return Table1Config("paper", 10, data_lib.paper(), {m: train_config.paper(m) for m in METHODS})


def tiny() -> Table1Config:
    """A seconds-scale preset for tests and smoke runs (not a result)."""
    d = data_lib.DataConfig(
        preset="tiny", n_train=300, n_eval=100, n_train_scenes=20, n_new_scenes=4, chunk_size=512
    )
    t = {
        "slotv": train_config.quick("slotv", hidden=(32, 16), epochs=2, train_size=None),
        "trex": train_config.quick("trex", hidden=(32, 16), epochs=2, train_size=None),
    }
    return Table1Config("tiny", 2, d, t)


PRESETS = {"quick": quick, "paper": paper, "tiny": tiny}


def with_model(cfg: Table1Config, model: str) -> Table1Config:
    """The same run with SLOT-V's network replaced by an observer archetype (SPEC §10,
    :func:`slotv_jax.training.config.archetype` of the matching preset; the tiny preset trains it
    2 epochs on all its data, as its MLP). T-REX keeps its network. ``"mlp"``: ``cfg``."""
    if model == "mlp":
        return cfg
    if cfg.preset == "tiny":
        tc = train_config.archetype("quick", model, epochs=2, train_size=None)
    else:
        tc = train_config.archetype("paper" if cfg.preset == "paper" else "quick", model)
    return dataclasses.replace(cfg, train={**cfg.train, "slotv": tc})


def _train_key(config_doc: dict) -> dict:
    """The training configs of a results document, rebuilt through TrainConfig (so that
    documents written before a field existed compare equal to their defaults)."""
    return {
        m: train_config.TrainConfig.from_dict(c).to_dict()
        for m, c in config_doc.get("train", {}).items()
    }


def with_compute_dtype(cfg: Table1Config, dtype: str) -> Table1Config:
    """The same run with the hidden matmuls in ``dtype`` (parameters stay float32)."""
    train = {m: dataclasses.replace(c, compute_dtype=dtype) for m, c in cfg.train.items()}
    return dataclasses.replace(cfg, train=train)


# ------------------------------------------------------------------- results


def load_results(out: Path, cfg: Table1Config) -> dict:
    """Existing results of the same config (for resuming), or a fresh document."""
    path = out / "results.json"
    fresh = {
        "preset": cfg.preset,
        "config": cfg.to_json(),
        "environment": {},
        "cells": [],
        "summary": [],
        "timing": {"cells": []},
    }
    if not path.exists():
        return fresh
    try:
        doc = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: corrupt results file ({e}); move it away to start over") from e
    old = doc.get("config", {})
    if (old.get("data_digest"), _train_key(old)) != (cfg.data.digest(), _train_key(cfg.to_json())):
        raise ValueError(
            f"{path}: holds results of another configuration; use another --out to start anew"
        )
    doc["config"] = cfg.to_json()  # the trial count may grow between runs
    return doc


def summarise(cells: list[dict]) -> list[dict]:
    """Mean and SD (ddof=1 when n > 1) of accuracy over trials, per (labeler, method, split)."""
    groups: dict[tuple, list[float]] = {}
    for c in cells:
        groups.setdefault((c["labeler"], c["method"], c["split"]), []).append(c["accuracy"])
    out = []
    for (lab, meth, split), accs in sorted(groups.items()):
        a = np.asarray(accs, np.float64)
        sd = float(a.std(ddof=1)) if a.size > 1 else 0.0
        out.append(
            {
                "labeler": lab,
                "method": meth,
                "split": split,
                "mean": float(a.mean()),
                "sd": sd,
                "n": int(a.size),
            }
        )
    return out


def render_table(summary: list[dict]) -> str:
    """Markdown table in the paper's layout: ours ± SD, the paper's, and the difference."""
    by = {(s["labeler"], s["method"], s["split"]): s for s in summary}
    lines = [
        "| labeler | split | SLOT-V (ours) | SLOT-V (paper) | Δ "
        "| T-REX (ours) | T-REX (paper) | Δ |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for lab in LABELERS:
        for i, split in enumerate(SPLITS):
            row = [LABELER_TITLES[lab] if i == 0 else "", SPLIT_TITLES[split]]
            for meth in METHODS:
                s = by.get((lab, meth, split))
                pm, psd = PAPER_TABLE[(lab, meth, split)]
                if s is None:
                    row += ["—", f"{pm:.3f} ({psd:.3f})", "—"]
                else:
                    ours = f"{s['mean']:.3f} ± {s['sd']:.3f} (n={s['n']})"
                    row += [ours, f"{pm:.3f} ({psd:.3f})", f"{s['mean'] - pm:+.3f}"]
            lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


# ----------------------------------------------------------------------- run


def dataset_dir(cache: Path, cfg: data_lib.DataConfig) -> Path:
    """Where a dataset of this config is cached: one directory per config digest."""
    return cache / f"{cfg.preset}-{cfg.digest()}"


def run(
    cfg: Table1Config,
    out: Path,
    *,
    labelers: Sequence[str] = LABELERS,
    methods: Sequence[str] = METHODS,
    cache: Path = Path("data"),
    progress: bool = True,
    vmap_trials: bool = False,
    precompile: bool | None = None,
    time_limit_s: float | None = None,
) -> dict:
    """Run (or resume) Table 1 and return the results document.

    On one device each trial trains on its own (or, with ``vmap_trials``, the pending trials
    of each (labeler, method) together in one vmapped call; they are then written, and lost
    to an interruption, together). On several devices (every process's, under
    ``jax.distributed``) the pending trials of each method, all labelers together, train in
    groups side by side, one per device (:mod:`slotv_jax.training.parallel`: the trial axis sharded
    over the devices; a last group smaller than the device count pads or, for one trial,
    splits the batch over the devices). A group's trials are written as soon as it
    finishes; only process 0 writes.

    With ``precompile`` (default: on accelerators, where compiling the paper-size training
    takes seconds and the CPU is otherwise idle) each pending method's training function is
    compiled in a background thread while the dataset is generated. With ``time_limit_s``
    the run stops before a unit (or group) that would end after that many seconds, judged by
    the last one of the same method; a rerun continues.
    """

    t_start = time.perf_counter()
    writer = distributed.is_writer()
    if writer:
        out.mkdir(parents=True, exist_ok=True)
    doc = load_results(out, cfg)
    doc["environment"] = environment()

    everything = [(lab, meth, t) for lab in labelers for meth in methods for t in range(cfg.trials)]
    finished = {(c["labeler"], c["method"], c["trial"]) for c in doc["cells"]}
    done_mask = distributed.broadcast(np.array([u in finished for u in everything]))
    todo = [u for u, d in zip(everything, done_mask, strict=True) if not d]
    if writer and len(todo) < len(everything):
        print(f"resuming {out}: reusing {len(everything) - len(todo)} finished trial(s) of "
              f"{len(everything)}; {len(todo)} to train", flush=True)  # fmt: skip
    n_dev = jax.device_count()
    if precompile is None:
        precompile = jax.default_backend() != "cpu"
    pending = [] if vmap_trials or not precompile else sorted({m for _, m, _ in todo})
    compiling = _precompile_in_background(cfg, pending, n_dev)

    t0 = time.perf_counter()
    ddir = dataset_dir(cache, cfg.data)
    if not writer:  # process 0 generates (or loads) first: on a shared disk, once
        distributed.barrier("table1 dataset")
    dataset = data_lib.generate_dataset(cfg.data, ddir, progress=progress and writer)
    if writer:
        distributed.barrier("table1 dataset")
    doc["timing"]["data_s"] = time.perf_counter() - t0
    doc["dataset"] = str(ddir)
    for meth, job in compiling.items():
        try:
            job.result()
        except Exception as e:  # an optimisation only: training compiles as usual
            print(f"table1: ahead-of-time compilation of {meth} failed ({e!r})", file=sys.stderr)
    doc["timing"]["precompile_wait_s"] = time.perf_counter() - t0 - doc["timing"]["data_s"]
    doc["timing"]["stopped_by_time_limit"] = False  # of this invocation (a resumed doc had one)

    def save():
        doc["summary"] = summarise(doc["cells"])
        if writer:
            write_text(out / "results.json", json.dumps(doc, indent=1))

    def record(lab, meth, trial, accs, i, times, final_loss, together):
        doc["cells"].extend(
            {"labeler": lab, "method": meth, "split": split, "trial": trial,
             "accuracy": float(accs[split][i])}
            for split in SPLITS
        )  # fmt: skip
        doc["timing"]["cells"].append(
            {"labeler": lab, "method": meth, "trial": trial,
             **{k: v / together for k, v in times.items()},
             "trained_together": together, "final_loss": final_loss}
        )  # fmt: skip

    bar = tqdm(total=len(todo), desc="table1 cells", unit="cell", disable=not (progress and writer))
    steps = _device_steps if n_dev > 1 else _single_device_steps
    last: dict[str, float] = {}
    left = len(todo)
    for meth, units, run_step in steps(cfg, dataset, todo, vmap_trials, n_dev):
        expect = last.get(meth, 0.0)
        stop = time_limit_s is not None and time.perf_counter() - t_start + expect > time_limit_s
        if distributed.broadcast(np.array(stop)):
            doc["timing"]["stopped_by_time_limit"] = True
            print(f"table1: stopping at the time limit ({time_limit_s:.0f} s); "
                  f"{left} cells left, rerun to continue", file=sys.stderr)  # fmt: skip
            break
        bar.set_postfix_str(f"{meth}: {', '.join(f'{lab}/{t}' for lab, t in units)}")
        t_unit = time.perf_counter()
        accs, loss, times = run_step()
        last[meth] = time.perf_counter() - t_unit
        for i, (lab, trial) in enumerate(units):
            record(lab, meth, trial, accs, i, times, float(loss[i, -1].mean()), len(units))
        save()
        left -= len(units)
        bar.update(len(units))
    bar.close()

    doc["timing"]["last_run_total_s"] = time.perf_counter() - t_start
    save()
    if writer:
        write_text(out / "table1.md", report(doc))
    return doc


def _single_device_steps(cfg: Table1Config, dataset, todo, vmap_trials: bool, n_dev: int):
    """One device: yield (method, [(labeler, trial)], step) per trial (or, ``vmap_trials``,
    per (labeler, method)); ``step()`` trains and evaluates, returning (accuracies per
    split, losses, times)."""

    units: list[tuple[str, str, list[int]]] = []
    for lab, meth, trial in todo:
        if vmap_trials and units and units[-1][:2] == (lab, meth):
            units[-1][2].append(trial)
        else:
            units.append((lab, meth, [trial]))
    # Each labeler's splits are validated and trimmed once and shared by both methods.
    prepared: dict[tuple[str, str], types.TrainData] = {}

    def split_data(lab: str, split: str, size: int | None = None) -> types.TrainData:
        if prepared and next(iter(prepared))[0] != lab:
            prepared.clear()  # one labeler's arrays at a time
        if (lab, split) not in prepared:
            prepared[(lab, split)] = types.prepare(dataset[split], lab)
        data = prepared[(lab, split)]
        return data if size is None else types.subset(data, size)

    for lab, meth, trials in units:

        def step(lab=lab, meth=meth, trials=trials):
            tc = cfg.train[meth]
            t_cell = time.perf_counter()
            tdata = split_data(lab, "train")
            t_prep = time.perf_counter() - t_cell
            state, metrics = train.train_trials(tc, tdata, trials, progress=False)
            jax.block_until_ready((state, metrics))
            t_train = time.perf_counter() - t_cell - t_prep
            # "train" is scored on the trajectories the model trained on (the first train_size).
            used = {"train": tc.n_used(len(tdata.xyz))}
            accs = {
                split: np.asarray(
                    evaluate.accuracy(tc, state.params, split_data(lab, split, used.get(split)))
                ).reshape(-1)
                for split in SPLITS
            }
            t_total = time.perf_counter() - t_cell
            times = {"prepare_s": t_prep, "train_s": t_train, "total_s": t_total}
            return accs, np.asarray(metrics.loss), times

        yield meth, [(lab, t) for t in trials], step


def _device_steps(cfg: Table1Config, dataset, todo, vmap_trials: bool, n_dev: int):
    """Several devices: per method, the pending (labeler, trial) units in the groups of
    :func:`slotv_jax.training.parallel.groups`, each trained side by side and evaluated where it
    trained. The trajectories are shared and each unit has its labeler's labels."""

    shared: dict[str, types.TrainData] = {}
    labels: dict[tuple[str, str], np.ndarray] = {}

    def arrays(split: str, labs: Sequence[str], size: int | None = None):
        for lab in labs:
            if (lab, split) not in labels:
                d = types.prepare(dataset[split], lab)  # validates this labeler's labels
                labels[(lab, split)] = np.asarray(d.labels)
                shared.setdefault(split, d)
        d = shared[split] if size is None else types.subset(shared[split], size)
        n = d.xyz.shape[0]
        return d, np.stack([labels[(lab, split)][:n] for lab in labs])

    for meth in dict.fromkeys(m for _, m, _ in todo):
        units = [(lab, t) for lab, m, t in todo if m == meth]
        tc = cfg.train[meth]
        for group, t in schedule.groups(units, n_dev):

            def step(group=group, t=t, tc=tc):
                labs = [lab for lab, _ in group]
                mesh = schedule.unit_mesh(t, tc.batch_size)
                t_cell = time.perf_counter()
                tdata, tlabels = arrays("train", labs)
                t_prep = time.perf_counter() - t_cell
                seeds = [trial for _, trial in group]
                state, metrics = parallel.train_group(tc, tdata, seeds, mesh, labels=tlabels)
                jax.block_until_ready((state, metrics))
                t_train = time.perf_counter() - t_cell - t_prep
                used = {"train": tc.n_used(len(tdata.xyz))}
                accs = {}
                for split in SPLITS:
                    d, lab_arr = arrays(split, labs, used.get(split))
                    accs[split] = parallel.group_accuracy(tc, state.params, d, mesh, labels=lab_arr)
                loss = distributed.fetch(metrics.loss)  # (padded runs, E, K): the first are ours
                t_total = time.perf_counter() - t_cell
                times = {"prepare_s": t_prep, "train_s": t_train, "total_s": t_total}
                return accs, loss, times

            yield meth, group, step


def _precompile_in_background(cfg: Table1Config, methods: Sequence[str], n_dev: int = 1) -> dict:
    """Start the ahead-of-time compilation of each method's training function, for the
    shape the training split will have (its size, points, and largest goal count): on one
    device :func:`slotv_jax.training.trainer.precompile`, on several the full group of
    :func:`slotv_jax.training.parallel.precompile_group`. Returns the futures."""

    if not methods:
        return {}
    d = cfg.data
    shape = (d.n_train, d.trajectory.n_points, max(d.train_goal_counts))
    pool = ThreadPoolExecutor(max_workers=len(methods), thread_name_prefix="precompile")
    if n_dev == 1:
        jobs = {m: pool.submit(train.precompile, cfg.train[m], *shape) for m in methods}
    else:
        jobs = {
            m: pool.submit(
                parallel.precompile_group,
                cfg.train[m],
                *shape,
                schedule.unit_mesh(n_dev, cfg.train[m].batch_size),
            )
            for m in methods
        }
    pool.shutdown(wait=False)
    return jobs


def merge(docs: Sequence[dict]) -> dict:
    """One results document from several runs of the same configuration (for example one
    per GPU or machine, each given other ``--labelers``): the union of their cells.

    Raises ValueError if the configurations differ or two runs disagree on a cell.
    """
    if not docs:
        raise ValueError("merge: expected at least one results document")
    first = docs[0]
    key = (first["config"].get("data_digest"), _train_key(first["config"]))
    cells: dict[tuple, dict] = {}
    timing: dict[tuple, dict] = {}
    for i, doc in enumerate(docs):
        if (doc["config"].get("data_digest"), _train_key(doc["config"])) != key:
            raise ValueError(f"merge: document {i} holds results of another configuration")
        for c in doc["cells"]:
            k = (c["labeler"], c["method"], c["split"], c["trial"])
            if k in cells and cells[k]["accuracy"] != c["accuracy"]:
                raise ValueError(f"merge: documents disagree on cell {k}")
            cells[k] = c
        for t in doc["timing"]["cells"]:
            timing.setdefault((t["labeler"], t["method"], t["trial"]), t)
    out = json.loads(json.dumps(first))
    out["config"]["trials"] = max(d["config"]["trials"] for d in docs)
    out["cells"] = [cells[k] for k in sorted(cells)]
    out["summary"] = summarise(out["cells"])
    out["timing"] = {
        "cells": [timing[k] for k in sorted(timing)],
        "runs": [{k: v for k, v in d["timing"].items() if k != "cells"} for d in docs],
    }
    return out


def report(doc: dict) -> str:
    """The Markdown report: how it was made and the table."""
    env = doc["environment"]
    cells = doc["timing"]["cells"]
    per_cell = np.mean([c["total_s"] for c in cells]) if cells else float("nan")
    model = doc["config"].get("train", {}).get("slotv", {}).get("model", "mlp")
    note = (
        []
        if model == "mlp"
        else [
            f"The SLOT-V columns are the `{model}` observer archetype "
            "(slotv_jax.observers.parametric), trained with SLOT-V's loss; the paper's SLOT-V "
            "is its network. T-REX is the MLP.",
            "",
        ]
    )
    return "\n".join(
        [
            f"# Table 1 ({doc['preset']} preset)",
            "",
            *note,
            f"Accuracy (SPEC §8) as mean ± SD over trials; the paper's values (10 trials) "
            f"in parentheses. {len(doc['cells']) // len(SPLITS)} trained models, "
            f"{per_cell:.1f} s per cell on average (training and evaluation).",
            "",
            f"jax {env.get('jax')}, flax {env.get('flax')}, mujoco {env.get('mujoco')}, "
            f"devices {env.get('devices')}.",
            "",
            render_table(doc["summary"]),
            "",
        ]
    )


def is_results_dir(path: Path) -> bool:
    """True if ``path`` holds an experiment's ``results.json`` (the marker of our output)."""
    return (Path(path) / "results.json").is_file()


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="python -m slotv_jax.experiments.table1",
        description="Reproduce Table 1 of the SLOT-V paper.",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--labelers", nargs="+", choices=LABELERS, default=list(LABELERS))
    p.add_argument("--methods", nargs="+", choices=METHODS, default=list(METHODS))
    p.add_argument("--trials", type=int, help="trials per cell (default: the preset's)")
    p.add_argument("--out", type=Path, help="results directory (default: runs/table1_<preset>)")
    p.add_argument("--cache", type=Path, default=Path("data"), help="dataset cache directory")
    p.add_argument(
        "--distribution",
        choices=sorted(data_lib.DATA_DISTRIBUTIONS),
        default="default",
        help="dataset distribution: trajectories and label temperatures (default: chosen by "
        "the fidelity ablation; spec_v1: the first version's 3-5 via points and β)",
    )
    p.add_argument(
        "--compute-dtype",
        choices=("float32", "bfloat16"),
        help="matmul dtype of the hidden layers (default: the preset's, float32)",
    )
    p.add_argument(
        "--model",
        choices=train_config.MODELS,
        default="mlp",
        help="observer trained with SLOT-V's loss: the paper's network (mlp, default) or a "
        "parametric archetype (SPEC §10); T-REX keeps its network",
    )
    p.add_argument(
        "--vmap-trials",
        action="store_true",
        help="train the trials of each (labeler, method) together in one vmapped call",
    )
    p.add_argument(
        "--merge",
        nargs="+",
        type=Path,
        metavar="DIR",
        help="only merge the results.json of these run directories (same configuration, "
        "e.g. one per GPU) into --out, and render the table",
    )
    p.add_argument(
        "--time-limit",
        type=float,
        metavar="SECONDS",
        help="stop before a trial (group) that would end after this many seconds; "
        "rerun the same command to continue",
    )
    distributed.add_cli_args(p)
    args = p.parse_args(argv)
    suffix = "" if args.model == "mlp" else f"_{args.model}"
    out = args.out or Path("runs") / f"table1_{args.preset}{suffix}"
    if args.merge and args.out is None:
        raise cli.InputError("--merge needs --out")
    # a results directory of ours is resumed (finished cells are kept); else refused
    fileio.check_output_dir(out, ours=is_results_dir, resume=True)
    distributed.init_from_args(args)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)
    if args.merge:
        try:
            doc = merge([fileio.read_json(d / "results.json") for d in args.merge])
        except KeyError as e:
            raise cli.InputError(f"--merge: a results.json lacks the field {e}") from None
        args.out.mkdir(parents=True, exist_ok=True)
        write_text(args.out / "results.json", json.dumps(doc, indent=1))
        write_text(args.out / "table1.md", report(doc))
        print(render_table(doc["summary"]))
        return 0

    cfg = PRESETS[args.preset]()
    if args.trials is not None:
        if args.trials < 1:
            p.error("--trials: expected an integer >= 1")
        cfg = dataclasses.replace(cfg, trials=args.trials)
    if args.compute_dtype is not None:
        cfg = with_compute_dtype(cfg, args.compute_dtype)
    if args.distribution != "default":
        cfg = dataclasses.replace(cfg, data=data_lib.with_distribution(cfg.data, args.distribution))
    if args.time_limit is not None and not args.time_limit >= 0:
        p.error("--time-limit: expected a number of seconds >= 0")
    cfg = with_model(cfg, args.model)
    t0 = time.perf_counter()
    doc = run(
        cfg,
        out,
        labelers=args.labelers,
        methods=args.methods,
        cache=args.cache,
        vmap_trials=args.vmap_trials,
        time_limit_s=args.time_limit,
    )
    if not distributed.is_writer():
        return 0
    print()
    print(render_table(doc["summary"]))
    print(
        f"\n{len(doc['cells'])} cell results in {out / 'results.json'}; table in "
        f"{out / 'table1.md'}; this run took {time.perf_counter() - t0:.0f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
