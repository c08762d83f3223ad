"""Datasets: split structure, determinism, labels, storage, corruption detection, resume, CLI."""

import collections
import dataclasses
import json
import os
import types
from pathlib import Path

import numpy as np
import pytest
from docs_pages import all_text

from slotv_jax import data
from slotv_jax.data import cli as data_cli
from slotv_jax.data import generate
from slotv_jax.data import report as data_report
from slotv_jax.world.trajectories import TrajectoryConfig

GOAL_COUNTS = {
    "train": {2, 3, 5, 6},
    "trajectory_val": {2, 3, 5, 6},
    "trajectory_test": {2, 3, 5, 6},
    "position_val": {2, 3, 5, 6},
    "position_test": {2, 3, 5, 6},
    "goal_count_val": {7},
    "goal_count_test": {4, 8},
}


def test_split_sizes_scenes_and_goal_counts(tiny_data, tiny_cfg):
    assert set(tiny_data) == set(data.SPLITS)
    for name, split in tiny_data.items():
        assert len(split) == tiny_cfg.split_size(name)
        n_scenes = tiny_cfg.n_train_scenes if name.startswith(("train", "trajectory")) else 4
        assert split.scene_goals.shape == (n_scenes, 8, 3)
        assert set(split.scene_mask.sum(-1)) <= GOAL_COUNTS[name]
        assert split.env_id.min() >= 0 and split.env_id.max() < n_scenes
        assert split.meta["reachability"]["trajectory_rejection_rate"] >= 0
    # train / trajectory_* share their scenes; the other splits have new ones.
    np.testing.assert_array_equal(
        tiny_data["train"].scene_goals, tiny_data["trajectory_test"].scene_goals
    )
    a = tiny_data["position_val"].scene_goals.reshape(-1, 3)
    b = tiny_data["position_test"].scene_goals.reshape(-1, 3)
    assert not np.array_equal(a, b)
    # Trajectory splits drawn independently of train.
    assert not np.array_equal(tiny_data["train"].xyz[:100], tiny_data["trajectory_val"].xyz)


def test_labels_are_distributions(tiny_data):
    for split in tiny_data.values():
        assert set(split.labels) == set(data.LABELER_NAMES)
        for y in split.labels.values():
            assert y.shape == (len(split), 8) and y.dtype == np.float32
            assert np.all(y[~split.goal_mask] == 0.0)
            assert np.all(y >= 0)
            np.testing.assert_allclose(y.sum(-1), 1.0, atol=1e-5)


@pytest.mark.slow
def test_determinism_and_chunk_size_independence(tiny_data, tiny_cfg):
    """Same seed and config: identical arrays, whatever the chunk size."""
    again = data.generate_dataset(tiny_cfg, None, splits=["position_val"], progress=False)
    ref = tiny_data["position_val"]
    for k, a in ref.arrays().items():
        np.testing.assert_array_equal(a, again["position_val"].arrays()[k], err_msg=k)
    # Another chunk size: the same draws; floats agree to float32 rounding (XLA compiles each
    # batch shape on its own, so the last bit may differ).
    cfg = dataclasses.replace(tiny_cfg, chunk_size=64)
    small = data.generate_dataset(cfg, None, splits=["position_val"], progress=False)
    for k in ("target", "env_id", "n_via", "scene_goals", "scene_mask"):
        np.testing.assert_array_equal(getattr(ref, k), getattr(small["position_val"], k), k)
    np.testing.assert_allclose(small["position_val"].xyz, ref.xyz, rtol=0, atol=1e-5)
    other = data.generate_dataset(
        dataclasses.replace(tiny_cfg, seed=1), None, splits=["position_val"], progress=False
    )
    assert not np.array_equal(ref.xyz, other["position_val"].xyz)


def test_unreachable_draws_are_rejected_and_counted(tiny_cfg):
    """Via points partly out of reach: those draws are redrawn and the rate is reported."""
    far = TrajectoryConfig(via_low=(0.25, -0.5, 0.1), via_high=(1.3, 0.5, 0.4))
    cfg = dataclasses.replace(tiny_cfg, trajectory=far)
    split = data.generate_dataset(cfg, None, splits=["position_test"], progress=False)
    split = split["position_test"]
    r = split.meta["reachability"]
    assert len(split) == cfg.n_eval
    assert 0.05 < r["trajectory_rejection_rate"] < 0.95
    assert r["trajectories_drawn"] > cfg.n_eval
    assert split.residual.max() <= far.max_residual


def test_round_trip_and_checksums(tiny_data, tiny_cfg, tmp_path):
    split = tiny_data["goal_count_val"]
    data.save_split(tmp_path, split, tiny_cfg)
    back = data.load_split(tmp_path, "goal_count_val")
    for k, a in split.arrays().items():
        np.testing.assert_array_equal(a, back.arrays()[k], err_msg=k)
        assert back.arrays()[k].dtype == a.dtype
    meta = json.loads((tmp_path / "goal_count_val.json").read_text())
    assert meta["config_digest"] == tiny_cfg.digest()
    assert meta["seed"] == tiny_cfg.seed
    assert {"jax", "mujoco", "numpy"} <= set(meta["environment"])
    assert set(meta["arrays"]) == set(split.arrays())
    assert all(len(v["sha256"]) == 64 for v in meta["arrays"].values())
    assert not list(tmp_path.glob(".*tmp"))  # no temporary files left behind
    np.testing.assert_array_equal(back.goals, split.scene_goals[split.env_id])


@pytest.fixture
def saved(tiny_data, tiny_cfg, tmp_path):
    data.save_split(tmp_path, tiny_data["position_test"], tiny_cfg)
    return tmp_path


def test_truncated_file_is_detected(saved):
    p = saved / "position_test.npz"
    p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])
    with pytest.raises(ValueError, match=r"position_test\.npz.*(corrupt|truncated)"):
        data.load_split(saved, "position_test")


def test_flipped_byte_is_detected(saved):
    p = saved / "position_test.npz"
    b = bytearray(p.read_bytes())
    # Flip a byte inside the xyz payload (stored uncompressed), far from any header.
    off = b.find(b"xyz.npy") + 4000
    b[off] ^= 0xFF
    p.write_bytes(bytes(b))
    with pytest.raises(ValueError, match=r"position_test\.npz"):
        data.load_split(saved, "position_test")


def test_swapped_array_fails_checksum(saved, tiny_data):
    split = tiny_data["position_test"]
    arrays = split.arrays()
    arrays["target"] = (arrays["target"] + 1) % 2
    np.savez(saved / "position_test.npz", **arrays)
    with pytest.raises(ValueError, match="'target' fails its SHA-256"):
        data.load_split(saved, "position_test")


def test_corrupt_or_mismatched_sidecar(saved):
    j = saved / "position_test.json"
    meta = json.loads(j.read_text())
    meta["arrays"]["xyz"]["shape"] = [1, 100, 3]
    j.write_text(json.dumps(meta))
    with pytest.raises(ValueError, match=r"'xyz'.*sidecar says"):
        data.load_split(saved, "position_test")
    j.write_text("{not json")
    with pytest.raises(ValueError, match=r"position_test\.json: corrupt JSON"):
        data.load_split(saved, "position_test")
    j.unlink()
    with pytest.raises(FileNotFoundError, match=r"position_test\.json"):
        data.load_split(saved, "position_test")
    with pytest.raises(ValueError, match="name: expected one of"):
        data.load_split(saved, "validation")


def test_missing_array_is_detected(saved, tiny_data):
    arrays = tiny_data["position_test"].arrays()
    del arrays["q"]
    np.savez(saved / "position_test.npz", **arrays)
    with pytest.raises(ValueError, match="do not match the sidecar"):
        data.load_split(saved, "position_test")


def test_resume_skips_finished_splits_and_refuses_other_configs(tiny_data, tiny_cfg, tmp_path):
    for name in ("position_val", "position_test"):
        data.save_split(tmp_path, tiny_data[name], tiny_cfg)
    stamp = os.stat(tmp_path / "position_val.npz").st_mtime_ns
    out = data.generate_dataset(
        tiny_cfg, tmp_path, splits=["position_val", "position_test"], progress=False
    )
    assert os.stat(tmp_path / "position_val.npz").st_mtime_ns == stamp
    np.testing.assert_array_equal(out["position_val"].xyz, tiny_data["position_val"].xyz)
    with pytest.raises(ValueError, match="another config"):
        data.generate_dataset(dataclasses.replace(tiny_cfg, seed=9), tmp_path, progress=False)


def test_ctrl_c_leaves_no_dataset_folder_or_one_that_resumes(
    tiny_data, tiny_cfg, tmp_path, monkeypatch, capsys
):
    """Ctrl-C in the first split leaves nothing named like the dataset (it left an empty
    data/<preset>-<digest>); Ctrl-C in a later split leaves the finished splits, which the
    next run keeps, making only the rest."""
    made = []

    def split_or_ctrl_c(cfg, name, scenes, progress=True):  # stands in for minutes of work
        if name in interrupt:
            raise KeyboardInterrupt
        made.append(name)
        return dataclasses.replace(tiny_data[name], meta={"reachability": {}})

    monkeypatch.setattr(generate, "sample_scene_sets",
                        lambda cfg: collections.defaultdict(lambda: (None, {})))  # fmt: skip
    monkeypatch.setattr(generate, "generate_split", split_or_ctrl_c)
    monkeypatch.chdir(tmp_path)
    home = data.dataset_dir(data.DEFAULT_CACHE, tiny_cfg)
    splits = ["position_val", "position_test"]
    interrupt = {"position_val"}
    with pytest.raises(KeyboardInterrupt):
        generate.cached_dataset(tiny_cfg, data.DEFAULT_CACHE, splits=splits, progress=False)
    assert list(tmp_path.iterdir()) == []  # no data/, no data/tiny-<digest>
    # through the command: one line, exit 130, still nothing written
    monkeypatch.setattr(data_cli, "config_for", lambda *a, **k: tiny_cfg)
    with pytest.raises(SystemExit) as e:
        data_cli.main(["--splits", *splits])
    assert e.value.code == 130 and list(tmp_path.iterdir()) == []
    assert capsys.readouterr().err.strip().endswith("interrupted; rerun the same command to resume")
    interrupt = {"position_test"}  # Ctrl-C in the second split: the first one is kept
    with pytest.raises(KeyboardInterrupt):
        generate.cached_dataset(tiny_cfg, data.DEFAULT_CACHE, splits=splits, progress=False)
    assert sorted(p.name for p in home.iterdir()) == ["position_val.json", "position_val.npz"]
    stamp = os.stat(home / "position_val.npz").st_mtime_ns
    interrupt, made[:] = set(), []
    out = generate.cached_dataset(tiny_cfg, data.DEFAULT_CACHE, splits=splits, progress=False)
    assert made == ["position_test"] and os.stat(home / "position_val.npz").st_mtime_ns == stamp
    np.testing.assert_array_equal(out["position_val"].xyz, tiny_data["position_val"].xyz)
    np.testing.assert_array_equal(data.load_split(home, "position_test").xyz,
                                  tiny_data["position_test"].xyz)  # fmt: skip


def test_cli_generate_into_the_cache_and_relabel(tmp_path, monkeypatch, capsys):
    """Without --out the command writes the cache folder (as the main job does), a rerun
    regenerates nothing, the cache is never relabelled in place, and --relabel --data SRC
    --out DST writes new labels on the same trajectories elsewhere."""
    monkeypatch.chdir(tmp_path)
    opts = ["--splits", "goal_count_test", "--n-eval", "100", "--n-train", "300"]
    opts += ["--chunk-size", "512"]
    assert data_cli.main(opts) == 0
    cfg = data.config_for("quick", n_eval=100, n_train=300, chunk_size=512)
    cache = data.dataset_dir("data", cfg)
    out = capsys.readouterr().out
    assert f"wrote {cache} in" in out and "--data quick" not in out  # not the preset's own
    split = data.load_split(cache, "goal_count_test")
    assert len(split) == 100 and split.meta["config"]["preset"] == "quick"
    stamp = os.stat(cache / "goal_count_test.npz").st_mtime_ns
    assert data_cli.main(opts) == 0  # the same command again: reused, not regenerated
    assert os.stat(cache / "goal_count_test.npz").st_mtime_ns == stamp
    relabel = ["--relabel", "--splits", "goal_count_test", "--beta-dragan", "1.0"]
    with pytest.raises(SystemExit) as e:  # in place, the cache would lie about its config
        data_cli.main([*relabel, "--out", str(cache)])
    assert e.value.code == 2 and "another folder" in capsys.readouterr().err
    assert data_cli.main([*relabel, "--data", str(cache), "--out", "soft"]) == 0
    relabelled = data.load_split("soft", "goal_count_test")
    assert relabelled.meta["label_config"]["beta_dragan"] == 1.0
    np.testing.assert_array_equal(relabelled.xyz, split.xyz)
    np.testing.assert_array_equal(relabelled.labels["effdist"], split.labels["effdist"])
    assert not np.allclose(relabelled.labels["dragan"], split.labels["dragan"])
    stamp = os.stat(Path("soft") / "goal_count_test.npz").st_mtime_ns
    capsys.readouterr()
    assert data_cli.main([*relabel, "--data", str(cache), "--out", "soft"]) == 0  # resumed
    assert os.stat(Path("soft") / "goal_count_test.npz").st_mtime_ns == stamp
    assert "goal_count_test: already relabelled in soft, kept" in capsys.readouterr().out
    # Softer labels: lower β gives higher entropy.
    ent = lambda y: -(y * np.log(np.where(y > 0, y, 1))).sum(-1).mean()  # noqa: E731
    assert ent(relabelled.labels["dragan"]) > ent(split.labels["dragan"])
    again = data.load_split(cache, "goal_count_test")  # the source is untouched
    np.testing.assert_array_equal(again.labels["dragan"], split.labels["dragan"])
    # an ordinary folder is relabelled in place, as before
    assert data_cli.main([*relabel[:-1], "30", "--out", "soft"]) == 0
    sharp = data.load_split("soft", "goal_count_test")
    assert ent(sharp.labels["dragan"]) < ent(relabelled.labels["dragan"])


# ------------------------------------------------------- one place for the data


def test_the_main_job_caches_where_a_preset_name_looks():
    """Table 1's dataset (its run preset's data config in its default cache) is the folder
    that the preset's name finds, and the data command's default config is the same."""
    from slotv_jax.runs.presets import PRESETS as RUNS

    for p in ("quick", "paper"):
        assert data.dataset_dir(data.DEFAULT_CACHE, RUNS[p]().data) == data.preset_dir(p)
        assert data.config_for(p).digest() == RUNS[p]().data.digest()
        assert data.data_command(RUNS[p]().data) == f"python -m slotv_jax.data --preset {p}"


def test_a_preset_name_reads_the_cached_dataset(tiny_data, tmp_path, monkeypatch, capsys):
    """`--data quick` / load_split("quick", ...) read data/quick-<digest>; the data command
    on it reuses what is there and says how other commands find it."""
    monkeypatch.chdir(tmp_path)
    home = data.preset_dir("quick")
    assert home == data.DEFAULT_CACHE / f"quick-{data.quick().digest()}"
    split = tiny_data["position_test"]
    home.mkdir(parents=True)
    data.save_split(home, split, data.quick())  # stands in for the main job's split
    back = data.load_split("quick", "position_test")
    np.testing.assert_array_equal(back.xyz, split.xyz)
    assert data.find_dataset("quick") == home
    stamp = os.stat(home / "position_test.npz").st_mtime_ns
    assert data_cli.main(["--preset", "quick", "--splits", "position_test"]) == 0
    out = capsys.readouterr().out
    assert f"found {home}: every split was already there" in out  # nothing was made
    assert "other commands find it as --data quick" in out
    assert os.stat(home / "position_test.npz").st_mtime_ns == stamp  # not regenerated
    (tmp_path / "quick").mkdir()  # a folder of that name is what it names
    assert data.find_dataset("quick") == tmp_path.joinpath("quick").relative_to(tmp_path)


def test_a_misspelt_preset_names_the_presets_and_the_closest(tmp_path, monkeypatch, capsys):
    """`--data qiuck` (no such folder): the folder is missing, the presets are named and the
    closest one suggested; a name close to none names the presets without a guess."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("SLOTV_JAX_TRACEBACK", raising=False)  # the command's own one line
    with pytest.raises(SystemExit) as e:
        data_report.main(["--data", "qiuck"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: qiuck: no such dataset folder ("), err
    assert "the presets: quick, paper; did you mean quick?" in err
    assert "paper" in err.split("did you mean")[0]  # every preset, not only the closest
    with pytest.raises(FileNotFoundError) as e:
        data.find_dataset("papr")
    assert "did you mean paper?" in str(e.value)
    with pytest.raises(FileNotFoundError) as e:
        data.find_dataset("zzzz")
    assert "the presets: quick, paper" in str(e.value) and "did you mean" not in str(e.value)


def test_the_splits_bar_says_what_it_waits_for_first(tiny_cfg, monkeypatch):
    """Before the first split's bar, the scenes' goals are checked by IK, compiled first (a
    silent 18-40 s on a loaded 2-core CPU): the splits bar says so while it waits."""
    bars, seen = [], []

    class Bar:
        def __init__(self, iterable=None, **kw):
            self.iterable, self.post = iterable, ""
            bars.append(self)

        def __iter__(self):
            return iter(self.iterable)

        def set_postfix_str(self, s, refresh=True):
            self.post = s

    def scene_sets(cfg):
        seen.append(bars[0].post)
        return collections.defaultdict(lambda: (None, {}))

    monkeypatch.setattr(generate, "tqdm", Bar)
    monkeypatch.setattr(generate, "sample_scene_sets", scene_sets)
    made = types.SimpleNamespace(meta={"reachability": {}})
    monkeypatch.setattr(generate, "generate_split", lambda *a, **k: made)
    generate.generate_dataset(tiny_cfg, None, splits=["train", "position_test"])
    assert seen == ["scenes: compiling inverse kinematics, checking the goals"]  # once
    assert bars[0].post == ""  # gone once the splits have their own bars


def test_a_missing_dataset_names_the_command_that_makes_it(tiny_data, tmp_path, monkeypatch):
    """A preset name run from a folder without the cache: the absolute folder looked in, how
    to point at the dataset (the folder holding data/, or its own path), how to make it."""
    monkeypatch.chdir(tmp_path)
    for name in ("quick", Path("quick")):  # the commands pass a Path
        with pytest.raises(FileNotFoundError) as e:
            data.load_split(name, "position_test")
        msg = str(e.value)
        assert msg.startswith("dataset 'quick': the quick preset's dataset is not in "
                              f"{tmp_path / data.preset_dir('quick')} "), msg  # fmt: skip
        assert "run the command from the folder that holds data/" in msg
        assert f"--data DIR/data/{data.preset_dir('quick').name}" in msg
        assert "run: python -m slotv_jax.data --preset quick " not in msg  # not the first advice
        assert "to make it here: python -m slotv_jax.data --preset quick " in msg
    with pytest.raises(FileNotFoundError) as e:  # another cache: looked for there
        data.find_dataset("quick", cache=tmp_path / "elsewhere")
    assert f"is not in {tmp_path / 'elsewhere' / data.preset_dir('quick').name};" in str(e.value)
    with pytest.raises(FileNotFoundError) as e:
        data.load_split("data/quick", "position_test")
    msg = str(e.value)
    assert f"data/quick: no such dataset folder ({tmp_path / 'data/quick'})" in msg
    assert "run: python -m slotv_jax.data --preset quick --out data/quick" in msg
    assert "preset name alone (quick)" in msg
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError) as e:
        data.load_split("empty", "train")
    assert "empty holds no dataset; run: python -m slotv_jax.data --preset quick --out empty" in (
        str(e.value)
    )
    # a folder with other splits: the exact command that adds the missing one
    some = tmp_path / "some"
    some.mkdir()
    data.save_split(some, tiny_data["position_test"], data.quick(n_eval=100, seed=2))
    with pytest.raises(FileNotFoundError) as e:
        data.load_split(some, "train")
    want = f"run: python -m slotv_jax.data --preset quick --seed 2 --n-eval 100 --out {some}"
    assert "holds position_test but not train" in str(e.value)
    assert f"{want} --splits train" in str(e.value)


def test_readme_reads_the_dataset_the_main_job_makes():
    """Every dataset the README and the manual read is a preset's cached one (made by the
    main job) or the --out of an earlier command of theirs; none generates it a second time."""
    import re

    text = all_text()
    reads = [(m.start(), m.group(1)) for m in re.finditer(r"--data ([^\s`]+)", text)]
    reads += [(m.start(), m.group(1)) for m in re.finditer(r'load_split\("([^"]+)"', text)]
    assert len(reads) >= 6
    for at, where in reads:
        made = re.search(rf"--out {re.escape(where)}\b", text[:at])
        assert where in data.PRESETS or made, f"the docs read {where!r}, which nothing made"
    for line in re.findall(r"python -m slotv_jax\.data [^\n`]*", text):
        assert "--relabel" in line or "--out" not in line, line  # the cache, not a copy


@pytest.mark.parametrize(
    "kw",
    [
        {"n_train": 0},
        {"n_eval": -5},
        {"chunk_size": 0},
        {"n_new_scenes": 0},
        {"train_goal_counts": (2, 9)},
        {"goal_count_val_counts": ()},
    ],
)
def test_config_validation(kw):
    with pytest.raises(ValueError, match="DataConfig"):
        data.DataConfig(**kw)


def test_presets_keep_every_split():
    q, p = data.quick(), data.paper()
    assert (p.n_train, p.n_eval, p.n_train_scenes, p.n_new_scenes) == (100_000, 10_000, 250, 10)
    assert q.n_train_scenes == 250 and q.n_new_scenes == 10
    assert p.n_train + 6 * p.n_eval == 160_000
