"""The one table of names and default temperatures: a labeler called without β, a dataset
generated without β and the labelers' command line agree."""

from __future__ import annotations

import numpy as np
import pytest

from slotv_jax import data
from slotv_jax.core import defaults, validation
from slotv_jax.labelers import cli as labelers_cli
from slotv_jax.observers import labelers, labelling
from slotv_jax.world import scene

ROWS = 8  # trajectories compared per split


def test_the_tables_are_shared_not_copied():
    assert labelers.DEFAULT_BETAS is defaults.DEFAULT_BETAS
    assert labelers.LABELER_NAMES is defaults.LABELER_NAMES is data.LABELER_NAMES
    assert data.SPLITS is defaults.SPLITS
    assert set(defaults.TEST_SPLITS) <= set(defaults.SPLITS)
    assert tuple(defaults.DEFAULT_BETAS) == tuple(defaults.BETAS_V1) == defaults.LABELER_NAMES
    assert data.LabelConfig().betas() == dict(defaults.DEFAULT_BETAS)
    assert data.LABELS_V1.betas() == dict(defaults.BETAS_V1)
    assert data.DATA_DISTRIBUTIONS["spec_v1"][1] == data.LABELS_V1
    # the values :ref:`concepts-temperatures` states (the datasets' temperatures), and the first
    # version's
    assert dict(defaults.DEFAULT_BETAS) == {
        "dragan": 20.0,
        "nikolaidis": 30.0,
        "effdist": 20.0,
        "fastapp": 20.0,
    }
    assert dict(defaults.BETAS_V1) == {
        "dragan": 5.0,
        "nikolaidis": 7.5,
        "effdist": 5.0,
        "fastapp": 5.0,
    }
    with pytest.raises(TypeError):
        defaults.DEFAULT_BETAS["dragan"] = 1.0  # type: ignore[index]


@pytest.mark.parametrize("name", defaults.LABELER_NAMES)
def test_labeler_without_beta_equals_the_dataset_label(tiny_data, name):
    """``labelers.<name>(xyz, goals, mask)`` with no β gives the dataset's ``y_<name>`` of
    the same trajectory (float32 rounding); the first version's β does not."""
    cam = scene.camera(data.DataConfig().labels.camera)
    for split in ("train", "position_test", "goal_count_test"):
        s = tiny_data[split]
        for i in range(ROWS):
            args = (s.xyz[i], s.goals[i], s.goal_mask[i])
            fn = labelers.LABELERS[name]
            kw = {"camera": cam} if name == "nikolaidis" else {}
            y = np.asarray(fn(*args, **kw))
            np.testing.assert_allclose(y, s.labels[name][i], rtol=0, atol=2e-6,
                                       err_msg=f"{name} {split} {i}")  # fmt: skip
        # the test can fail: the old default temperature gives other labels
        y_v1 = np.stack([
            np.asarray(fn(s.xyz[i], s.goals[i], s.goal_mask[i], beta=defaults.BETAS_V1[name], **kw))
            for i in range(ROWS)
        ])  # fmt: skip
        assert np.abs(y_v1 - s.labels[name][:ROWS]).max() > 1e-2, (name, split)


def test_label_all_and_the_command_line_default_to_the_table(tmp_path):
    rng = np.random.default_rng(0)
    xyz = rng.uniform([0.3, -0.4, 0.1], [0.7, 0.4, 0.4], (3, 20, 3)).astype(np.float32)
    goals = np.zeros((8, 3), np.float32)
    goals[:3] = [[0.4, 0.3, 0.025], [0.5, 0.0, 0.025], [0.6, -0.3, 0.025]]
    mask = np.arange(8) < 3
    y = labelling.label_all(xyz, goals, mask, progress=False)
    np.savez(tmp_path / "in.npz", xyz=xyz, goals=goals, goal_mask=mask)
    assert labelers_cli.main(["--in", str(tmp_path / "in.npz"), "--out", str(tmp_path / "out.npz"),
                          "--quiet"]) == 0  # fmt: skip
    with np.load(tmp_path / "out.npz") as f:
        for name in defaults.LABELER_NAMES:
            assert float(f[f"beta_{name}"]) == defaults.DEFAULT_BETAS[name]
            np.testing.assert_array_equal(f[f"y_{name}"], y[name])
    kw = {"camera": scene.camera("observer")}
    for name in defaults.LABELER_NAMES:
        one = labelers.LABELERS[name](xyz[1], goals, mask, **(kw if name == "nikolaidis" else {}))
        np.testing.assert_allclose(y[name][1], np.asarray(one), rtol=0, atol=2e-6, err_msg=name)


def test_beta_is_checked_once_on_the_dataset_path(tiny_data, monkeypatch):
    """β is checked when the LabelConfig is made, and not again while a split is labelled
    (the labelers' own check only sees concrete values; under label_with β is traced)."""
    seen = []
    check = validation.check_positive

    def counting(name, value):
        if validation.is_concrete(value):
            seen.append(name)
        return check(name, value)

    monkeypatch.setattr(validation, "check_positive", counting)
    labels = data.LabelConfig(beta_dragan=21.0)
    assert seen == [f"beta_{n}" for n in defaults.LABELER_NAMES]
    seen.clear()
    split = tiny_data["position_test"]
    out = data.relabel(split, labels, progress=False)
    assert seen == []
    y = labelers.dragan(split.xyz[0], split.goals[0], split.goal_mask[0], beta=21.0)
    np.testing.assert_allclose(out.labels["dragan"][0], np.asarray(y), rtol=0, atol=2e-6)
    assert seen == ["beta"]  # the public labeler checks its own (concrete) β
    with pytest.raises(ValueError, match="beta_effdist: expected a finite number > 0"):
        labelling.label_all(split.xyz[:2], split.goals[:2], split.goal_mask[:2], beta_effdist=0)
    with pytest.raises(ValueError, match=r"DataConfig\.labels: expected a LabelConfig"):
        data.DataConfig(labels=data.LabelConfig(camera=scene.camera("observer")))
