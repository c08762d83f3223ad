"""The planning experiment scores its plans at the dataset's temperatures, and writes its
example plans in the documented plans.npz format."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import jax
import numpy as np
import pytest

from slotv_jax import data
from slotv_jax.core.defaults import BETAS_V1, DEFAULT_BETAS
from slotv_jax.experiments import planning as exp
from slotv_jax.observers import labelers
from slotv_jax.planning import evaluation
from slotv_jax.planning.plans import load_plans, save_plans
from slotv_jax.world import scene


def _case():
    goals = np.zeros((8, 3), np.float32)
    goals[:3] = [[0.45, 0.3, 0.025], [0.55, 0.0, 0.025], [0.45, -0.3, 0.025]]
    mask = np.arange(8) < 3
    start = np.array([0.3, 0.0, 0.45], np.float32)
    xyz = np.linspace(start, goals[0] + [0.0, -0.1, 0.1], 30).astype(np.float32)
    return xyz, goals, mask


@pytest.mark.parametrize("labels", [data.LabelConfig(), data.LABELS_V1])
def test_oracles_and_scoring_use_the_datasets_temperatures(labels):
    cfg = exp.tiny()
    cfg = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, labels=labels))
    betas = cfg.scoring_betas()
    assert betas == {f: getattr(labels, f"beta_{f}") for f in exp.FAMILIES}
    assert cfg.to_json()["scoring_betas"] == betas  # config.scoring_betas of results.json
    xyz, goals, mask = _case()
    cam = scene.camera(labels.camera)
    oracles = exp.oracles(cfg)
    for f in exp.FAMILIES:
        kw = {"camera": cam} if f == "nikolaidis" else {}
        want = np.asarray(labelers.LABELERS[f](xyz, goals, mask, beta=betas[f], **kw))
        other = np.asarray(labelers.LABELERS[f](xyz, goals, mask, beta=2 * betas[f], **kw))
        assert np.abs(want - other).max() > 1e-3  # the temperature matters here
        got = np.asarray(jax.nn.softmax(oracles[f](xyz, goals, mask)))
        np.testing.assert_allclose(got, want, rtol=0, atol=2e-6, err_msg=f)
        y = evaluation.true_labels(f, xyz[None], goals[None], mask[None], beta=betas[f])
        np.testing.assert_allclose(y[0], want, rtol=0, atol=2e-6, err_msg=f)


def test_the_presets_score_at_the_default_temperatures():
    for preset in exp.PRESETS.values():
        assert preset().scoring_betas() == {f: DEFAULT_BETAS[f] for f in exp.FAMILIES}
    assert {f: DEFAULT_BETAS[f] for f in exp.FAMILIES} != {f: BETAS_V1[f] for f in exp.FAMILIES}


class _Plans:
    """A stand-in for a batch of :class:`planning.PlanResult`: q and xyz only."""

    def __init__(self, seed: int, n: int, t: int):
        rng = np.random.default_rng(seed)
        self.q = rng.normal(size=(n, t, 7)).astype(np.float32)
        self.xyz = rng.normal(size=(n, t, 3)).astype(np.float32)


def test_saved_plans_format(tmp_path):
    cfg = dataclasses.replace(exp.tiny(), archetype={"dragan": exp.tiny().archetype["dragan"]})
    rng = np.random.default_rng(0)
    scenes = {}
    for s in exp.SPLITS:
        goals = rng.uniform(0.2, 0.6, (5, 8, 3)).astype(np.float32)
        mask = np.arange(8)[None] < rng.integers(2, 6, 5)[:, None]
        scenes[s] = (goals, mask)
    problems = exp.make_problems(scenes)
    n, t = len(problems["target"]), 12
    straight = _Plans(0, n, t)
    plans, labels = {}, {}
    for i, f in enumerate(exp.FAMILIES):
        labels[f, "straight"] = rng.random((n, 8), dtype=np.float32)
        for name in (f, *cfg.methods(f)):
            plans[exp.observer_key(name, f)] = _Plans(10 * i + len(plans), n, t)
            labels[f, name] = rng.random((n, 8), dtype=np.float32)
    saved = exp.saved_plans(cfg, problems, straight, plans, labels)
    path = tmp_path / "plans.npz"
    save_plans(path, saved)  # checked on the way out and in
    pl = load_plans(path)
    names = [str(x) for x in pl["names"]]
    assert names == ["straight", "oracle", "slotv", "trex", "slotv_plus", "trex_plus", "archetype"]
    idx = exp.example_indices(problems, exp.N_SAVED)
    P, K = 2 * len(idx), len(names)
    assert 0 < len(idx) <= exp.N_SAVED
    assert pl["goals"].shape == (P, 8, 3) and pl["goals"].dtype == np.float32
    assert pl["goal_mask"].shape == (P, 8) and pl["goal_mask"].dtype == bool
    assert pl["target"].shape == (P,) and pl["target"].dtype == np.int32
    assert pl["q"].shape == (K, P, t, 7) and pl["q"].dtype == np.float32
    assert pl["xyz"].shape == (K, P, t, 3) and pl["y"].shape == (K, P, 8)
    for k in ("family", "names", "split"):
        assert pl[k].dtype.kind == "U"
    assert pl["family"].tolist() == ["dragan"] * len(idx) + ["nikolaidis"] * len(idx)
    assert pl["beta"].tolist() == [DEFAULT_BETAS[str(f)] for f in pl["family"]]
    for p in range(P):
        i, f = int(pl["problem"][p]), str(pl["family"][p])
        np.testing.assert_array_equal(pl["goals"][p], problems["goals"][i])
        assert pl["target"][p] == problems["target"][i]
        assert pl["split"][p] == exp.SPLITS[problems["split"][i]]
        for k, name in enumerate(names):
            key = {"straight": "straight", "oracle": f}.get(name, name)
            if name == "archetype" and f == "nikolaidis":  # not in this run: NaN
                assert np.isnan(pl["xyz"][k, p]).all() and np.isnan(pl["y"][k, p]).all()
                continue
            res = straight if key == "straight" else plans[exp.observer_key(key, f)]
            np.testing.assert_array_equal(pl["q"][k, p], res.q[i])
            np.testing.assert_array_equal(pl["xyz"][k, p], res.xyz[i])
            np.testing.assert_array_equal(pl["y"][k, p], labels[f, key][i])


@pytest.mark.parametrize("stem", ["planning", "planning_paper"])
def test_records_are_rendered_from_their_results(stem):
    """The recorded reports hold the report rendered from the recorded results
    (numbers come from the results document only), scored at the datasets' temperatures;
    their example plans load without pickle."""
    from pathlib import Path

    from slotv_jax.experiments import planning_report

    folder = Path(__file__).resolve().parent.parent / "experiments"
    doc = json.loads((folder / f"{stem}_results.json").read_text())
    betas = doc["config"]["scoring_betas"]
    assert betas == {f: doc["config"]["data"]["labels"][f"beta_{f}"] for f in exp.FAMILIES}
    lines = iter((folder / f"{stem}.md").read_text().splitlines())
    for want in planning_report.report(doc, figures=f"{stem}_").splitlines():
        # every rendered line, in order (other figures may stand between them)
        assert any(line == want for line in lines), want
    f = load_plans(folder / f"{stem}_plans.npz")  # the plans file's format, without pickle
    assert set(f["family"].tolist()) == set(exp.FAMILIES)
    np.testing.assert_array_equal(f["beta"], [betas[str(x)] for x in f["family"]])


def _good_plans(P: int = 2, K: int = 2, T: int = 6) -> dict[str, np.ndarray]:
    """A valid plans file: P problems of 2 and 3 goals, K planners, T points."""
    goals = np.zeros((P, 8, 3), np.float32)
    goals[:, :3] = [[0.45, 0.3, 0.025], [0.55, 0.0, 0.025], [0.45, -0.3, 0.025]]
    return {"goals": goals, "goal_mask": np.arange(8) < np.arange(2, 2 + P)[:, None],
            "target": np.arange(1, 1 + P, dtype=np.int32),
            "names": np.array(["straight", "slotv"][:K]), "q": np.zeros((K, P, T, 7), np.float32),
            "xyz": np.zeros((K, P, T, 3), np.float32)}  # fmt: skip


def test_plans_file_checked_and_every_reader_says_what_is_wrong_in_one_line(tmp_path, capsys):
    """A plans file with a wrong shape or target is refused on write (nothing written) and
    on read, by the render command and by the stimuli command, each naming the array."""
    P, K, T = 2, 2, 6
    good = _good_plans(P, K, T)
    bad = {
        "q": ({"q": np.zeros((K, P, T, 3), np.float32)}, r"q: expected \(K=2, P, T, 7\)"),
        "xyz": ({"xyz": np.zeros((K, P, T + 1, 3))}, r"xyz: expected \(2, 2, 6, 3\)"),
        "target": ({"target": np.array([1, 2]) + 1}, "target: expected the index of a real goal"),
        "names": ({"names": np.array([1, 2])}, r"names: expected \(K,\) strings"),
        "missing": ({"goals": None}, r"missing arrays \['goals'\]"),
    }
    save_plans(tmp_path / "good.npz", good)
    assert load_plans(tmp_path / "good.npz")["target"].tolist() == [1, 2]
    for name, (change, msg) in bad.items():
        arrays = {k: v for k, v in {**good, **change}.items() if v is not None}
        with pytest.raises(ValueError, match=msg):
            save_plans(tmp_path / f"{name}.npz", arrays)
        assert not (tmp_path / f"{name}.npz").exists()
        np.savez(tmp_path / f"{name}.npz", **arrays)
        with pytest.raises(ValueError, match=f"--plans {tmp_path / name}.npz: " + msg):
            load_plans(tmp_path / f"{name}.npz")
    from slotv_jax.render import cli as render_cli
    from slotv_jax.study import cli as study_cli

    for main, argv, msg in (
        (render_cli.main, ["--plans", str(tmp_path / "q.npz"), "--out", str(tmp_path)],
         "q: expected"),
        (study_cli.main, ["stimuli", "--plans", str(tmp_path / "target.npz"), "--out",
                          str(tmp_path / "stim")], "target: expected"),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert e.value.code != 0 and len(err) == 1 and "--plans" in err[0] and msg in err[0], err
    assert not (tmp_path / "stim").exists()


def _plans_with(**change) -> dict[str, np.ndarray]:
    plans = _good_plans()
    for k, f in change.items():
        plans[k] = f(plans.get(k))
    return plans


def _nan_at(index):
    def f(a):
        a = a.astype(np.float64 if a.dtype == np.float64 else np.float32).copy()
        a[index] = np.nan
        return a

    return f


BAD_PLANS = {
    "no problems": (_plans_with(goals=lambda a: a[:0], goal_mask=lambda a: a[:0],
                                target=lambda a: a[:0], q=lambda a: a[:, :0],
                                xyz=lambda a: a[:, :0]),
                    "q: expected at least one problem (P >= 1)"),
    "no planners": (_plans_with(names=lambda a: a[:0], q=lambda a: a[:0], xyz=lambda a: a[:0]),
                    "names: expected at least one planner, got none"),
    "every q NaN": (_plans_with(q=_nan_at(...)), "q: no plan in the file"),
    "one point per plan": (_plans_with(q=lambda a: a[:, :, :1], xyz=lambda a: a[:, :, :1]),
                           "q: expected at least 2 points per plan (T >= 2)"),
    "q beyond float32": (_plans_with(q=lambda a: np.where(np.arange(7) == 3, 1e300,
                                                          a.astype(np.float64))),
                         "q: expected magnitudes at most 3.403e+38 (float32), found 1e+300"),
    "every goal NaN": (_plans_with(goals=_nan_at(...)), "goals: expected finite values"),
    "a planner twice": (_plans_with(names=lambda a: np.array(["slotv", "slotv"])),
                        "names: expected each planner once, 'slotv' is twice"),
    "no path of a plan": (_plans_with(xyz=_nan_at((1, 0))),
                          "xyz: expected finite points where q is a plan, planner 'slotv' of "
                          "problem 0"),
    "a family per planner": (_plans_with(family=lambda _: np.array(["dragan"])),
                             "family: expected one entry per problem, shape (2,)"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BAD_PLANS))
def test_every_reader_of_a_bad_plans_file_names_it_before_any_work(case, tmp_path, capsys,
                                                                   monkeypatch):  # fmt: skip
    """Zero problems or planners, no plan at all, T = 1, values beyond float32, NaN goals
    (an IndexError traceback, an unnamed message, or an error once rendering had begun):
    ``render --plans`` and ``study stimuli --plans`` each say one line naming the file and
    the array, exit code 2, before a renderer is made."""
    from slotv_jax.render import cli as render_cli
    from slotv_jax.rendering import frames
    from slotv_jax.study import cli as study_cli

    monkeypatch.setattr(frames.MotionRenderer, "__init__", None)  # must not be reached
    arrays, msg = BAD_PLANS[case]
    path = tmp_path / "plans.npz"
    np.savez(path, **arrays)
    with pytest.raises(ValueError, match="^plans for .*: " + re.escape(msg)):
        save_plans(tmp_path / "out.npz", arrays)
    for main, argv in (
        (render_cli.main, ["--plans", str(path), "--out", str(tmp_path / "r.png"), "--quiet"]),
        (study_cli.main, ["stimuli", "--plans", str(path), "--n", "1", "--out",
                          str(tmp_path / "stim")]),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            main(argv)
        err = capsys.readouterr().err
        want = f"error: --plans {path}: {msg}"
        assert e.value.code == 2 and err.startswith(want) and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plans.npz"]  # nothing written


def test_the_scenes_figure_keeps_plans_apart_and_its_legends_off_the_axes():
    """The recorded planning run's scenes, redrawn from its plans and results: in every panel
    each planner's line has its own (colour, dashes), the oracle's lies wide beneath the
    others (a learned plan equal to it no longer hides it), and every legend sits outside
    its axes, on neither ticks nor goals."""
    from slotv_jax.experiments import planning_report

    root = Path(__file__).resolve().parent.parent / "experiments"
    with np.load(root / "planning_plans.npz", allow_pickle=False) as f:
        pl = {k: f[k] for k in f.files}
    doc = json.loads((root / "planning_results.json").read_text())
    fig = planning_report.scenes_figure(pl, doc, 3)
    fig.canvas.draw()
    panels = [ax for ax in fig.axes if ax.get_legend() is not None]
    assert len(panels) == 3 * len(planning_report.families(doc))
    for ax in panels:
        lines = [ln for ln in ax.get_lines() if ln.get_label() and ln.get_label()[0] != "_"]
        assert len(lines) == len(pl["names"])
        styles = [(ln.get_color(), str(ln.get_linestyle()), ln.get_linewidth()) for ln in lines]
        assert len(set(styles)) == len(styles)
        oracle = next(ln for ln in lines if "(oracle)" in ln.get_label())
        assert all(oracle.get_zorder() < ln.get_zorder() for ln in lines if ln is not oracle)
        assert all(oracle.get_linewidth() > ln.get_linewidth() for ln in lines if ln is not oracle)
        box, inner = ax.get_legend().get_window_extent(), ax.get_window_extent()
        ticks = ax.xaxis.get_tightbbox()  # the x ticks, their labels and the axis label
        assert not box.overlaps(inner) and box.y1 <= ticks.y0 + 1, (box, inner, ticks)
