"""The command line: ``python -m slotv_jax.experiments.study_size``."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import slotv_jax
from slotv_jax import data as data_lib
from slotv_jax.core import cli
from slotv_jax.core.fileio import write_text
from slotv_jax.experiments.study_size import PRESETS, is_results, p_name, run, stem_of
from slotv_jax.experiments.study_size.report import plot, report
from slotv_jax.runs import command, record

PROG = "python -m slotv_jax.experiments.study_size"


def _parse_args(argv):
    ap = cli.ArgumentParser(
        prog=PROG,
        description="Simulated studies: trajectories × participants for a learned observer.",
    )
    ap.add_argument("--preset", default="quick", choices=tuple(PRESETS))
    ap.add_argument(
        "--out",
        default=str(command.DEFAULT_OUT),
        help=f"output folder (default: {command.DEFAULT_OUT})",
    )
    ap.add_argument("--cache", default="data", help="dataset cache folder")
    ap.add_argument("--n-grid", default=None, help="comma-separated N, e.g. 100,1000")
    ap.add_argument("--participants", default=None, help="comma-separated P; 0 means ∞")
    ap.add_argument("--trials", type=int, default=None)
    ap.add_argument("--taus", default=None, help="stop times, e.g. 0.25,0.5,0.75,1")
    ap.add_argument("--lapse", type=float, default=None)
    ap.add_argument("--labeler", default=None, choices=data_lib.LABELER_NAMES)
    ap.add_argument("--updates", type=int, default=None, help="updates per cell (both methods)")
    ap.add_argument(
        "--no-budget-check", action="store_true", help="skip the accuracy-against-updates check"
    )
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="TrainConfig override (both methods, after the preset's), e.g. "
        "--set compute_dtype=bfloat16",
    )
    ap.add_argument(
        "--report",
        action="store_true",
        help="only render OUT/STEM.md and .png again from the results document OUT/STEM.json",
    )
    ap.add_argument("--no-progress", action="store_true")
    return ap.parse_args(argv)


def report_again(out: Path, preset: str) -> int:
    """Render ``OUT/STEM.md`` and ``.png`` again from ``OUT/STEM.json`` alone (the report's
    date is the run's, from the document)."""
    stem = stem_of(preset)

    def render(doc: dict, cmd: str) -> None:
        plot(doc, out / f"{stem}.png")
        write_text(out / f"{stem}.md", report(doc, stem, cmd))

    return command.render_again(
        out, stem, is_results, render, f"{PROG} --preset {preset}", results=f"{stem}.json"
    )


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    args = _parse_args(argv)
    if args.report:
        return report_again(Path(args.out), args.preset)
    print(slotv_jax.XLA_CONFIG.summary(), flush=True)
    kw: dict = {}
    if args.n_grid:
        kw["n_grid"] = tuple(int(v) for v in args.n_grid.split(","))
    if args.participants:
        kw["participants"] = tuple(int(v) for v in args.participants.split(","))
    if args.taus:
        kw["taus"] = tuple(float(v) for v in args.taus.split(","))
    for name in ("trials", "lapse", "labeler"):
        if getattr(args, name) is not None:
            kw[name] = getattr(args, name)
    if args.updates is not None:
        kw["updates"] = args.updates
    if args.no_budget_check:
        kw["budget_check"] = False
    cfg = PRESETS[args.preset](**kw)
    if args.set:  # after the preset's own overrides
        cfg = dataclasses.replace(cfg, overrides=cfg.overrides + tuple(args.set))
    out, stem = Path(args.out), stem_of(cfg.preset)
    doc = run(cfg, out, cache=Path(args.cache), progress=not args.no_progress)
    plot(doc, out / f"{stem}.png")
    write_text(out / f"{stem}.md", report(doc, stem, record.command_line(PROG, argv).strip()))
    for r in doc["needed"]:
        got = "not reached" if r["n"] is None else f"N ≈ {r['n']:,.0f}"
        print(f"{r['method']} P={p_name(r['participants'])}: {got} (best {r['best']:.3f})")
    print(f"wrote {out / (stem + '.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
