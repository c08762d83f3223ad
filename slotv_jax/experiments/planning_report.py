"""The report and figures of the planning experiment, rendered from its output alone.

:func:`report` turns a ``results.json`` document of :mod:`slotv_jax.experiments.planning`
into Markdown; :func:`render` draws ``scenes.png`` and ``bars.png`` from ``results.json``
and ``plans.npz`` (that module's docstring describes both). No number is typed here:
every one comes from those two files, so a recorded run can be re-rendered::

    python -m slotv_jax.experiments.planning_report runs/planning_quick --doc report.md
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

from slotv_jax.core import cli, fileio
from slotv_jax.core.fileio import write_text
from slotv_jax.robot.kinematics import home_tcp
from slotv_jax.runs import figures as figure_style
from slotv_jax.world.scene import camera, project

TITLES = {"straight": "straight line", "dragan": "Dragan (oracle)",
          "nikolaidis": "Nikolaidis (oracle)", "slotv": "SLOT-V", "trex": "T-REX",
          "slotv_plus": "SLOT-V+ (start term, time weights)",
          "trex_plus": "T-REX+ (start term, time weights)",
          "archetype": "SLOT-V loss, archetype"}  # fmt: skip
_COLOURS = {"straight": "0.4", "oracle": "C3", "slotv": "C0", "trex": "C2",
            "slotv_plus": "C9", "trex_plus": "C8", "archetype": "C1"}  # fmt: skip
# Dashes per planner in the scenes, so that plans on top of each other stay apart; the
# oracle is drawn wide and pale beneath the rest (a learned plan often equals it).
_DASHES = {"straight": (0, (5, 2)), "oracle": "-", "slotv": "-", "trex": (0, (3, 1.5)),
           "slotv_plus": (0, (1, 1)), "trex_plus": (0, (6, 1.5, 1, 1.5)),
           "archetype": (0, (2, 2))}  # fmt: skip
FIGURES = ("scenes.png", "bars.png")


def families(doc: dict) -> list[str]:
    """The labeler families of a run, in its order (the keys of ``config.scoring_betas``)."""
    return list(doc["config"]["scoring_betas"])


def all_rows(doc: dict) -> list[dict]:
    """Every planner row of a results document: SPEC's, the ``+`` and the archetype ones."""
    return doc["planners"] + doc.get("plus_planners", []) + doc.get("archetype_planners", [])


def _title(row: dict) -> str:
    if row["observer"] == "archetype":
        return f"SLOT-V loss, {row['model']} archetype"
    return TITLES[row["observer"]]


def render(out: Path, n_examples: int = 3) -> None:
    """``out/scenes.png`` (top view for the first family, the observer camera's view for
    the others) and ``out/bars.png`` (true legibility per planner ± SD), from
    ``out/plans.npz`` and ``out/results.json``."""
    plt = figure_style.pyplot()
    with np.load(out / "plans.npz", allow_pickle=False) as f:
        pl = {k: f[k] for k in f.files}
    doc = json.loads((out / "results.json").read_text())
    fams = families(doc)
    figure_style.save(scenes_figure(pl, doc, n_examples), out / "scenes.png", dpi=90)

    fig, axes = plt.subplots(1, len(fams), figsize=(10, 3.8), sharey=True, squeeze=False)
    for ax, family in zip(axes[0], fams, strict=True):
        rows = [r for r in all_rows(doc) if r["labeler"] == family]
        labels = [_title(r).replace(" loss, ", " loss,\n") for r in rows]
        colours = [_COLOURS["oracle" if r["observer"] == family else r["observer"]] for r in rows]
        ax.bar(labels, [r["mean_y_target"] for r in rows], yerr=[r["sd_y_target"] for r in rows],
               color=colours, capsize=4)  # fmt: skip
        beta = doc["config"]["scoring_betas"][family]
        ax.set(title=f"true {family} legibility, β = {beta:g} (n = {rows[0]['n']})",
               ylabel="mean y_target ± SD")  # fmt: skip
        ax.tick_params(axis="x", rotation=25)
        plt.setp(ax.get_xticklabels(), ha="right", rotation_mode="anchor")
    fig.tight_layout()
    figure_style.save(fig, out / "bars.png", dpi=100)


def scenes_figure(pl: dict, doc: dict, n_examples: int = 3):
    """The figure of ``scenes.png`` from the plans ``pl`` (``plans.npz``'s arrays) and the
    results ``doc``: a row per example problem, the top view for the first family and the
    observer camera's view for the others; each planner its own colour and dashes, the
    oracle wide and pale beneath the rest, the legends below the axes."""
    plt = figure_style.pyplot()
    fams = families(doc)
    cam = camera(doc["config"]["data"]["labels"]["camera"])
    cam64 = jax.tree.map(lambda a: np.asarray(a, np.float64), cam)
    names = [str(n) for n in pl["names"]]
    per_family = len(pl["target"]) // len(fams)
    shown = np.linspace(0, per_family - 1, min(n_examples, per_family)).round().astype(int)
    fig, axes = plt.subplots(len(shown), len(fams), figsize=(11, 6.0 * len(shown)), squeeze=False)
    home = np.asarray(home_tcp(), np.float64)[None]
    for row, j in enumerate(shown):
        for col, family in enumerate(fams):
            ax, p = axes[row, col], col * per_family + j
            view = (lambda a: a[..., :2]) if col == 0 else (lambda a: project(a, cam64)[0])
            g, m, t = pl["goals"][p].astype(np.float64), pl["goal_mask"][p], int(pl["target"][p])
            for k, name in enumerate(names):
                if np.isnan(pl["xyz"][k, p]).any():
                    continue
                oracle = name == "oracle"
                ax.plot(*view(pl["xyz"][k, p].astype(np.float64)).T, color=_COLOURS[name],
                        lw=5.0 if oracle else 1.6, alpha=0.4 if oracle else 1.0,
                        ls=_DASHES[name], zorder=1 if oracle else 2,
                        label=f"{TITLES[family if name == 'oracle' else name]}: "
                        f"y = {pl['y'][k, p, t]:.2f}")  # fmt: skip
            gp, y = view(g[m]), pl["y"][names.index("oracle"), p][m]
            sc = ax.scatter(gp[:, 0], gp[:, 1], c=y, cmap="viridis", vmin=0, vmax=1, s=120,
                            marker="s", edgecolors="k", zorder=3)  # fmt: skip
            k = int(np.flatnonzero(m).tolist().index(t))
            ax.scatter(gp[k, 0], gp[k, 1], marker="*", s=260, c="w", edgecolors="k", zorder=4)
            ax.plot(*view(home)[0], "ko", ms=5)
            if col == 0:
                title = f"{pl['split'][p]} scene {int(pl['scene'][p])}: top view, {family}"
                ax.set(xlabel="x (m)", ylabel="y (m)", aspect="equal", title=title)
            else:
                ax.set(xlabel="u (image plane)", ylabel="v", aspect="equal",
                       title=f"observer camera view, {family}")  # fmt: skip
            # below the axes: inside, it covered ticks and goals
            ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
            fig.colorbar(sc, ax=ax, shrink=0.7, label="true y of the oracle plan")
    fig.tight_layout()
    return fig


def report(doc: dict, figures: str = "") -> str:
    """The Markdown report of a run (``figures``: path prefix of the two PNGs)."""
    env, t, cfg = doc["environment"], doc["timing"], doc["config"]
    fams, splits = families(doc), list(doc["n_problems_by_split"])
    betas = ", ".join(f"{f} β = {b:g}" for f, b in cfg["scoring_betas"].items())
    lines = [
        f"# Legible planning with learned observers ({doc['preset']} preset)",
        "",
        "Every plan is scored by the TRUE hand-crafted labeler of its family, at the "
        f"temperature of the dataset's labels the learned observers were trained on ({betas}; "
        "`config.scoring_betas`); the oracle plans with the same labeler. `y_target` is "
        "the labeler's probability of the goal the robot moves to; argmax: the target is the "
        "labeler's most likely goal; length ratio: path length over the straight line's; "
        "lowered: fraction of problems where the plan's true y_target is below the straight "
        "line's; gain kept: (mean y − straight) / (oracle mean y − straight).",
        "",
        f"{doc['n_problems']} problems: every (scene, goal) pair of "
        + ", ".join(f"{n} in {s}" for s, n in doc["n_problems_by_split"].items())
        + f" ({cfg['n_scenes']} held-out scenes per split), start TCP(q_home). Planner: "
        f"{cfg['planner']['iters']} covariant steps, trust-region budget "
        f"{cfg['planner']['budget']} m² on C = ½∫‖ξ'‖²dt, clearance "
        f"{cfg['planner']['clearance']} m.",
        "",
        "| true labeler | observer planned with | mean y_target ± SD | argmax rate | length ratio "
        "| feasible | lowered | raised | gain kept | observer's own P(target): straight → plan |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    every = all_rows(doc)
    for r in sorted(every, key=lambda r: fams.index(r["labeler"])):
        kept = r.get("oracle_gain_kept")
        own = (
            f"{r['observer_p_target_straight']:.3f} → {r['observer_p_target_plan']:.3f}"
            if "observer_p_target_plan" in r
            else "—"
        )
        lines.append(
            f"| {r['labeler']} | {_title(r)} | {r['mean_y_target']:.3f} ± "
            f"{r['sd_y_target']:.3f} | {r['argmax_rate']:.3f} | {r['length_ratio']:.3f} | "
            f"{r['feasible_rate']:.3f} | {r['lowered_rate']:.3f} | {r['raised_rate']:.3f} | "
            f"{'—' if kept is None else f'{kept:.0%}'} | {own} |"
        )
    plan_s = sum(t["plan_s"].values())

    def worst(field, pick):
        return pick(r[field] for r in every if field in r)

    lines += [
        "",
        f"![true legibility per planner]({figures}bars.png)",
        "",
        f"![example scenes]({figures}scenes.png)",
        "",
        "Constraints on every returned plan (worst case over problems and observers): "
        f"target residual {worst('max_target_residual_m', max) * 1e3:.2f} mm; joint-limit "
        f"margin {worst('min_joint_margin_rad', min):.4f} rad; TCP height above the "
        f"clearance {worst('min_table_clearance_m', min) * 1e3:.1f} mm; trust region "
        f"C − κ {worst('max_cost_over_limit_m2', max):.2e} m² (≤ 0 holds).",
        "",
        f"Timing: total {t['total_s']:.0f} s = data {t['data_s']:.0f} s, observer training "
        f"{t['train_s']:.0f} s, straight lines {t['straight_line_s']:.0f} s (compilation "
        f"included), planning {plan_s:.0f} s ("
        + ", ".join(f"{k} {v:.1f} s" for k, v in t["plan_s"].items())
        + "; the first includes the one compilation).",
        "",
        f"jax {env.get('jax')}, flax {env.get('flax')}, mujoco {env.get('mujoco')}, "
        f"devices {env.get('devices')}.",
        "",
        "Learned observers: accuracy (concepts: metrics) on the labels of their family on the "
        "held-out splits' trajectories; the learned time-weighting exponent α of SLOT-V+ and "
        "T-REX+.",
        "",
        "| observer | " + " | ".join(f"accuracy {s}" for s in splits) + " | α | source |",
        "|---|" + "---|" * len(splits) + "---|---|",
    ]
    for k, v in doc["observers"].items():
        acc = v.get("accuracy", {})
        alpha = v.get("alpha")
        lines.append(
            f"| {k} | "
            + " | ".join(f"{acc[s]:.3f}" if s in acc else "—" for s in splits)
            + f" | {'—' if alpha is None else f'{alpha:.3f}'} | "
            + ("trained by this run" if v["trained"] else v["checkpoint"])
            + " |"
        )
    lines.append("")
    return "\n".join(lines)


def write_doc(out: Path, doc: dict, path: Path) -> None:
    """Write the report of the run in ``out`` to ``path``, its figures beside it
    (``<stem>_scenes.png``, ``<stem>_bars.png``)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    for fig in FIGURES:
        shutil.copyfile(out / fig, path.parent / f"{path.stem}_{fig}")
    write_text(path, report(doc, figures=f"{path.stem}_"))


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.experiments.planning_report",
        description="Re-render the figures and the report of a planning run from its "
        "results.json and plans.npz.",
    )
    p.add_argument("run", type=Path, help="output directory of a planning run")
    p.add_argument("--n-examples", type=int, default=3, help="example problems in scenes.png")
    p.add_argument("--doc", type=Path, help="also write the report here, figures beside it")
    args = p.parse_args(argv)
    missing = [f for f in ("results.json", "plans.npz") if not (args.run / f).is_file()]
    if missing:
        raise cli.InputError(f"run: {args.run} holds no {' or '.join(missing)}")
    if args.n_examples < 1:
        raise cli.InputError(f"--n-examples: expected an integer >= 1, got {args.n_examples}")
    if args.doc is not None:
        names = [args.doc.name, *(f"{args.doc.stem}_{f}" for f in FIGURES)]
        fileio.check_output_files(args.doc.parent, names, what="--doc")
    try:
        doc = json.loads((args.run / "results.json").read_text())
        doc["config"]["scoring_betas"]
    except (ValueError, KeyError) as e:
        raise cli.InputError(
            f"run: {args.run / 'results.json'}: not a planning results "
            f"document with config.scoring_betas ({e!r})"
        ) from None
    render(args.run, args.n_examples)
    write_text(args.run / "planning.md", report(doc))
    if args.doc is not None:
        write_doc(args.run, doc, args.doc)
    print(f"wrote {', '.join(FIGURES)} and planning.md in {args.run}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
