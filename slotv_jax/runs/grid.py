"""The resumable grid of trained cells: every (labeler, method, trial) trained on a cached
dataset and scored on the table splits, each cell written to ``OUT/results.json`` as soon as
it finishes (:ref:`concepts-public-names`), on one device or side by side on many.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from functools import partial
from pathlib import Path

import jax
import numpy as np
from tqdm.auto import tqdm

from slotv_jax.core import distributed
from slotv_jax.core.defaults import LABELER_NAMES, TEST_SPLITS
from slotv_jax.core.environment import environment
from slotv_jax.core.fileio import write_text
from slotv_jax.data.generate import cached_dataset
from slotv_jax.data.storage import dataset_dir
from slotv_jax.runs.presets import METHODS, RunConfig, _train_key
from slotv_jax.runs.summary import pooled
from slotv_jax.training import evaluate, parallel, schedule, types
from slotv_jax.training import trainer as train

# ------------------------------------------------------------------- results


def load_results(out: Path, cfg: RunConfig) -> dict:
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
    """Mean and SD (ddof=1 when n > 1) of accuracy over trials, per (labeler, method, split)
    (:func:`slotv_jax.runs.summary.pooled`)."""
    return pooled(cells, ("labeler", "method", "split"))


def run(
    cfg: RunConfig,
    out: Path,
    *,
    labelers: Sequence[str] = LABELER_NAMES,
    methods: Sequence[str] = METHODS,
    cache: Path = Path("data"),
    progress: bool = True,
    vmap_trials: bool = False,
    time_limit_s: float | None = None,
) -> dict:
    """Run (or resume) the grid of ``cfg`` into ``out`` and return the results document.

    Every (labeler, method, trial) of ``labelers`` × ``methods`` × ``cfg.trials`` is trained
    on the cached dataset of ``cfg.data`` (:func:`slotv_jax.data.cached_dataset`) and scored
    on :data:`slotv_jax.runs.presets.SPLITS`; the document (:ref:`concepts-public-names`:
    ``preset``, ``config``, ``environment``, ``cells``, ``summary``, ``timing``) is written to
    ``OUT/results.json`` after every cell, and a rerun skips the finished cells.

    On one device each trial trains on its own (or, with ``vmap_trials``, the pending trials
    of each (labeler, method) together in one vmapped call; they are then written, and lost
    to an interruption, together). On several devices (every process's, under
    ``jax.distributed``) the pending trials of each method, all labelers together, train in
    groups side by side, one per device (:mod:`slotv_jax.training.parallel`: the trial axis sharded
    over the devices; a last group smaller than the device count pads or, for one trial,
    splits the batch over the devices). A group's trials are written as soon as it
    finishes; only process 0 writes.

    With ``time_limit_s``
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

    t0 = time.perf_counter()
    dataset = cached_dataset(cfg.data, cache, progress=progress)
    doc["timing"]["data_s"] = time.perf_counter() - t0
    doc["dataset"] = str(dataset_dir(cache, cfg.data))
    doc["timing"]["stopped_by_time_limit"] = False  # of this invocation (a resumed doc had one)

    def save():
        doc["summary"] = summarise(doc["cells"])
        if writer:
            write_text(out / "results.json", json.dumps(doc, indent=1))

    def record(lab, meth, trial, accs, i, times, final_loss, together):
        doc["cells"].extend(
            {"labeler": lab, "method": meth, "split": split, "trial": trial,
             "accuracy": float(accs[split][i])}
            for split in TEST_SPLITS
        )  # fmt: skip
        doc["timing"]["cells"].append(
            {"labeler": lab, "method": meth, "trial": trial,
             **{k: v / together for k, v in times.items()},
             "trained_together": together, "final_loss": final_loss}
        )  # fmt: skip

    bar = tqdm(total=len(todo), desc="cells", unit="cell", disable=not (progress and writer))
    # one device: each cell's training bar too (several: every process compiles the same
    # program, with no progress callback, and only process 0 shows bars)
    steps = _device_steps if n_dev > 1 else partial(_single_device_steps, progress=progress)
    last: dict[str, float] = {}
    left = len(todo)
    for meth, units, run_step in steps(cfg, dataset, todo, vmap_trials, n_dev):
        expect = last.get(meth, 0.0)
        stop = time_limit_s is not None and time.perf_counter() - t_start + expect > time_limit_s
        if distributed.broadcast(np.array(stop)):
            doc["timing"]["stopped_by_time_limit"] = True
            print(f"stopping at the time limit ({time_limit_s:.0f} s); "
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
    return doc


def _single_device_steps(
    cfg: RunConfig, dataset, todo, vmap_trials: bool, n_dev: int, progress: bool = False
):
    """One device: yield (method, [(labeler, trial)], step) per trial (or, ``vmap_trials``,
    per (labeler, method)); ``step()`` trains (``progress``: with the trainer's bar, which
    also says when it compiles) and evaluates, returning (accuracies per split, losses,
    times)."""

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
            state, metrics = train.train_trials(tc, tdata, trials, progress=progress)
            jax.block_until_ready((state, metrics))
            t_train = time.perf_counter() - t_cell - t_prep
            # "train" is scored on the trajectories the model trained on (the first train_size).
            used = {"train": tc.n_used(len(tdata.xyz))}
            accs = {
                split: np.asarray(
                    evaluate.accuracy(tc, state.params, split_data(lab, split, used.get(split)))
                ).reshape(-1)
                for split in TEST_SPLITS
            }
            t_total = time.perf_counter() - t_cell
            times = {"prepare_s": t_prep, "train_s": t_train, "total_s": t_total}
            return accs, np.asarray(metrics.loss), times

        yield meth, [(lab, t) for t in trials], step


def _device_steps(cfg: RunConfig, dataset, todo, vmap_trials: bool, n_dev: int):
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
                for split in TEST_SPLITS:
                    d, lab_arr = arrays(split, labs, used.get(split))
                    accs[split] = parallel.group_accuracy(tc, state.params, d, mesh, labels=lab_arr)
                loss = distributed.fetch(metrics.loss)  # (padded runs, E, K): the first are ours
                t_total = time.perf_counter() - t_cell
                times = {"prepare_s": t_prep, "train_s": t_train, "total_s": t_total}
                return accs, loss, times

            yield meth, group, step


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


def is_results_dir(path: Path) -> bool:
    """True if ``path`` holds an experiment's ``results.json`` (the marker of our output)."""
    return (Path(path) / "results.json").is_file()
