"""How hard are the labelling tasks? Statistics of the four labelers' labels per split.

For every labeler (:ref:`concepts-labelers`) and every dataset split (:ref:`concepts-datasets`) this
computes:

- the mean label entropy ``H(y) = −Σ_k y_k log y_k`` over real goals (nats), beside
  the entropy of a uniform distribution over the same goals (mean ``log n_goals``);
  their ratio is 0 for one-hot labels and 1 for uniform ones;
- the mean max-probability ``max_k y_k`` (beside the uniform ``1/n_goals``);
- target agreement: how often ``argmax y`` is the trajectory's true target goal
  (ties go to the lowest slot index, as in :ref:`concepts-metrics`), beside chance ``1/n_goals``;

and, per split, how often all four labelers' argmaxes agree and how often each
pair agrees. The report says whether the tasks are non-trivial: labels far from
one-hot, argmax not always the target, labelers disagreeing.

    python -m slotv_jax.data.report --data quick --out runs/labels

Writes ``OUT/labels.md`` (tables and a short reading) and ``OUT/labels.png``
(entropy ratio and target agreement per labeler × split, four-way agreement per
split, pairwise agreement heatmap), each atomically.
"""

from __future__ import annotations

import datetime
import itertools
import shlex
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from slotv_jax.core import cli, fileio
from slotv_jax.core.defaults import LABELER_NAMES, SPLITS
from slotv_jax.core.fileio import save_figure, write_text
from slotv_jax.data.stats import NEAR_TIE, collect
from slotv_jax.data.storage import Split, find_dataset, has_split, load_split

LABELERS = LABELER_NAMES  # dragan, nikolaidis, effdist, fastapp
TITLES = {
    "dragan": "Dragan",
    "nikolaidis": "Nikolaidis",
    "effdist": "EffDist",
    "fastapp": "FastApp",
}
TITLE = "# Label statistics: are the four labelling tasks non-trivial?"  # the report's first line
AT_CHANCE = 0.02  # target agreement within this of chance, in every split, counts as chance


# ---------------------------------------------------------------------- report


def _reading(stats: dict) -> str:
    """The 3–6 sentence interpretation, generated from the numbers themselves."""
    labelers, per = stats["labelers"], stats["splits"]

    def rng(key: str, names: Sequence[str] = labelers) -> tuple[float, float]:
        v = [per[s]["labelers"][n][key] for s in per for n in names]
        return min(v), max(v)

    def span(lo_hi: tuple[float, float], fmt: str = ".2f") -> str:
        lo, hi = lo_hi
        return f"{lo:{fmt}}" if f"{lo:{fmt}}" == f"{hi:{fmt}}" else f"{lo:{fmt}}–{hi:{fmt}}"

    def names(ns: Sequence[str]) -> str:
        t = [TITLES[n] for n in ns]
        return t[0] if len(t) == 1 else ", ".join(t[:-1]) + " and " + t[-1]

    out = []
    ratio = rng("entropy_ratio")
    by_ratio = sorted(labelers, key=lambda n: rng("entropy_ratio", [n])[0])
    if ratio[0] >= 0.8:
        head = "Labels are close to uniform, far from one-hot"
    elif ratio[1] >= 0.2:
        head = "Labels are far from one-hot"
    else:
        head = "Labels are close to one-hot"
    lift = [
        per[s]["labelers"][n]["max_prob"] - per[s]["labelers"][n]["uniform_max_prob"]
        for s in per
        for n in labelers
    ]
    out.append(
        f"{head}: per split, mean entropy is {span(ratio)} of the uniform entropy over the same "
        f"goals ({TITLES[by_ratio[0]]} lowest at {span(rng('entropy_ratio', by_ratio[:1]))}, "
        f"{TITLES[by_ratio[-1]]} highest at {span(rng('entropy_ratio', by_ratio[-1:]))}), and the "
        f"mean max-probability exceeds the uniform 1/n_goals by "
        f"{'only ' if ratio[0] >= 0.8 else ''}{span((min(lift), max(lift)))}."
    )
    excess = {
        n: [
            per[s]["labelers"][n]["target_agreement"] - per[s]["labelers"][n]["chance"] for s in per
        ]
        for n in labelers
    }
    at_chance = [n for n in labelers if max(abs(e) for e in excess[n]) <= AT_CHANCE]
    above = [n for n in labelers if n not in at_chance]
    agree = rng("target_agreement")
    txt = f"argmax(y) is the true target goal on at most {agree[1]:.1%} of a split's trajectories"
    if at_chance:
        txt += (
            f"; for {names(at_chance)} it is at chance level (within ±{AT_CHANCE:.2f} of mean "
            "1/n_goals in every split), so these labels carry almost no information about where "
            "the motion ends"
            + (
                " (likely because the paths pass random via points before the target, and "
                "the (1 − t) weight of concepts: Dragan discounts the final approach)"
                if set(at_chance) <= {"dragan", "nikolaidis"}
                else ""
            )
        )
    if above:
        ex = [e for n in above for e in excess[n]]
        txt += (
            f"; {names(above)} beat chance by {min(ex):+.2f} to {max(ex):+.2f}"
            if at_chance
            else f"; every labeler beats chance, by {min(ex):+.2f} to {max(ex):+.2f}"
        )
    out.append(txt[0].upper() + txt[1:] + ".")
    four = [per[s]["all_agree"] for s in per]
    pm = stats["pairwise_mean"]
    pairs = sorted((pm[a][b], a, b) for a, b in itertools.combinations(labelers, 2))
    if len(labelers) > 1:
        out.append(
            f"All {len(labelers)} labelers pick the same goal on only "
            f"{span((min(four), max(four)), '.1%')} of a split's trajectories; the closest pair is "
            f"{TITLES[pairs[-1][1]]}/{TITLES[pairs[-1][2]]} ({pairs[-1][0]:.1%} agreement, mean "
            f"over splits) and the most different {TITLES[pairs[0][1]]}/{TITLES[pairs[0][2]]} "
            f"({pairs[0][0]:.1%})."
        )
    out.append(
        f"Argmax decisions are often close calls: the mean gap between the two largest "
        f"probabilities is {span(rng('margin'), '.3f')}, and {span(rng('near_tie'), '.0%')} of "
        f"a split's trajectories have a gap below {NEAR_TIE}, which makes argmax accuracy "
        "sensitive to small errors in the predicted distribution."
    )
    trivial = agree[1] >= 0.95 or (len(labelers) > 1 and max(four) >= 0.95) or ratio[1] < 0.05
    out.append(
        "Some of these tasks are close to trivial (see the tables); read accuracies on them "
        "with that in mind."
        if trivial
        else "The four tasks are therefore non-trivial and distinct: predicting the target, "
        "copying another labeler, or a one-hot rule would score poorly on each of them."
    )
    return " ".join(out)


def _fmt_counts(counts: Mapping[int, int]) -> str:
    return ", ".join(f"{k}: {v}" for k, v in sorted(counts.items()))


def render_markdown(
    stats: dict, *, command: str, digest: str, date: str, environment: Mapping, figure: str
) -> str:
    """The Markdown report: provenance, tables, the figure link and the reading."""
    labelers, per = stats["labelers"], stats["splits"]
    env = ", ".join(
        f"{k} {environment[k]}"
        for k in ("slotv_jax", "python", "jax", "flax", "optax", "mujoco", "numpy")
        if k in environment
    )
    devices = ", ".join(environment.get("devices", [])) or "unknown"
    L = [TITLE, ""]
    L += [
        f"- Command: `{command}`",
        f"- Dataset config digest: `{digest}`",
        f"- Date: {date}",
        f"- Versions (from the dataset's sidecar): {env}; devices: {devices}",
        "- Entropy in nats over each trajectory's real goals; *uniform* = mean log n_goals. "
        "Ratio = mean entropy / mean uniform entropy (0: one-hot, 1: uniform). "
        "*Top-2 gap* = mean difference between the two largest probabilities. "
        "*Target* = fraction with argmax(y) = the planner's target goal "
        "(ties to the lowest slot, concepts: metrics); *chance* = mean 1/n_goals.",
        "",
        "## Splits",
        "",
        "| split | trajectories | goal counts (count: trajectories) |",
        "|---|---:|---|",
    ]
    L += [f"| {s} | {per[s]['n']:,} | {_fmt_counts(per[s]['goal_counts'])} |" for s in per]
    L += ["", f"![label statistics]({figure})", "", "## Reading", "", _reading(stats), ""]
    L += ["## Per labeler and split", ""]
    L += [
        "| labeler | split | entropy | uniform | ratio | max prob (uniform) "
        f"| top-2 gap | gap < {NEAR_TIE} | target | chance |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for n in labelers:
        for s in per:
            r = per[s]["labelers"][n]
            L.append(
                f"| {TITLES[n]} | {s} | {r['entropy']:.3f} | {r['uniform_entropy']:.3f} "
                f"| {r['entropy_ratio']:.2f} | {r['max_prob']:.3f} ({r['uniform_max_prob']:.3f}) "
                f"| {r['margin']:.3f} | {r['near_tie']:.3f} "
                f"| {r['target_agreement']:.3f} | {r['chance']:.3f} |"
            )
    L += ["", "## Agreement between labelers (argmax), per split", ""]
    head = " | ".join(f"{TITLES[a]}/{TITLES[b]}" for a, b in itertools.combinations(labelers, 2))
    L += [
        f"| split | all {len(labelers)} | {head} |",
        "|---|---:|" + "---:|" * len(list(itertools.combinations(labelers, 2))),
    ]
    for s in per:
        pw = per[s]["pairwise"]
        cells = " | ".join(f"{pw[a][b]:.3f}" for a, b in itertools.combinations(labelers, 2))
        L.append(f"| {s} | {per[s]['all_agree']:.3f} | {cells} |")
    L += ["", "Pairwise agreement averaged over the splits (unweighted mean of split rates):", ""]
    L += [
        "| | " + " | ".join(TITLES[b] for b in labelers) + " |",
        "|---|" + "---:|" * len(labelers),
    ]
    pm = stats["pairwise_mean"]
    L += [
        f"| {TITLES[a]} | " + " | ".join(f"{pm[a][b]:.3f}" for b in labelers) + " |"
        for a in labelers
    ]
    worst_sum = max(per[s]["labelers"][n]["max_sum_error"] for s in per for n in labelers)
    worst_pad = max(per[s]["labelers"][n]["max_padded"] for s in per for n in labelers)
    lowest = min(per[s]["labelers"][n]["min_value"] for s in per for n in labelers)
    L += [
        "",
        "## Label sanity",
        "",
        f"Over all splits and labelers: worst |Σ y − 1| over real goals {worst_sum:.2e}, "
        f"largest |y| on a padded slot {worst_pad:.2e}, smallest y on a real goal {lowest:.2e}.",
        "",
    ]
    return "\n".join(L)


def plot(stats: dict, path: Path) -> None:
    """Grouped bars (entropy ratio, target agreement) per labeler × split, four-way
    agreement per split, and the split-averaged pairwise agreement heatmap."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    labelers, per = stats["labelers"], stats["splits"]
    splits = list(per)
    x = np.arange(len(splits))
    w = 0.8 / len(labelers)
    colors = dict(zip(LABELERS, ("tab:blue", "tab:orange", "tab:green", "tab:red"), strict=True))
    fig = plt.figure(figsize=(13, 7.2), dpi=130)
    gs = fig.add_gridspec(2, 2, width_ratios=(2.6, 1), hspace=0.55, wspace=0.25)
    short = [s.replace("_", "\n") for s in splits]
    for row, (key, ylabel, title) in enumerate(
        (
            ("entropy_ratio", "entropy / uniform entropy", "Label entropy relative to uniform"),
            ("target_agreement", "P(argmax y = target)", "Argmax equals the true target goal"),
        )
    ):
        ax = fig.add_subplot(gs[row, 0])
        for j, n in enumerate(labelers):
            v = [per[s]["labelers"][n][key] for s in splits]
            ax.bar(x + (j - (len(labelers) - 1) / 2) * w, v, w, label=TITLES[n], color=colors[n])
        if key == "target_agreement":
            ch = [per[s]["labelers"][labelers[0]]["chance"] for s in splits]
            ax.hlines(ch, x - 0.45, x + 0.45, colors="k", linestyles="--", linewidth=1.2,
                      zorder=3, label="chance (1/n goals)")  # fmt: skip
        ax.set_xticks(x, short, fontsize=8)
        ax.set_ylim(0, 1.18)
        ax.set_yticks(np.linspace(0, 1, 6))
        ax.set_ylabel(ylabel)
        ax.set_title(title, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
        ax.set_axisbelow(True)
        ax.legend(ncol=len(labelers) + 1, fontsize=8, loc="upper center", frameon=False)
    ax = fig.add_subplot(gs[0, 1])
    four = [per[s]["all_agree"] for s in splits]
    ax.barh(x, four, color="tab:gray")
    for xi, v in zip(x, four, strict=True):
        ax.text(v + 0.01, xi, f"{v:.2f}", va="center", fontsize=8)
    ax.set_yticks(x, splits, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel("fraction of trajectories")
    ax.set_title(f"All {len(labelers)} labelers' argmaxes agree", fontsize=10)
    ax.grid(axis="x", alpha=0.3)
    ax = fig.add_subplot(gs[1, 1])
    pm = np.array([[stats["pairwise_mean"][a][b] for b in labelers] for a in labelers])
    im = ax.imshow(pm, vmin=0, vmax=1, cmap="viridis")
    names = [TITLES[n] for n in labelers]
    ax.set_xticks(range(len(labelers)), names, fontsize=8, rotation=30)
    ax.set_yticks(range(len(labelers)), names, fontsize=8)
    for i, j in itertools.product(range(len(labelers)), repeat=2):
        ax.text(j, i, f"{pm[i, j]:.2f}", ha="center", va="center", fontsize=8,
                color="k" if pm[i, j] > 0.6 else "w")  # fmt: skip
    ax.set_title("Pairwise argmax agreement\n(mean over splits)", fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    fig.suptitle("Label statistics per labeler and split", fontsize=12)
    try:
        save_figure(fig, path, bbox_inches="tight")
    finally:
        plt.close(fig)


def write_report(
    splits: Mapping[str, Split],
    out: str | Path,
    *,
    command: str,
    date: str | None = None,
    labelers: Sequence[str] = LABELERS,
) -> dict:
    """Compute the statistics of ``splits`` and write ``OUT/labels.md`` and ``OUT/labels.png``.

    The splits must come from one dataset (one ``config_digest``). Returns the statistics.
    """
    if not splits:
        raise ValueError("splits: expected at least one split")
    digests = {s.meta.get("config_digest", "unknown") for s in splits.values()}
    if len(digests) != 1:
        raise ValueError(f"splits come from different dataset configs: {sorted(digests)}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stats = collect(splits, labelers)
    first = next(iter(splits.values()))
    plot(stats, out / "labels.png")
    md = render_markdown(
        stats,
        command=command,
        digest=digests.pop(),
        date=date or datetime.date.today().isoformat(),
        environment=first.meta.get("environment", {}),
        figure="labels.png",
    )
    write_text(out / "labels.md", md)
    return stats


def is_report(path: Path) -> bool:
    """Whether ``path`` holds a label report this module wrote (its first line)."""
    try:
        with open(path, encoding="utf-8") as f:
            return f.readline().rstrip("\n") == TITLE
    except (OSError, UnicodeDecodeError):
        return False


@cli.command
def main(argv: Sequence[str] | None = None) -> int:
    """Command line: load the splits of ``--data`` and write the report to ``--out``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    p = cli.ArgumentParser(
        prog="python -m slotv_jax.data.report",
        description="Label entropy, target agreement and labeler agreement per split.",
    )
    p.add_argument(
        "--data", required=True, help="dataset folder, or a preset name (quick: the main job's)"
    )
    p.add_argument("--out", type=Path, default=Path("runs/labels"), help="default: runs/labels")
    p.add_argument(
        "--splits", nargs="+", choices=SPLITS, help="default: every split the dataset holds"
    )
    p.add_argument("--date", help="date to print in the report (default: today)")
    args = p.parse_args(argv)
    # a report of ours is regenerated; a labels.md or .png of anybody else's is refused
    ours = {"labels.md": is_report, "labels.png": lambda p: is_report(p.with_name("labels.md"))}
    fileio.check_output_files(args.out, ["labels.md", "labels.png"], ours=ours)
    folder = find_dataset(args.data)
    names = args.splits or [n for n in SPLITS if has_split(folder, n)]
    if not names:
        raise cli.InputError(f"--data {args.data}: holds no dataset split")
    splits = {name: load_split(folder, name) for name in names}
    command = shlex.join(["python", "-m", "slotv_jax.data.report", *argv])
    stats = write_report(splits, args.out, command=command, date=args.date)
    for name, s in stats["splits"].items():
        cells = "  ".join(
            f"{n}: H/Hu {r['entropy_ratio']:.2f} tgt {r['target_agreement']:.3f}"
            for n, r in s["labelers"].items()
        )
        print(f"{name:>16s}  all-agree {s['all_agree']:.3f}  {cells}")
    print(f"wrote {args.out}/labels.md and {args.out}/labels.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
