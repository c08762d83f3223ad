"""Fidelity ablation: what the paper's unreported choices do to Table 1
(:ref:`concepts-trajectories`, :ref:`concepts-labelers`, :ref:`concepts-table1`).

The paper does not state every choice its datasets rest on. This experiment varies
one factor at a time from a base setting and records, for each setting:

- the **label statistics** of the four labelers on the four Table 1 splits
  (:func:`slotv_jax.experiments.split_stats`): label entropy over the
  uniform entropy, the top-1/top-2 margin, how often ``argmax y`` is the true target,
  and how often all four labelers agree;
- **SLOT-V and T-REX accuracy** on the four Table 1 splits for the trained labelers
  (Dragan and Nikolaidis by default: the cells furthest from the paper), with
  ``key_trials`` trials for the settings the conclusions rest on and ``trials`` for
  the others.

The factors (base: one via point, equal arc-length spacing, the SPEC's via box,
the first version's β: 5 (Dragan, EffDist, FastApp) and 7.5 (Nikolaidis)):

==========  ==============================================================
via         via-point counts 0, 1, 2, 3, {1, 2, 3} and {3, 4, 5}
beta        all four β at ×1 and ×4 the first version's (Dragan 5,
            Nikolaidis 7.5, EffDist 5, FastApp 5)
box         the SPEC's via box, and a tighter one over the goal table
timing      equal arc length, or equal time per segment (as the first
            author's public ``legibility`` code samples its 100 points)
defaults    around the first stage's defaults (one via point, β ×4, the
            SPEC's box): Nikolaidis' β alone at ×8 and ×16 (the others stay
            ×4), and the table box
==========  ==============================================================

The last factor is a second stage: the first four vary one choice from the first
version's base, ``defaults`` asks what the choices left open after that (a temperature
per labeler, the box) add to the defaults they picked. Its ``default+box=tight`` setting
is the current default distribution (generator version 7): one via point in the table
box, arc length, β ×4.

Each setting is a Table 1 run (:func:`slotv_jax.runs.grid.run`) in its own
directory ``OUT/<setting>/``: datasets are cached by config digest and finished cells
resume. Then ``OUT/results.json`` collects everything, and the report (tables and
``fidelity.png``: accuracy against each factor, the paper's values as reference lines)
is written.

    python -m slotv_jax.experiments.fidelity                          # quick preset (CPU)
    python -m slotv_jax.experiments.fidelity --preset paper --compute-dtype bfloat16
    python -m slotv_jax.experiments.fidelity --settings via=1 via=3-5 # a subset
    python -m slotv_jax.experiments.fidelity --report-only --out DIR  # re-render

The report goes to ``OUT/fidelity.md`` (and ``.png``); ``--doc`` chooses another path
(``--doc experiments/fidelity.md`` rewrites the record).
"""

from __future__ import annotations

import dataclasses
import json
import shlex
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.core import cli, fileio
from slotv_jax.core.defaults import LABELER_NAMES, TEST_SPLITS
from slotv_jax.core.fileio import write_text
from slotv_jax.data.stats import split_stats
from slotv_jax.experiments.fidelity_report import FACTOR_TITLES, render_markdown, write_report
from slotv_jax.runs import command, grid, presets
from slotv_jax.training import config as train_config
from slotv_jax.world.trajectories import SPEC_VIA_BOX, TABLE_VIA_BOX

FACTORS = tuple(FACTOR_TITLES)  # via, beta, box, timing, defaults
VIA_COUNTS = ((0,), (1,), (2,), (3,), (1, 2, 3), (3, 4, 5))
BETA_SCALES = (1.0, 4.0)  # × the first version's β (Dragan 5, Nikolaidis 7.5, EffDist 5, FastApp 5)
NIKOLAIDIS_SCALES = (8.0, 16.0)  # Nikolaidis' β alone, × the first version's, at the defaults
KEY_SETTINGS = ("via=1", "via=3-5", "via=1-3")


@dataclasses.dataclass(frozen=True)
class Setting:
    """One point of the ablation: a dataset config and how many trials to train on it."""

    name: str  # short id, also the directory name, e.g. "via=1-3"
    factor: str  # one of FACTORS
    value: str  # the factor's value in words, e.g. "{1, 2, 3}"
    data: data_lib.DataConfig
    trials: int


@dataclasses.dataclass(frozen=True)
class FidelityConfig:
    """What one ablation run does."""

    preset: str
    base: data_lib.DataConfig  # the base setting every factor varies from
    train: dict[str, train_config.TrainConfig]  # method -> training config
    labelers: tuple[str, ...] = ("dragan", "nikolaidis")  # labelers trained per setting
    methods: tuple[str, ...] = presets.METHODS
    trials: int = 1  # trials of an ordinary setting
    key_trials: int = 3  # trials of the settings in KEY_SETTINGS

    def to_json(self) -> dict:
        return {
            "preset": self.preset,
            "base": self.base.to_json(),
            "train": {m: c.to_dict() for m, c in self.train.items()},
            "labelers": list(self.labelers),
            "methods": list(self.methods),
            "trials": self.trials,
            "key_trials": self.key_trials,
            "key_settings": list(KEY_SETTINGS),
        }


def _base_data(d: data_lib.DataConfig) -> data_lib.DataConfig:
    """The base setting: one via point, arc length, the SPEC's box, the first version's β."""
    traj = dataclasses.replace(
        d.trajectory,
        via_counts=(1,),
        timing="arc_length",
        via_low=SPEC_VIA_BOX[0],
        via_high=SPEC_VIA_BOX[1],
    )
    return dataclasses.replace(d, trajectory=traj, labels=data_lib.LABELS_V1)


def quick() -> FidelityConfig:
    """CPU preset: the quick networks on 4,000 training and 1,000 evaluation trajectories."""
    base = _base_data(data_lib.quick(n_train=4000, n_eval=1000))
    return FidelityConfig("quick", base, {m: train_config.quick(m) for m in presets.METHODS})


def paper() -> FidelityConfig:
    """The paper's dataset sizes and training hyperparameters."""
    base = _base_data(data_lib.paper())
    return FidelityConfig("paper", base, {m: train_config.paper(m) for m in presets.METHODS})


def tiny() -> FidelityConfig:
    """Seconds-scale preset for tests (not a result)."""
    t1 = presets.tiny()
    return FidelityConfig("tiny", _base_data(t1.data), t1.train, key_trials=1)


PRESETS = {"quick": quick, "paper": paper, "tiny": tiny}


def _counts_name(counts: tuple[int, ...]) -> str:
    if len(counts) == 1:
        return str(counts[0])
    if counts == tuple(range(counts[0], counts[-1] + 1)):
        return f"{counts[0]}-{counts[-1]}"
    return ",".join(map(str, counts))


def settings(cfg: FidelityConfig) -> list[Setting]:
    """Every setting of the ablation, base first; each varies one factor from ``cfg.base``."""
    base = cfg.base
    out: list[tuple[str, str, str, data_lib.DataConfig]] = []

    def traj(**kw) -> data_lib.DataConfig:
        return dataclasses.replace(base, trajectory=dataclasses.replace(base.trajectory, **kw))

    for counts in VIA_COUNTS:
        value = "{" + ", ".join(map(str, counts)) + "}" if len(counts) > 1 else str(counts[0])
        out.append((f"via={_counts_name(counts)}", "via", value, traj(via_counts=counts)))
    for k in BETA_SCALES:
        v1 = data_lib.LABELS_V1
        labels = dataclasses.replace(
            base.labels,
            **{f"beta_{n}": k * getattr(v1, f"beta_{n}") for n in LABELER_NAMES},
        )
        out.append((f"beta=x{k:g}", "beta", f"×{k:g}", dataclasses.replace(base, labels=labels)))
    out.append(("box=spec", "box", "SPEC", base))
    out.append(
        ("box=tight", "box", "tight", traj(via_low=TABLE_VIA_BOX[0], via_high=TABLE_VIA_BOX[1]))
    )
    out.append(("timing=arc", "timing", "arc length", base))
    out.append(("timing=segment", "timing", "per segment", traj(timing="segment")))
    # Second stage, around the chosen defaults (β ×4 for all four labelers).
    x4 = next(d for n, _, _, d in out if n == "beta=x4")
    out.append(("default", "defaults", "defaults", x4))
    for k in NIKOLAIDIS_SCALES:
        beta = k * data_lib.LABELS_V1.beta_nikolaidis
        labels = dataclasses.replace(x4.labels, beta_nikolaidis=beta)
        out.append((f"default+nik=x{k:g}", "defaults", f"Nik. β ×{k:g}",
                    dataclasses.replace(x4, labels=labels)))  # fmt: skip
    tight = dataclasses.replace(x4.trajectory, via_low=TABLE_VIA_BOX[0], via_high=TABLE_VIA_BOX[1])
    out.append(("default+box=tight", "defaults", "tight box",
                dataclasses.replace(x4, trajectory=tight)))  # fmt: skip
    return [
        Setting(n, f, v, d, cfg.key_trials if n in KEY_SETTINGS else cfg.trials)
        for n, f, v, d in out
    ]


def unique_runs(all_settings: Sequence[Setting]) -> dict[str, Setting]:
    """Map each setting's name to the setting whose directory holds its results.

    Settings with equal dataset configs (``via=1``, ``beta=x1``, ``box=spec`` and
    ``timing=arc`` all equal the base) share one run: the first of them, with the largest
    trial count of the group.
    """
    groups: dict[str, list[Setting]] = {}
    for s in all_settings:
        groups.setdefault(s.data.digest(), []).append(s)
    owner = {}
    for group in groups.values():
        run = dataclasses.replace(group[0], trials=max(s.trials for s in group))
        owner.update({s.name: run for s in group})
    return owner


# ----------------------------------------------------------------------- run


def _label_stats(ddir: Path) -> dict:
    """:func:`split_stats` of the four Table 1 splits, plus their mean."""
    per = {name: split_stats(data_lib.load_split(ddir, name)) for name in TEST_SPLITS}
    mean = {
        lab: {
            k: float(np.mean([per[s]["labelers"][lab][k] for s in TEST_SPLITS]))
            for k in ("entropy_ratio", "margin", "near_tie", "target_agreement", "chance")
        }
        for lab in data_lib.LABELER_NAMES
    }
    all_agree = float(np.mean([per[s]["all_agree"] for s in TEST_SPLITS]))
    return {"splits": per, "mean": mean, "all_agree": all_agree}


def run_setting(
    cfg: FidelityConfig, s: Setting, out: Path, *, cache: Path, progress: bool = True
) -> dict:
    """Train and evaluate one setting (resuming), and collect its label statistics."""
    t0 = time.perf_counter()
    t1 = presets.RunConfig(cfg.preset, s.trials, s.data, cfg.train)
    doc = grid.run(
        t1, out / s.name, labelers=cfg.labelers, methods=cfg.methods, cache=cache, progress=progress
    )
    stats_path = out / s.name / "label_stats.json"
    if stats_path.exists():
        stats = json.loads(stats_path.read_text())
    else:
        stats = _label_stats(Path(doc["dataset"]))
        write_text(stats_path, json.dumps(stats, indent=1))
    return {"doc": doc, "label_stats": stats, "time_s": time.perf_counter() - t0}


def collect(cfg: FidelityConfig, out: Path, previous: dict | None = None) -> dict:
    """``OUT/results.json``: every setting with its label statistics and accuracy summary,
    read from the setting directories that exist.

    ``previous`` (an earlier ``results.json``, e.g. ``experiments/fidelity_results.json``)
    supplies the settings whose directories are not in ``out``: runs made on other
    machines join the report. A setting found in both comes from ``out``.
    """
    owner = unique_runs(settings(cfg))
    earlier = {r["run"]: r for r in (previous or {}).get("settings", [])}
    rows = []
    env = {}
    for s in settings(cfg):
        run_name = owner[s.name].name
        d = out / run_name
        if (d / "results.json").exists() and (d / "label_stats.json").exists():
            doc = json.loads((d / "results.json").read_text())
            env = env or doc.get("environment", {})
            found = {
                "label_stats": json.loads((d / "label_stats.json").read_text()),
                "summary": doc["summary"],
                "cells": doc["cells"],
                "timing": doc["timing"],
            }
        elif run_name in earlier:
            found = {k: earlier[run_name][k] for k in ("label_stats", "summary", "cells", "timing")}
        else:
            continue
        rows.append(
            {
                "name": s.name,
                "factor": s.factor,
                "value": s.value,
                "run": run_name,
                "data_digest": s.data.digest(),
                "trajectory": dataclasses.asdict(s.data.trajectory),
                "labels": dataclasses.asdict(s.data.labels),
                **found,
            }
        )
    env = env or (previous or {}).get("environment", {})
    return {
        "preset": cfg.preset,
        "config": cfg.to_json(),
        "environment": env,
        "settings": rows,
    }


def run(
    cfg: FidelityConfig,
    out: Path,
    *,
    only: Sequence[str] | None = None,
    cache: Path = Path("data"),
    progress: bool = True,
    previous: dict | None = None,
) -> dict:
    """Run (or resume) the ablation; ``only`` restricts it to the named settings, and
    ``previous`` (see :func:`collect`) joins earlier runs to the results."""
    out.mkdir(parents=True, exist_ok=True)
    all_settings = settings(cfg)
    names = [s.name for s in all_settings]
    unknown = sorted(set(only or ()) - set(names))
    if unknown:
        raise ValueError(f"settings: unknown {unknown}; expected names from {names}")
    owner = unique_runs(all_settings)
    runs = {owner[n].name: owner[n] for n in (only or names)}
    for s in tqdm(runs.values(), desc="fidelity settings", unit="setting", disable=not progress):
        run_setting(cfg, s, out, cache=cache, progress=progress)
    doc = collect(cfg, out, previous)
    write_text(out / "results.json", json.dumps(doc, indent=1))
    return doc


# ----------------------------------------------------------------------- CLI


@cli.command(resumes=True)
def main(argv: Sequence[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.fidelity",
        description="Ablation of the paper's unreported dataset choices "
        "(concepts: trajectories, labelers).",
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick")
    p.add_argument("--out", type=Path, help="results directory (default: runs/fidelity_<preset>)")
    p.add_argument("--cache", type=Path, default=Path("data"), help="dataset cache directory")
    p.add_argument("--settings", nargs="+", help="run only these settings (default: all)")
    p.add_argument("--labelers", nargs="+", choices=LABELER_NAMES, help="labelers to train")
    p.add_argument("--trials", type=int, help="trials of an ordinary setting")
    p.add_argument("--key-trials", type=int, help=f"trials of {', '.join(KEY_SETTINGS)}")
    p.add_argument("--compute-dtype", choices=("float32", "bfloat16"))
    p.add_argument("--doc", type=Path, help="report path (default: see the module docstring)")
    p.add_argument("--report-only", action="store_true", help="only collect and re-render")
    p.add_argument(
        "--previous",
        type=Path,
        help="an earlier results.json whose settings join the report where OUT lacks them",
    )
    p.add_argument("--list", action="store_true", help="list the settings and exit")
    args = p.parse_args(argv)
    print(slotv_jax.XLA_CONFIG.summary(), file=sys.stderr)

    cfg = PRESETS[args.preset]()
    kw = {}
    if args.labelers:
        kw["labelers"] = tuple(args.labelers)
    command.at_least_one(p, trials=args.trials, key_trials=args.key_trials)
    kw |= {n: v for n, v in (("trials", args.trials), ("key_trials", args.key_trials)) if v}
    if args.compute_dtype:
        kw["train"] = command.retrained(cfg.train, args.compute_dtype)
    cfg = dataclasses.replace(cfg, **kw)
    if args.list:
        for s in settings(cfg):
            print(f"{s.name:>16s}  {s.factor:>6s}  {s.value:<12s} trials {s.trials}")
        return 0
    out = args.out or Path("runs") / f"fidelity_{args.preset}"
    fileio.check_output_dir(out, ours=fileio.is_results_dir, resume=True)  # a rerun resumes
    doc_path = args.doc or out / "fidelity.md"
    fileio.check_output_files(doc_path.parent, [doc_path.name], what="--doc")
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    previous = None
    if args.previous:
        try:
            previous = json.loads(args.previous.read_text())
        except (OSError, ValueError) as e:
            p.error(f"--previous: cannot read {args.previous} as JSON ({e})")
    if args.report_only:
        doc = collect(cfg, out, previous)
        write_text(out / "results.json", json.dumps(doc, indent=1))
    else:
        try:
            doc = run(cfg, out, only=args.settings, cache=args.cache, previous=previous)
        except ValueError as e:
            p.error(str(e))
    wall = None if args.report_only else time.perf_counter() - t0
    cmd = "python -m slotv_jax.experiments.fidelity " + shlex.join(
        sys.argv[1:] if argv is None else list(argv)
    )
    write_report(doc, doc_path, command=cmd.strip(), wall_s=wall)
    print(render_markdown(doc))
    print(f"\nresults in {out / 'results.json'}; report in {doc_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
