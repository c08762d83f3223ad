"""The command-line pieces the experiments share: the flags of a run over presets and seeds,
the checks of their values, and the output files checked before any work starts
(:ref:`concepts-commands`: an input error is one line ``error: ...`` and exit code 2,
:mod:`slotv_jax.core.cli`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections.abc import Callable, Sequence
from pathlib import Path

from slotv_jax.core import cli, fileio, validation
from slotv_jax.runs import record
from slotv_jax.training import config as train_config

#: The folder every command writes to by default (git ignores it). The recorded documents in
#: ``experiments/`` are rewritten only by a command whose ``--out`` names that folder.
DEFAULT_OUT = Path("runs")


def seeded_parser(prog: str, description: str, presets: Sequence[str]) -> argparse.ArgumentParser:
    """The command line of an experiment run over seeds and selection strategies (the two
    active-selection experiments): preset, output and cache folders, seeds, held-out
    motions, strategies; :func:`seeded_overrides` reads it back."""
    ap = cli.ArgumentParser(prog=prog, description=description)
    ap.add_argument("--preset", default="quick", choices=tuple(presets))
    ap.add_argument(
        "--out", default=str(DEFAULT_OUT), help=f"output folder (default: {DEFAULT_OUT})"
    )
    ap.add_argument("--cache", default="data", help="dataset cache folder")
    ap.add_argument("--seeds", type=int, default=None)
    ap.add_argument("--first-seed", type=int, default=None, help="seeds from this one (tuning)")
    ap.add_argument(
        "--eval-offset", type=int, default=None, help="held-out motions from this one (tuning)"
    )
    ap.add_argument("--strategies", default=None, help="comma-separated, random among them")
    ap.add_argument(
        "--report",
        action="store_true",
        help="only render the report and figure again from the results document in --out",
    )
    ap.add_argument("--no-progress", action="store_true")
    return ap


def seeded_overrides(args: argparse.Namespace, names: Sequence[str] = ()) -> dict:
    """The preset's fields that a :func:`seeded_parser` command line sets: seeds,
    first_seed, eval_offset, the strategies, and the flags ``names``."""
    if args.first_seed is not None:
        validation.check_seeds(
            "--first-seed", args.first_seed, args.seeds or 1, count_name="--seeds"
        )
    kw = {n: getattr(args, n) for n in ("seeds", "first_seed", "eval_offset", *names)}
    kw = {n: v for n, v in kw.items() if v is not None}
    if args.strategies:
        kw["strategies"] = tuple(s.strip() for s in args.strategies.split(","))
    return kw


def prepare_out(
    out: Path, stem: str, is_ours: Callable[[Path], bool], results: str | None = None
) -> None:
    """Before any work: ``OUT/STEM_results.json`` (or ``OUT/results``), ``STEM.md`` and
    ``STEM.png`` can be written, and the results document, if there, is ours (``is_ours``;
    it is resumed and the report and figure rewritten from it), and a report or figure
    there stands beside it; then make ``out``."""
    names = [results or f"{stem}_results.json", f"{stem}.md", f"{stem}.png"]
    fileio.check_output_files(out, names, ours={names[0]: is_ours}, beside=names[0])
    out.mkdir(parents=True, exist_ok=True)


def at_least_one(parser: argparse.ArgumentParser, **values: int | None) -> None:
    """``parser.error`` (one line, exit code 2) naming the first flag whose value is below 1
    (``values``: flag name with underscores -> value; None: not given)."""
    for name, v in values.items():
        if v is not None and v < 1:
            parser.error(f"--{name.replace('_', '-')}: expected an integer >= 1")


def render_again(
    out: Path,
    stem: str,
    is_ours: Callable[[Path], bool],
    render: Callable[[dict, str], None],
    default_command: str,
    results: str | None = None,
) -> int:
    """A command's ``--report``: render ``OUT/STEM.md`` and ``OUT/STEM.png`` again from the
    results document ``OUT/STEM_results.json`` (or ``OUT/results``) alone, no dataset, no
    training. ``render(doc, command)`` writes them; the command they name is the one the
    existing report names (:func:`slotv_jax.runs.record.recorded_command`), else
    ``default_command``, each of its lines naming ``--out`` where ``out`` is not the
    default (:func:`slotv_jax.runs.record.with_out`), so that a rerun writes there again."""
    path = out / (results or f"{stem}_results.json")
    if not path.is_file():
        raise cli.InputError(f"--report: no results document {path} (--out names the run's folder)")
    if not is_ours(path):
        raise cli.InputError(f"--report: {path} is not a results document of this experiment")
    outputs = [f"{stem}.md", f"{stem}.png"]
    fileio.check_output_files(out, outputs)
    doc = json.loads(path.read_text(encoding="utf-8"))
    cmd = record.recorded_command(out / outputs[0]) or default_command
    render(doc, record.with_out(cmd, out, DEFAULT_OUT))
    print(f"wrote {', '.join(outputs)} in {out} from {path.name}")
    return 0


def retrained(train: dict, compute_dtype: str | None = None, sets: Sequence[str] = ()) -> dict:
    """The training configs ``train`` (method -> TrainConfig) with ``--compute-dtype`` (the
    matmul dtype, when given) and then the ``--set KEY=VALUE`` overrides applied to each
    (:func:`slotv_jax.training.config.apply_overrides`; a bad one is an input error)."""
    if compute_dtype:
        train = {m: dataclasses.replace(c, compute_dtype=compute_dtype) for m, c in train.items()}
    try:
        return (
            {m: train_config.apply_overrides(c, sets) for m, c in train.items()} if sets else train
        )
    except ValueError as e:
        raise cli.InputError(f"--set: {e}") from None
