"""End to end in a real browser: three participants take a rendered study in headless
Chromium (Playwright), then the answers are exported, imported, trained on and loaded.

Set ``SLOTV_JAX_REQUIRE_BROWSER=1`` (CI does) to fail instead of skip without Chromium.
"""

from __future__ import annotations

import os
import sqlite3
from pathlib import Path

import jax
import numpy as np
import pytest
from study_fixtures import ServerProcess, robot_motions

import slotv_jax
from slotv_jax import study, train_cli
from slotv_jax.study_web import cli
from slotv_jax.study_web.make_stimuli import SceneRenderer
from slotv_jax.study_web.stimuli import cross_specs, write_stimulus_set

CHROMIUM = "/usr/bin/chromium"
ARGS = ["--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]  # fmt: skip


@pytest.fixture(scope="module")
def browser():
    if not Path(CHROMIUM).exists():
        msg = f"no browser at {CHROMIUM} (apt-get install chromium)"
        if os.environ.get("SLOTV_JAX_REQUIRE_BROWSER") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    from playwright.sync_api import sync_playwright  # optional heavy dependency

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """3 motions at τ 0.5 and 1, an attention check and a practice trial; 160x90, 10 fps."""
    out = tmp_path_factory.mktemp("browser") / "stim"
    q, xyz, goals, mask, target = robot_motions(5)
    specs = cross_specs(range(3), taus=(0.5, 1.0), cameras=("observer",), attention=[3],
                        practice=[4])  # fmt: skip
    r = SceneRenderer(size=(160, 90), fps=10, duration=0.6, hold=0.1)
    try:
        write_stimulus_set(out, q=q, xyz=xyz, goals=goals, goal_mask=mask,
                           ids=["r0", "r1", "r2", "check", "practice"], specs=specs, render=r,
                           targets=target, progress=False)  # fmt: skip
    finally:
        r.close()
    return out


def take_part(page, url: str, pid: str, *, reload_at=None, back_at=None) -> tuple[str, list]:
    """Click through the study; returns the completion code and (header, goal, confidence)."""
    page.goto(f"{url}/?PROLIFIC_PID={pid}&STUDY_ID=s1&SESSION_ID={pid}-x")
    page.click("#next")  # consent
    page.click("#next")  # instructions: start
    clicked, n = [], 0
    while True:
        page.wait_for_selector("#still, #code", timeout=20000)
        if page.query_selector("#code"):
            return page.inner_text("#code"), clicked
        header = page.inner_text("h1")
        if n == reload_at:  # a refresh mid-trial: the same trial again
            page.reload()
            page.wait_for_selector("#still", timeout=20000)
            assert page.inner_text("h1") == header
        hot = page.query_selector_all(".hotspot")
        assert len(hot) == 3
        goal = ["A", "B", "C"][n % 3]
        if n % 2:
            page.click(f".hotspot[data-goal={goal}]")  # on the still
        else:
            page.click(f".choices button[data-goal={goal}]")  # on the buttons
        conf = 1 + n % 5
        page.check(f"#conf{conf}")
        page.click("#submit")
        page.wait_for_selector("#submit", state="detached")  # the next page replaced this one
        clicked.append((header, goal, conf))
        if n == back_at:  # the back button: still the next unanswered trial
            page.wait_for_selector("#clip, #code")
            nxt = page.inner_text("h1")
            page.go_back()
            page.wait_for_selector("#clip, #code")
            assert page.inner_text("h1") == nxt
        n += 1


def test_three_people_in_chromium_then_training(browser, rendered, tmp_path):
    db = tmp_path / "study.db"
    server = ServerProcess(rendered, db)
    try:
        results = []
        for i, kw in enumerate(({}, {"reload_at": 2}, {"back_at": 1})):
            ctx = browser.new_context(viewport={"width": 900, "height": 700})
            results.append(take_part(ctx.new_page(), server.url, f"person{i}", **kw))
            ctx.close()
    finally:
        server.stop()
    # every click is stored once, as clicked, with the external ids
    con = sqlite3.connect(db)
    rows = con.execute(
        "SELECT p.external_id, p.session_id, t.position, a.guess, a.confidence, a.response_ms "
        "FROM answers a JOIN trials t ON t.trial = a.trial "
        "JOIN participants p ON p.participant = t.participant ORDER BY p.participant, t.position"
    ).fetchall()
    codes = [r[0] for r in con.execute("SELECT completion_code FROM participants")]
    con.close()
    assert [c for c, _ in results] == codes
    assert len(rows) == 3 * 5  # practice, 3 motions, 1 attention check
    for i, (_, clicked) in enumerate(results):
        mine = [r for r in rows if r[0] == f"person{i}"]
        assert [(r[3], r[4]) for r in mine] == [(g, c) for _, g, c in clicked]
        assert all(r[1] == f"person{i}-x" and 0 <= r[5] < 60000 for r in mine)
    # export -> import -> train -> load_observer
    out = tmp_path / "answers"
    assert cli.main(["export", "--db", str(db), "--out", str(out)]) == 0
    npz = tmp_path / "people.npz"
    assert study.main(["import", "--trajectories", str(out / "trajectories.csv"),
                       "--goals", str(out / "goals.csv"), "--answers", str(out / "answers.csv"),
                       "--out", str(npz)]) == 0  # fmt: skip
    s = study.load_study(npz)
    assert s.n_answers == 3 * 3 and s.conditions == ("observer",)
    ckpt = tmp_path / "ckpt"
    assert train_cli.main(["--study", str(npz), "--method", "slotv", "--out", str(ckpt),
                           "--epochs", "2", "--set", "batch_size=2",
                           "--set", "hidden=16,8"]) == 0  # fmt: skip
    observer = slotv_jax.load_observer(ckpt)
    k = s.trajectory_ids.index("r0")
    p = jax.nn.softmax(observer(s.xyz[k, : s.length[k]], s.goals[k], s.goal_mask[k]))
    p = np.asarray(p)[s.goal_mask[k]]
    assert p.shape == (3,) and np.isclose(p.sum(), 1.0, atol=1e-5) and np.all(p > 0)
