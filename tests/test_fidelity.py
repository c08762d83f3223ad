"""The fidelity ablation: its settings, a resumed run, the report; Table 1's merge."""

import copy
import dataclasses
import json

import pytest
from test_experiments import cache  # noqa: F401  (the tiny dataset, cached as table1 finds it)

from slotv_jax import data
from slotv_jax.core.defaults import TEST_SPLITS
from slotv_jax.experiments import fidelity
from slotv_jax.runs import grid
from slotv_jax.world import trajectories


def _differences(a: data.DataConfig, b: data.DataConfig) -> set[str]:
    """Names of the dataset fields (trajectory.* and labels.*) in which a and b differ."""
    out = set()
    for part in ("trajectory", "labels"):
        x, y = dataclasses.asdict(getattr(a, part)), dataclasses.asdict(getattr(b, part))
        out |= {f"{part}.{k}" for k in x if x[k] != y[k]}
    rest = {f.name for f in dataclasses.fields(a)} - {"trajectory", "labels"}
    out |= {k for k in rest if getattr(a, k) != getattr(b, k)}
    return out


def test_settings_vary_one_factor_at_a_time():
    cfg = fidelity.paper()
    base = cfg.base
    assert base.trajectory.via_counts == (1,) and base.labels == data.LABELS_V1
    assert (base.n_train, base.n_eval) == (100_000, 10_000)  # the paper's sizes
    allowed = {
        "via": {"trajectory.via_counts"},
        "beta": {f"labels.beta_{n}" for n in data.LABELER_NAMES},
        "box": {"trajectory.via_low", "trajectory.via_high"},
        "timing": {"trajectory.timing"},
    }
    settings = fidelity.settings(cfg)
    assert len({s.name for s in settings}) == len(settings)
    assert {s.factor for s in settings} == set(fidelity.FACTORS)
    counts = [s.data.trajectory.via_counts for s in settings if s.factor == "via"]
    assert counts == [(0,), (1,), (2,), (3,), (1, 2, 3), (3, 4, 5)]
    x4_data = next(s for s in settings if s.name == "beta=x4").data
    for s in settings:
        if s.factor == "defaults":  # the second stage varies one choice from the defaults
            allowed_here = {"labels.beta_nikolaidis", "trajectory.via_low", "trajectory.via_high"}
            assert len(_differences(x4_data, s.data)) <= 2, s.name
            assert _differences(x4_data, s.data) <= allowed_here, s.name
            continue
        assert _differences(base, s.data) <= allowed[s.factor], s.name
        assert s.trials == (cfg.key_trials if s.name in fidelity.KEY_SETTINGS else cfg.trials)
    x4 = next(s for s in settings if s.name == "beta=x4").data.labels
    assert (x4.beta_dragan, x4.beta_nikolaidis, x4.beta_effdist, x4.beta_fastapp) == (
        20.0,
        30.0,
        20.0,
        20.0,
    )
    # The four settings equal to the base share one run, with the group's largest trial count.
    owner = fidelity.unique_runs(settings)
    shared = {n for n in owner if owner[n].name == "via=1"}
    assert shared == {"via=1", "beta=x1", "box=spec", "timing=arc"}
    assert owner["via=1"].trials == cfg.key_trials
    assert owner["default"].name == "beta=x4"  # the defaults are the β×4 setting's run
    nik = [s.data.labels for s in settings if s.name.startswith("default+nik")]
    assert [(la.beta_nikolaidis, la.beta_dragan) for la in nik] == [(60.0, 20.0), (120.0, 20.0)]
    assert len({o.name for o in owner.values()}) == len(settings) - 4


def test_the_chosen_defaults_are_an_ablation_setting():
    """The default distribution is the second stage's table-box setting: one via point in
    the table box, arc length, β ×4."""
    named = {s.name: s.data for s in fidelity.settings(fidelity.paper())}
    assert named["default+box=tight"] == data.paper()
    assert named["beta=x4"] != data.paper()  # the first stage's pick, in the SPEC's box
    v1 = data.with_distribution(data.paper(), "spec_v1")
    assert v1.trajectory.via_counts == (3, 4, 5) and v1.labels == data.LABELS_V1
    assert (v1.trajectory.via_low, v1.trajectory.via_high) == trajectories.SPEC_VIA_BOX
    with pytest.raises(ValueError, match="distribution"):
        data.with_distribution(data.paper(), "v0")


@pytest.mark.slow
def test_fidelity_run_resumes_and_reports(cache, tmp_path):  # noqa: F811
    cfg = dataclasses.replace(fidelity.tiny(), labelers=("effdist",), methods=("slotv",))
    out = tmp_path / "fid"
    doc = fidelity.run(cfg, out, only=["beta=x4"], cache=cache, progress=False)
    rows = {r["name"]: r for r in doc["settings"]}
    # Only the settings that ran are collected ("default" is the β×4 run, shared).
    assert set(rows) == {"beta=x4", "default"}
    row = rows["beta=x4"]
    assert len(row["cells"]) == cfg.trials * len(TEST_SPLITS)
    stats = row["label_stats"]
    assert set(stats["splits"]) == set(TEST_SPLITS)
    for lab in data.LABELER_NAMES:
        assert 0.0 <= stats["mean"][lab]["entropy_ratio"] <= 1.0
        assert 0.0 <= stats["mean"][lab]["target_agreement"] <= 1.0
    before = json.loads((out / "beta=x4" / "results.json").read_text())
    again = fidelity.run(cfg, out, only=["beta=x4"], cache=cache, progress=False)
    after = json.loads((out / "beta=x4" / "results.json").read_text())
    assert after["cells"] == before["cells"]  # resumed: nothing retrained
    assert len(after["timing"]["cells"]) == len(before["timing"]["cells"])
    assert again["settings"][0]["summary"] == row["summary"]
    with pytest.raises(ValueError, match="unknown"):
        fidelity.run(cfg, out, only=["via=7"], cache=cache, progress=False)
    # An earlier results.json supplies the runs this directory lacks, never the ones it has.
    earlier = {"settings": [{**row, "run": "via=0", "name": "via=0"}, {**row, "cells": []}]}
    merged = {r["name"]: r for r in fidelity.collect(cfg, out, earlier)["settings"]}
    assert set(merged) == {"via=0", "beta=x4", "default"}
    assert merged["via=0"]["cells"] == row["cells"] and merged["beta=x4"]["cells"] == row["cells"]

    md = tmp_path / "doc" / "fidelity.md"
    fidelity.write_report(again, md, command="python -m slotv_jax.experiments.fidelity")
    text = md.read_text()
    assert "×4" in text and "SLOT-V EffDist" in text and "(fidelity.png)" in text
    assert (tmp_path / "doc" / "fidelity.png").stat().st_size > 10_000


def test_table1_merge_joins_runs_and_refuses_mismatches():
    def cell(lab, trial, acc):
        return [
            {"labeler": lab, "method": "slotv", "split": s, "trial": trial, "accuracy": acc}
            for s in TEST_SPLITS
        ]

    def doc(cells, trials=2):
        times = [
            {"labeler": c["labeler"], "method": "slotv", "trial": c["trial"], "total_s": 1.0}
            for c in cells[:: len(TEST_SPLITS)]
        ]
        return {
            "preset": "tiny",
            "config": {"trials": trials, "data_digest": "abc", "train": {"slotv": {}}},
            "environment": {},
            "cells": cells,
            "summary": grid.summarise(cells),
            "timing": {"cells": times, "data_s": 1.0},
        }

    a = doc(cell("dragan", 0, 0.5) + cell("dragan", 1, 0.7) + cell("effdist", 0, 0.9))
    b = doc(cell("dragan", 0, 0.5) + cell("effdist", 1, 0.8), trials=3)
    m = grid.merge([a, b])
    assert len(m["cells"]) == 4 * len(TEST_SPLITS)  # the shared cell counted once
    assert m["config"]["trials"] == 3 and len(m["timing"]["cells"]) == 4
    by = {(s["labeler"], s["split"]): s for s in m["summary"]}
    assert by[("dragan", "train")]["n"] == 2
    assert by[("dragan", "train")]["mean"] == pytest.approx(0.6)
    assert by[("effdist", "train")]["mean"] == pytest.approx(0.85)
    other = copy.deepcopy(b)
    other["config"]["data_digest"] = "xyz"
    with pytest.raises(ValueError, match="another configuration"):
        grid.merge([a, other])
    clash = doc(cell("dragan", 0, 0.6))
    with pytest.raises(ValueError, match="disagree"):
        grid.merge([a, clash])
