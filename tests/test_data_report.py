"""The label report: statistics against hand-computed values, and the files it writes."""

import math

import numpy as np
import pytest

from slotv_jax import data
from slotv_jax.data import report as lr
from slotv_jax.data import stats


def _split(name: str, labels: dict[str, np.ndarray], target, env_id, mask) -> data.Split:
    """A hand-built Split with the given labels; trajectories and goals are zeros."""
    n = len(target)
    mask = np.asarray(mask, bool)
    return data.Split(
        name=name,
        xyz=np.zeros((n, 5, 3), np.float32),
        q=np.zeros((n, 5, 7), np.float32),
        target=np.asarray(target, np.int32),
        env_id=np.asarray(env_id, np.int32),
        n_via=np.zeros(n, np.int32),
        residual=np.zeros(n, np.float32),
        scene_goals=np.zeros((mask.shape[0], 8, 3), np.float32),
        scene_mask=mask,
        labels={k: np.asarray(v, np.float32) for k, v in labels.items()},
        meta={"config_digest": "abc123", "environment": {"jax": "0.0", "numpy": "1.0"}},
    )


def _onehot(k: int) -> list[float]:
    y = [0.0] * 8
    y[k] = 1.0
    return y


# Two scenes: scene 0 has 4 real goals, scene 1 has 2.
MASK = [[1, 1, 1, 1, 0, 0, 0, 0], [1, 1, 0, 0, 0, 0, 0, 0]]
U4 = [0.25] * 4 + [0.0] * 4
TIE = [0.5, 0.5] + [0.0] * 6


@pytest.fixture
def split() -> data.Split:
    """Three trajectories (targets 2, 1, 0; scenes 0, 0, 1) with known labels."""
    labels = {
        "dragan": [_onehot(2), _onehot(3), _onehot(0)],  # argmax 2, 3, 0: targets 2/3 hit
        "nikolaidis": [U4, U4, TIE],  # argmax 0 (tie), 0 (tie), 0 (tie)
        "effdist": [_onehot(2), _onehot(1), _onehot(0)],  # argmax = target everywhere
        "fastapp": [_onehot(2), _onehot(0), _onehot(1)],  # argmax 2, 0, 1
    }
    return _split("train", labels, target=[2, 1, 0], env_id=[0, 0, 1], mask=MASK)


def test_entropy_and_argmax_by_hand():
    mask = np.array([[1, 1, 1, 1, 0, 0, 0, 0]] * 3, bool)
    y = np.array([_onehot(1), U4, [0.5, 0.5, 0, 0, 0, 0, 0, 0]])
    np.testing.assert_allclose(stats.entropy(y, mask), [0.0, math.log(4), math.log(2)], atol=1e-12)
    # ties go to the lowest slot; a padded slot never wins, even if it is larger
    assert stats.masked_argmax(y, mask).tolist() == [1, 0, 0]
    y_pad = np.array([[0.1, 0.2, 0.3, 0.4, 0.9, 0, 0, 0]])
    assert stats.masked_argmax(y_pad, mask[:1]).tolist() == [3]


def test_label_stats_by_hand(split):
    mask = split.goal_mask
    one = stats.label_stats(split.labels["effdist"], split.target, mask)
    assert one["entropy"] == 0.0
    assert one["max_prob"] == 1.0
    assert one["target_agreement"] == 1.0
    assert one["max_sum_error"] == 0.0 and one["max_padded"] == 0.0
    uniform = math.log(4) * 2 / 3 + math.log(2) / 3
    assert one["uniform_entropy"] == pytest.approx(uniform)
    assert one["chance"] == pytest.approx((0.25 + 0.25 + 0.5) / 3)
    assert one["uniform_max_prob"] == pytest.approx(one["chance"])

    flat = stats.label_stats(split.labels["nikolaidis"], split.target, mask)
    assert flat["entropy"] == pytest.approx(uniform, rel=1e-6)
    assert flat["entropy_ratio"] == pytest.approx(1.0, rel=1e-6)
    assert flat["max_prob"] == pytest.approx((0.25 + 0.25 + 0.5) / 3)
    assert flat["target_agreement"] == pytest.approx(1 / 3)  # argmax 0 = target only in traj 2

    dragan = stats.label_stats(split.labels["dragan"], split.target, mask)
    assert dragan["target_agreement"] == pytest.approx(2 / 3)


def test_split_stats_agreement_by_hand(split):
    s = stats.split_stats(split)
    assert s["n"] == 3 and s["goal_counts"] == {2: 1, 4: 2}
    # argmaxes: dragan 2,3,0  nikolaidis 0,0,0  effdist 2,1,0  fastapp 2,0,1
    assert s["all_agree"] == 0.0
    pw = s["pairwise"]
    assert pw["dragan"]["effdist"] == pytest.approx(2 / 3)
    assert pw["dragan"]["fastapp"] == pytest.approx(1 / 3)
    assert pw["nikolaidis"]["fastapp"] == pytest.approx(1 / 3)
    assert pw["effdist"]["nikolaidis"] == pytest.approx(1 / 3)
    assert all(pw[n][n] == 1.0 for n in lr.LABELERS)
    # all four agree when every labeler is the same one-hot
    same = {n: [_onehot(2), _onehot(1), _onehot(0)] for n in lr.LABELERS}
    s2 = stats.split_stats(_split("train", same, [2, 1, 0], [0, 0, 1], MASK))
    assert s2["all_agree"] == 1.0


def test_collect_averages_pairwise_over_splits(split):
    same = {n: [_onehot(0)] for n in lr.LABELERS}
    other = _split("position_test", same, [0], [1], MASK)
    stats = lr.collect({"train": split, "position_test": other})
    assert stats["pairwise_mean"]["dragan"]["fastapp"] == pytest.approx((1 / 3 + 1) / 2)


def test_write_report_files(split, tmp_path):
    other = _split(
        "goal_count_test",
        {n: [_onehot(1), U4] for n in lr.LABELERS},
        target=[1, 3],
        env_id=[0, 0],
        mask=MASK,
    )
    out = tmp_path / "exp"
    lr.write_report(
        {"train": split, "goal_count_test": other}, out, command="python -m x", date="2026-11-21"
    )
    md = (out / "labels.md").read_text()
    assert "`abc123`" in md and "2026-11-21" in md and "`python -m x`" in md
    assert "jax 0.0" in md and "![label statistics](labels.png)" in md
    assert "| EffDist | train | 0.000 |" in md
    png = (out / "labels.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    assert sorted(p.name for p in out.iterdir()) == ["labels.md", "labels.png"]  # no temp files


def test_write_report_rejects_mixed_datasets(split, tmp_path):
    other = _split("position_test", {n: [_onehot(0)] for n in lr.LABELERS}, [0], [1], MASK)
    other.meta["config_digest"] = "different"
    with pytest.raises(ValueError, match="different dataset configs"):
        lr.write_report({"train": split, "position_test": other}, tmp_path, command="x")


def test_the_command_reports_the_splits_a_dataset_holds(split, tmp_path, capsys):
    """Without --splits the command takes every split the folder holds (a dataset made for
    one experiment holds only some); a folder without one is a one-line error."""
    other = _split("position_test", {n: [_onehot(0)] for n in lr.LABELERS}, [0], [1], MASK)
    folder = tmp_path / "dataset"
    folder.mkdir()
    for s in (split, other):
        s.meta.pop("config_digest")  # save_split writes the config's own
        data.save_split(folder, s, data.DataConfig(preset="tiny", n_train=3, n_eval=1))
    out = tmp_path / "report"
    assert lr.main(["--data", str(folder), "--out", str(out), "--date", "2026-11-27"]) == 0
    md = (out / "labels.md").read_text()
    assert "| train | 3 |" in md and "| position_test | 1 |" in md
    assert "trajectory_val" not in md
    assert lr.main(["--data", str(folder), "--out", str(out), "--splits", "train"]) == 0
    assert "position_test" not in (out / "labels.md").read_text()
    (tmp_path / "empty").mkdir()
    with pytest.raises(SystemExit) as e:
        lr.main(["--data", str(tmp_path / "empty"), "--out", str(out)])
    assert e.value.code == 2
    assert capsys.readouterr().err.strip().endswith("holds no dataset split")


def test_the_command_regenerates_its_report_and_refuses_anybody_elses(split, tmp_path, capsys):
    """--out may hold anything: a report of ours is written again, a labels.md (or a
    labels.png without our labels.md) of somebody else's is refused before any work and
    left as it was."""
    folder = tmp_path / "dataset"
    folder.mkdir()
    split.meta.pop("config_digest")
    data.save_split(folder, split, data.DataConfig(preset="tiny", n_train=3, n_eval=1))
    out = tmp_path / "shared"
    args = ["--data", str(folder), "--out", str(out)]
    assert lr.main(args) == 0 and lr.main(args) == 0  # ours: regenerated
    assert lr.is_report(out / "labels.md")
    for name in ("labels.md", "labels.png"):
        mine = tmp_path / f"mine_{name}"
        mine.mkdir()
        (mine / name).write_text("my own notes\n")
        (mine / "keep.txt").write_text("x")
        with pytest.raises(SystemExit) as e:
            lr.main(["--data", str(folder), "--out", str(mine)])
        assert e.value.code == 2
        assert f"{name} exists and is not ours" in capsys.readouterr().err
        assert (mine / name).read_text() == "my own notes\n"
        assert sorted(p.name for p in mine.iterdir()) == sorted([name, "keep.txt"])
