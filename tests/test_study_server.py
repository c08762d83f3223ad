"""The study server's HTTP API through Starlette's test client, its design and its export."""

from __future__ import annotations

import json
import os
import shutil
import sqlite3
from collections import Counter
from pathlib import Path

import httpx
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from starlette.testclient import TestClient
from study_fixtures import ServerProcess, write_dot_set

from slotv_jax import study
from slotv_jax.webstudy import design, export, stimuli
from slotv_jax.webstudy.database import PENDING_SECONDS, SQLiteStorage
from slotv_jax.webstudy.server import COOKIE, LOOPBACK_HOSTS, MAX_BODY, make_app
from slotv_jax.webstudy.service import StudyService

ADMIN = "admin-token-for-tests-0123456789"
CHROMIUM = "/usr/bin/chromium"


@pytest.fixture(scope="module")
def dot_set(tmp_path_factory):
    out = tmp_path_factory.mktemp("dots") / "stim"
    write_dot_set(out)
    return out


@pytest.fixture
def stimdir(dot_set, tmp_path):
    out = tmp_path / "stim"
    shutil.copytree(dot_set, out)
    return out


@pytest.fixture
def server(stimdir, tmp_path):
    service = StudyService(stimdir, SQLiteStorage(tmp_path / "study.db"))
    return make_app(service, ADMIN), service


def client(app, **ids) -> tuple[TestClient, dict]:
    c = TestClient(app)
    r = c.post("/api/start", json={"consent": True, "ids": ids})
    assert r.status_code == 200, r.text
    return c, r.json()


def answer(c, state, guess=None, **kw):
    body = {"position": state["position"], "guess": guess or state["goals"][0],
            "confidence": 3, "response_ms": 850, **kw}  # fmt: skip
    return c.post("/api/answer", json=body)


def finish(c, state):
    while state["stage"] == "trial":
        r = answer(c, state)
        assert r.status_code == 200, r.text
        state = r.json()["state"]
    return state


def test_participant_flow(server, stimdir):
    app, service = server
    c = TestClient(app)
    assert c.get("/api/state").status_code == 401  # no participant yet: the consent page
    texts = c.get("/api/texts").json()
    assert "Consent" in texts["consent"] and texts["confidence"] is True
    assert c.get("/").status_code == 200 and "study.js" in c.get("/").text
    ids = {"PROLIFIC_PID": "5f0c1a2b3c4d5e6f7a8b9c0d", "STUDY_ID": "s1", "SESSION_ID": "x9"}
    r = c.post("/api/start", json={"consent": True, "ids": ids})
    assert r.status_code == 200 and COOKIE in r.cookies
    state = r.json()
    # practice first, then one stimulus of each of the 4 trajectories and 2... attention checks
    assert state["practice"] and state["position"] == 0
    assert c.get(state["clip"]).headers["content-type"] == "video/mp4"
    assert c.get(state["still"]).content[:4] == b"\x89PNG"
    seen = []
    while state["stage"] == "trial":
        seen.append(state)
        assert state["goals"] == ["A", "B", "C"] and len(state["goal_pixels"]) == 3
        state = answer(c, state).json()["state"]
    assert state["stage"] == "done" and len(state["code"]) == 8
    assert [s["position"] for s in seen] == list(range(len(seen)))
    trials = service.storage.trials(1)
    kinds = Counter(t["kind"] for t in trials)
    assert kinds == {"practice": 1, "trial": 4, "attention": 1}  # one check in the set
    trajs = [t["trajectory"] for t in trials]
    assert len(set(trajs)) == len(trajs)  # each trajectory at most once
    p = service.storage.participants()[0]
    assert (p["external_id"], p["study_id"], p["session_id"]) == ("5f0c1a2b3c4d5e6f7a8b9c0d",
                                                                  "s1", "x9")  # fmt: skip
    assert p["finished"] is not None and p["answered"] == 6
    # the same external participant id cannot start again (elsewhere)
    r = TestClient(app).post("/api/start", json={"consent": True, "ids": ids})
    assert r.status_code == 409


def test_resume_after_refresh_and_lost_connection(server):
    app, service = server
    c, state = client(app)
    for _ in range(3):
        state = answer(c, state).json()["state"]
    pos = state["position"]
    # a refresh (GET state again), the back button (the page asks again) or another tab
    # with the same cookie: the same next trial
    assert c.get("/api/state").json()["position"] == pos
    assert service.storage.trials(1)[pos]["shown"] == 1  # one reload of this trial
    c2 = TestClient(app, cookies={COOKIE: c.cookies[COOKIE]})
    assert c2.get("/api/state").json()["position"] == pos
    # a start request from a page that was open before (refreshed consent page) keeps trials
    r = c.post("/api/start", json={"consent": True, "ids": {}})
    assert r.json()["position"] == pos and len(service.storage.participants()) == 1
    assert finish(c2, state)["stage"] == "done"
    assert c.get("/api/state").json()["stage"] == "done"


def test_repeated_submission_is_stored_once(server):
    app, service = server
    c, state = client(app)
    first = answer(c, state, guess="B")
    assert first.status_code == 200 and not first.json()["duplicate"]
    again = answer(c, state, guess="B")
    assert again.status_code == 200 and again.json()["duplicate"]
    other = answer(c, state, guess="C", confidence=5)  # a changed mind after sending
    assert other.status_code == 200 and other.json()["duplicate"]
    rows = service.storage.answers()
    assert len(rows) == 1 and rows[0]["guess"] == "B" and rows[0]["confidence"] == 3
    # answers out of order are refused; the next trial is still the one after the first
    nxt = again.json()["state"]
    skip = {**nxt, "position": nxt["position"] + 1}
    assert answer(c, skip).status_code == 400
    assert c.get("/api/state").json()["position"] == nxt["position"]


def test_a_duplicate_answer_replies_with_the_state_after_it(server):
    """Two identical answers at once: the one whose write comes second is the duplicate,
    and its reply must show the trial after the answered one, as the first's does (it
    showed the answered trial again: its trial list was read before the other's write).
    The interleaving is made deterministic: the storage lets the twin request answer
    between this request's reading of the trials and its own write."""
    app, service = server
    c, state = client(app)
    token = c.cookies.get(COOKIE)
    body = (state["position"], state["goals"][0], 3, 850.0)
    storage, twin = service.storage, []

    class TwinFirst:  # the storage, but the first answer lets the twin's request go first
        def __getattr__(self, name):
            return getattr(storage, name)

        def answer(self, *args):
            if not twin:
                twin.append(None)  # the twin's own write goes straight through
                twin[0] = service.answer_for(token, *body)
            return storage.answer(*args)

    service.storage = TwinFirst()
    r = c.post("/api/answer", json=dict(zip(("position", "guess", "confidence",
                                              "response_ms"), body, strict=True)))  # fmt: skip
    service.storage = storage
    assert r.status_code == 200 and r.json()["duplicate"] and not twin[0]["duplicate"]
    assert twin[0]["state"]["position"] == state["position"] + 1
    assert r.json()["state"] == twin[0]["state"]  # the trial after the answered one
    assert len(storage.answers()) == 1


def test_tokens(server):
    app, service = server
    _, sa = client(app)
    b, sb = client(app)
    anon = TestClient(app)
    fake = TestClient(app, cookies={COOKIE: "x" * 43})
    for c in (anon, fake):
        assert c.get("/api/state").status_code == 401
        assert c.get("/api/media/0/clip").status_code == 401
        assert answer(c, sa).status_code == 401
    # a participant reaches only their own trials: positions index their own list
    n = len(service.storage.trials(1))
    assert b.get(f"/api/media/{n}/clip").status_code == 404
    assert answer(b, {**sb, "position": n}).status_code == 404
    assert b.get("/api/media/3/clip").status_code == 404  # not yet reached
    answer(b, sb)
    assert [r["participant"] for r in service.storage.answers()] == [2]
    # the admin API needs the admin token
    for hdr in ({}, {"Authorization": "Bearer wrong"}, {"Authorization": ADMIN}):
        assert anon.get("/api/admin/progress", headers=hdr).status_code == 401
        assert anon.get("/api/admin/export/answers.csv", headers=hdr).status_code == 401
    ok = {"Authorization": f"Bearer {ADMIN}"}
    prog = anon.get("/api/admin/progress", headers=ok).json()
    assert prog["answers"] == 1 and len(prog["participants"]) == 2
    assert sum(s["answers"] for s in prog["stimuli"]) == 1
    csv_text = anon.get("/api/admin/export/answers.csv", headers=ok).text
    assert csv_text.splitlines()[0].startswith("trajectory,tau,guess,participant,condition")
    assert anon.get("/admin").status_code == 200


def test_a_token_is_checked_whole(server):
    """A token that differs from a real one in its last characters only, or its first, is
    no token (a comparison of a prefix would let it in); nor is a prefix of the admin token
    (``Bearer a``), a longer one or an empty one."""
    app, service = server
    c, state = client(app)
    token = c.cookies[COOKIE]

    def other(ch: str) -> str:
        return "B" if ch == "A" else "A"

    forged = [token[:-1] + other(token[-1]), token[:-6] + "".join(map(other, token[-6:])),
              other(token[0]) + token[1:], token[:16], token + "A"]  # fmt: skip
    for f in forged:
        assert f != token
        fc = TestClient(app, cookies={COOKIE: f})
        assert fc.get("/api/state").status_code == 401, f
        assert fc.get(state["clip"]).status_code == 401
        assert answer(fc, state).status_code == 401
        assert fc.post("/api/resume", json={"token": f}).status_code == 401
    assert service.storage.answers() == []
    assert TestClient(app, cookies={COOKIE: token}).get("/api/state").status_code == 200
    # the admin token likewise, and neither a prefix of it (one letter, all but the last),
    # nor it and more, nor an empty one is any admin token
    admin_forged = [ADMIN[:-1] + other(ADMIN[-1]), other(ADMIN[0]) + ADMIN[1:], ADMIN[0],
                    ADMIN[:16], ADMIN[:-1], ADMIN + "0", ADMIN + ADMIN, ""]  # fmt: skip
    for f in admin_forged:
        assert f != ADMIN
        r = TestClient(app).get("/api/admin/progress", headers={"Authorization": f"Bearer {f}"})
        assert r.status_code == 401, f
    for header in ({}, {"Authorization": ADMIN}, {"Authorization": f"Basic {ADMIN}"}):
        assert TestClient(app).get("/api/admin/progress", headers=header).status_code == 401
    ok = {"Authorization": f"Bearer {ADMIN}"}
    assert TestClient(app).get("/api/admin/progress", headers=ok).status_code == 200


def test_lost_start_resumes_until_the_first_answer(server):
    """A start whose reply was lost (a killed server, the network, a cleared cookie) is
    the same request again: it resumes the same participant (one row, the same trials)
    while they have no answer; from their first answer on, only their token does."""
    app, service = server
    ids = {"PROLIFIC_PID": "lost1", "STUDY_ID": "s1"}
    first = TestClient(app).post("/api/start", json={"consent": True, "ids": ids})
    assert first.status_code == 200
    lost = first.cookies[COOKIE]  # the reply that never arrived
    trials = service.storage.trials(1)
    c, state = client(app, **ids)
    assert state == first.json() and c.cookies[COOKIE] != lost
    people = service.storage.participants()
    assert len(people) == 1 and people[0]["starts"] == 2 and service.storage.trials(1) == trials
    assert TestClient(app, cookies={COOKIE: lost}).get("/api/state").status_code == 401
    state = answer(c, state).json()["state"]
    # an answer is stored: a start with the id but not the token is refused, saying what to do
    for _ in range(2):
        r = TestClient(app).post("/api/start", json={"consent": True, "ids": ids})
        assert r.status_code == 409 and "researcher" in r.json()["error"]
    # ... the participant's own browser (a refresh, a second tab) goes on at the next trial
    r = c.post("/api/start", json={"consent": True, "ids": ids})
    assert r.status_code == 200 and r.json()["position"] == state["position"] == 1
    assert c.get("/api/state").json()["position"] == 1
    assert len(service.storage.participants()) == 1
    assert [a["participant"] for a in service.storage.answers()] == [1]
    # the same id in another study is another participant; a cookie does not carry over to
    # another person's id on a shared computer
    assert client(app, PROLIFIC_PID="lost1", STUDY_ID="s2")[1]["position"] == 0
    r = c.post("/api/start", json={"consent": True, "ids": {"PROLIFIC_PID": "next"}})
    assert r.status_code == 200 and r.json()["position"] == 0
    people = service.storage.participants()
    assert [(p["external_id"], p["study_id"], p["answered"]) for p in people] == [
        ("lost1", "s1", 1), ("lost1", "s2", 0), ("next", None, 0)]  # fmt: skip


def test_unanswered_starts_hold_trials_briefly(server):
    """A participant without an answer (a lost start nobody resumed) holds their trials
    for the balance only PENDING_SECONDS after last seen; one who answered, an hour."""
    _, service = server
    db = service.storage
    seen: list[dict] = []

    def plan(stims, counts, seed):
        seen.append(dict(counts))
        return [s.key for s in stims if s.kind == "trial"][:2]

    def age(pid: int, seconds: float) -> None:
        con = sqlite3.connect(db.path)
        con.execute("UPDATE participants SET last_seen = last_seen - ? WHERE participant = ?",
                    (seconds, pid))  # fmt: skip
        con.commit()
        con.close()

    for p in (1, 2):
        assert db.create_participant(f"h{p}", {}, plan, p, "C") == p
    k0, k1 = db.trials(1)[0]["stimulus"], db.trials(1)[1]["stimulus"]
    assert seen == [{}, {k0: 1, k1: 1}]
    db.answer(2, 0, "A", None, 100.0)
    age(1, PENDING_SECONDS + 60)  # no answer, 11 minutes ago: released
    age(2, PENDING_SECONDS + 60)  # answered 11 minutes ago: still holds both trials
    db.create_participant("h3", {}, plan, 3, "C")
    assert seen[-1] == {k0: 1, k1: 1}
    age(2, 3600.0)  # answered over an hour ago: only the answer counts
    age(3, PENDING_SECONDS + 60)
    db.create_participant("h4", {}, plan, 4, "C")
    assert seen[-1] == {k0: 1}
    # a resumed start re-uses its row and trials: no new draw, no second row
    db.create_participant("h5", {"external_id": "e"}, plan, 5, "C")
    n, trials = len(seen), db.trials(5)
    assert db.create_participant("h6", {"external_id": "e"}, plan, 6, "C", resume=True) == 5
    assert len(seen) == n and db.trials(5) == trials and db.participant("h5") is None
    assert db.participant("h6")["starts"] == 2 and len(db.participants()) == 5


def test_a_database_of_schema_1_is_brought_up_to_date(server):
    """A study database written before ``participants.starts`` opens with its rows."""
    app, service = server
    client(app, PROLIFIC_PID="before")
    path = service.storage.path
    con = sqlite3.connect(path)
    con.execute("ALTER TABLE participants DROP COLUMN starts")
    con.execute("UPDATE meta SET value = '1' WHERE key = 'schema'")
    con.commit()
    con.close()
    db = SQLiteStorage(path)
    assert [(p["external_id"], p["starts"]) for p in db.participants()] == [("before", 1)]
    con = sqlite3.connect(path)
    assert con.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone() == ("2",)
    con.execute("UPDATE meta SET value = '9' WHERE key = 'schema'")
    con.commit()
    con.close()
    with pytest.raises(ValueError, match="schema version 9, expected 2"):
        SQLiteStorage(path)


def test_resume_link(server):
    """The researcher's way on for someone who answered and then lost their cookie (another
    browser): a link with a new token; the old one stops working."""
    app, service = server
    c, state = client(app, PROLIFIC_PID="moved")
    state = answer(c, state).json()["state"]
    anon, ok = TestClient(app), {"Authorization": f"Bearer {ADMIN}"}
    assert anon.post("/api/admin/resume-link/1").status_code == 401
    assert anon.post("/api/admin/resume-link/9", headers=ok).status_code == 404
    url = anon.post("/api/admin/resume-link/1", headers=ok).json()["url"]
    assert url.startswith("http://testserver/#resume=")
    other = TestClient(app)  # the other browser opens the link
    r = other.post("/api/resume", json={"token": url.split("#resume=")[1]})
    assert r.status_code == 200 and r.json()["position"] == state["position"]
    assert c.get("/api/state").status_code == 401  # the token it had stops working
    assert finish(other, r.json())["stage"] == "done"
    assert len(service.storage.answers()) == 6
    assert service.storage.participants()[0]["starts"] == 2
    for body, code in (({"token": "x" * 43}, 401), ({"token": 5}, 400), ({}, 400),
                       ({"token": "x" * 500}, 400), ({"token": "x", "t": 1}, 400)):  # fmt: skip
        r = TestClient(app).post("/api/resume", json=body)
        assert r.status_code == code and set(r.json()) == {"error"}, body


JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=6),
    lambda inner: st.lists(inner, max_size=3)
    | st.dictionaries(st.sampled_from(["position", "guess", "confidence", "response_ms",
                                       "consent", "ids", "token", "PROLIFIC_PID", "x"]),
                      inner, max_size=5),
    max_leaves=12,
)  # fmt: skip


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
@given(body=JSON | st.binary(max_size=64), route=st.sampled_from(["start", "answer", "resume"]))
def test_any_body_is_answered_without_a_server_error(server, body, route):
    """Whatever the body, the answer is a 200 or a 4xx with ``{"error": ...}``."""
    app, _ = server
    c = TestClient(app, cookies={COOKIE: "x" * 43})
    if isinstance(body, bytes):
        r = c.post(f"/api/{route}", content=body, headers={"content-type": "application/json"})
    else:
        r = c.post(f"/api/{route}", json=body)
    assert r.status_code == 200 or 400 <= r.status_code < 500, (body, r.status_code)
    assert r.status_code == 200 or set(r.json()) == {"error"}


def test_host_header_is_checked(stimdir, tmp_path):
    """A server on the loopback answers only the loopback names: a page of another site
    that rebinds its name to 127.0.0.1 is refused (DNS rebinding), before any route."""
    service = StudyService(stimdir, SQLiteStorage(tmp_path / "study.db"))
    app = make_app(service, ADMIN, LOOPBACK_HOSTS)
    for host in ("127.0.0.1", "localhost:8000"):
        assert TestClient(app, base_url=f"http://{host}").get("/api/texts").status_code == 200
    assert TestClient(app, base_url="http://[::1]:8000").get("/api/texts").status_code == 200
    evil = TestClient(app, base_url="http://evil.example")
    r = evil.post("/api/start", json={"consent": True, "ids": {}})
    assert r.status_code == 400 and "content-security-policy" in r.headers
    assert set(r.json()) == {"error"} and "Host" in r.json()["error"]  # JSON like every error
    assert service.storage.answers() == [] and evil.get("/api/texts").status_code == 400
    for host in ("127.0.0.1.evil.example", "localhost:80:80", "[::1", "", "local host"):
        r = TestClient(app).get("/api/texts", headers={"host": host})
        assert r.status_code == 400 and set(r.json()) == {"error"}, host
    for bad in ("localhost", ("*evil.example",), ("a.*.org",), ("",)):
        with pytest.raises(ValueError, match="allowed_hosts"):
            make_app(service, ADMIN, bad)


def test_traversal_attempts(server, stimdir, tmp_path):
    app, _ = server
    c, _ = client(app)
    (tmp_path / "secret.txt").write_text("SECRET")
    probes = [
        "/static/../manifest.json", "/static/%2e%2e/%2e%2e/secret.txt", "/static/..%2fstudy.db",
        "/api/media/0/..%2f..%2fmanifest.json", "/api/media/0/manifest", "/api/media/-1/clip",
        "/api/media/0/clip/../../../secret.txt", "/api/media/%2e%2e/clip",
        "/stim/manifest.json", "/manifest.json", "/api/admin/export/..%2fsecret.csv",
        "/static/%2fetc%2fpasswd", "//etc/passwd",
    ]  # fmt: skip
    for path in probes:
        r = c.get(path)
        assert r.status_code in (400, 401, 404), (path, r.status_code)
        assert b"SECRET" not in r.content and b"stimuli" not in r.content, path
    # a manifest that points outside its folder is refused when the set is loaded
    m = json.loads((stimdir / "manifest.json").read_text())
    m["stimuli"][0]["clip"] = "../secret.txt"
    (stimdir / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(ValueError, match="relative path inside"):
        stimuli.load_stimulus_set(stimdir)
    m["stimuli"][0]["clip"] = "/etc/passwd"
    (stimdir / "manifest.json").write_text(json.dumps(m))
    with pytest.raises(ValueError, match="relative path inside"):
        stimuli.load_stimulus_set(stimdir)


def test_malformed_bodies(server):
    app, service = server
    c, state = client(app)
    pos = state["position"]
    good = {"position": pos, "guess": "A", "confidence": None, "response_ms": 500}
    bad = [
        ({"content": b"not json"}, 400), ({"content": b"[1, 2]"}, 400),
        ({"content": b"\xff\xfe"}, 400), ({"content": b"x" * (MAX_BODY + 1)}, 413),
        ({"json": {**good, "position": str(pos)}}, 400),
        ({"json": {**good, "position": True}}, 400),
        ({"json": {**good, "guess": "Z"}}, 400), ({"json": {**good, "guess": 1}}, 400),
        ({"json": {**good, "guess": "A" * 5000}}, 413), ({"json": {**good, "confidence": 7}}, 400),
        ({"json": {**good, "confidence": 2.5}}, 400), ({"json": {**good, "response_ms": -1}}, 400),
        ({"json": {**good, "response_ms": "fast"}}, 400), ({"json": {**good, "extra": 1}}, 400),
        ({"json": {k: v for k, v in good.items() if k != "guess"}}, 400),
        ({"content": b'{"position": 0, "guess": "A", "response_ms": NaN}'}, 400),
        ({"content": b'{"position": 0, "guess": "A", "response_ms": 1e999}'}, 400),
    ]  # fmt: skip
    for kw, code in bad:
        headers = {"content-type": "application/json"} if "content" in kw else {}
        r = c.post("/api/answer", headers=headers, **kw)
        assert r.status_code == code, (kw, r.status_code, r.text)
        assert set(r.json()) == {"error"} and "Traceback" not in r.text
    r = c.post("/api/answer", content=json.dumps(good), headers={"content-type": "text/plain"})
    assert r.status_code == 415
    assert c.post("/api/start", json={"consent": False}).status_code == 400
    assert service.storage.answers() == []
    assert c.post("/api/answer", json=good).status_code == 200


def post_raw(c: TestClient, route: str, body: bytes):
    return c.post(route, content=body, headers={"content-type": "application/json"})


def test_deeply_nested_bodies_are_refused(server):
    """2,000 nested lists in 4 kB: a 400 with ``{"error": ...}``, not a RecursionError
    and a 500."""
    app, service = server
    c, state = client(app)
    deep = [
        b'{"position":' + b"[" * 2000 + b"]" * 2000 + b"}",
        b"[" * 4000,
        b'{"":[' * 560 + b"1" + b"]}" * 560,  # objects and lists, 1,120 levels
    ]
    for route in ("/api/answer", "/api/start", "/api/resume"):
        for body in deep:
            r = post_raw(c, route, body)
            assert r.status_code == 400 and set(r.json()) == {"error"}, (route, body[:20])
    assert service.storage.answers() == [] and answer(c, state).status_code == 200


def test_duplicate_fields_are_refused(server):
    """A field given twice is refused, whichever of its values json would have kept."""
    app, service = server
    c, _ = client(app)
    bodies = {
        "/api/answer": [
            b'{"position": 0, "guess": "A", "guess": "B", "response_ms": 5}',
            b'{"position": 0, "guess": "A", "response_ms": 5, "response_ms": 5}',
        ],
        "/api/start": [
            b'{"consent": true, "consent": false}',
            b'{"consent": true, "ids": {"PROLIFIC_PID": "a", "PROLIFIC_PID": "b"}}',
        ],
    }
    for route, docs in bodies.items():
        for body in docs:
            r = post_raw(TestClient(app, cookies=c.cookies), route, body)
            assert r.status_code == 400 and "twice" in r.json()["error"], body
    assert service.storage.answers() == [] and len(service.storage.participants()) == 1


def test_external_ids_are_ascii(server):
    """External ids: at most 128 ASCII letters, digits and -_.:@, as the error says
    (``str.isalnum`` takes the letters and digits of every script)."""
    app, service = server
    for pid in ("<script>", "p\u0663", "caf\u00e9", "\uff11\uff12", "\u00b2", "a b", "x" * 129):
        r = TestClient(app).post("/api/start", json={"consent": True, "ids": {
            "PROLIFIC_PID": pid}})  # fmt: skip
        assert r.status_code == 400 and "ASCII" in r.json()["error"], pid
    assert service.storage.participants() == []
    assert client(app, PROLIFIC_PID="Ab-1_2.x:y@z" + "9" * 116)[1]["stage"] == "trial"


def test_errors_show_no_internals(server):
    app, service = server
    c, state = client(app)

    def broken(*a, **k):
        raise RuntimeError("secret internal detail /home/x/study.db")

    service.storage.answer = broken
    c = TestClient(app, raise_server_exceptions=False, cookies={COOKIE: c.cookies[COOKIE]})
    r = answer(c, state)
    assert r.status_code == 500 and r.json() == {"error": "internal error"}
    r = c.get("/no/such/page")
    assert r.status_code == 404 and "Traceback" not in r.text
    hdr = c.get("/api/state").headers
    assert "default-src 'self'" in hdr["content-security-policy"]
    assert hdr["x-content-type-options"] == "nosniff" and hdr["cache-control"] == "no-store"


def test_balanced_assignment_and_new_round(server, stimdir, caplog):
    app, service = server
    for _ in range(6):
        finish(*client(app))
    per = Counter((r["trajectory"], r["tau"]) for r in service.storage.answers()
                  if r["kind"] == "trial")  # fmt: skip
    assert len(per) == 8 and set(per.values()) == {3}  # 4 motions x 2 taus, 6 people each
    # a new round appears while the server runs: the next participant gets it
    write_dot_set(stimdir / "round-1", n=2, taus=(0.7,), round_=1, first=10)
    client(app)
    trials = service.storage.trials(7)
    assert {t["round"] for t in trials} == {1} and len(trials) == 4
    assert sorted(t["trajectory"] for t in trials if t["kind"] == "trial") == ["m10", "m11"]
    # an earlier participant is unaffected, and a changed round is refused
    assert service.storage.trials(1)[0]["round"] == 0
    write_dot_set(stimdir / "round-2", n=1, taus=(0.7,), round_=2, first=0)  # m0 differs
    client(app)  # the study goes on with round 1 and says why round 2 is left out
    assert {t["round"] for t in service.storage.trials(8)} == {1}
    assert "round 2 left out" in caplog.text and "differs" in caplog.text
    # ... and a server started on it refuses to start
    with pytest.raises(ValueError, match="differs"):
        StudyService(stimdir, service.storage)


@settings(max_examples=40, deadline=None)
@given(
    n_traj=st.integers(1, 6),
    per_traj=st.integers(1, 3),
    k=st.one_of(st.none(), st.integers(1, 6)),
    people=st.integers(1, 12),
    seed=st.integers(0, 2**31),
)
def test_design_balances_answers(n_traj, per_traj, k, people, seed):
    """Within a trajectory the stimuli's counts differ by at most one, and so do the
    trajectories' counts; no participant sees a trajectory twice; checks never first."""
    stims = [design.Stimulus(t * per_traj + j, f"t{t}", "trial")
             for t in range(n_traj) for j in range(per_traj)]  # fmt: skip
    stims.append(design.Stimulus(100, "check", "attention"))
    counts: Counter = Counter()
    for p in range(people):
        plan = design.plan_trials(stims, counts, k=k, n_attention=1, seed=seed + p)
        main = [s for s in plan if s != 100]
        assert len(main) == (n_traj if k is None else min(k, n_traj))
        assert plan[0] != 100  # never an attention check first
        assert len({s // per_traj for s in main}) == len(main)
        counts.update(plan)
    for t in range(n_traj):
        c = [counts[t * per_traj + j] for j in range(per_traj)]
        assert max(c) - min(c) <= 1
    tc = [sum(counts[t * per_traj + j] for j in range(per_traj)) for t in range(n_traj)]
    assert max(tc) - min(tc) <= 1


def test_export_imports_unchanged(server, tmp_path):
    app, service = server
    for pid in ("p-a", "p-b", "p-c"):
        finish(*client(app, PROLIFIC_PID=pid))
    n = export.export_tables(service.storage, tmp_path / "out")
    assert n == {"answers": 12, "trajectories": 4, "participants": 3}
    out = tmp_path / "out"
    s, report = study.read_tables(out / "trajectories.csv", out / "goals.csv", out / "answers.csv")
    assert report.answer_rows == 12 and report.participants == 3
    assert s.counts.sum() == 12 and s.conditions == ("observer",)
    # every answer lands on its goal's slot, at its τ, for its trajectory
    rows = [r for r in service.storage.answers() if r["kind"] == "trial"]
    for r in rows:
        k = s.trajectory_ids.index(r["trajectory"])
        a = [i for i in range(s.n_rows) if s.answer_trajectory[i] == k
             and np.isclose(s.answer_tau[i], r["tau"])]  # fmt: skip
        assert len(a) == 1
        assert s.counts[a[0], list(s.goal_names[k]).index(r["guess"])] >= 1
    header = (out / "answers.csv").read_text().splitlines()[0].split(",")
    assert header == list(export.ANSWER_COLUMNS)
    people = (out / "participants.csv").read_text().splitlines()
    assert len(people) == 4 and "p-a" in people[1]


@pytest.fixture(scope="module")
def browser():
    if not Path(CHROMIUM).exists():
        msg = f"no browser at {CHROMIUM} (apt-get install chromium)"
        if os.environ.get("SLOTV_JAX_REQUIRE_BROWSER") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    from playwright.sync_api import sync_playwright  # optional heavy dependency

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox", "--disable-gpu"])
        yield b
        b.close()


def test_page_resumes_a_lost_start_and_says_what_to_do(browser, stimdir, tmp_path):
    """The participant page in Chromium: the same id opened in a second browser before any
    answer resumes (the first one's answer then finds its token replaced and starts again,
    resuming); after an answer the second browser is told to ask the researcher, whose
    link continues the study there; a second tab goes on where the participant is."""
    server = ServerProcess(stimdir, tmp_path / "study.db")
    url = f"{server.url}/?PROLIFIC_PID=page1&STUDY_ID=s1"

    def start(page):
        page.click("#next")  # consent
        page.click("#next")  # instructions: start

    def trial(page) -> str:
        page.wait_for_selector("#still")
        return page.inner_text("h1")

    def answer_on(page):
        page.click(".choices button[data-goal=A]")
        page.click("#submit")
        page.wait_for_selector("#submit", state="detached")

    try:
        a, b = (browser.new_context().new_page() for _ in range(2))
        for page in (a, b):
            page.set_default_timeout(60_000)
            page.goto(url)
            start(page)
            assert trial(page) == "Practice trial"
        answer_on(a)  # b's start replaced a's token: a starts again and resumes
        start(a)
        assert trial(a) == "Practice trial"
        answer_on(a)
        assert trial(a) == "Video 1 of 5"
        tab = a.context.new_page()
        tab.goto(url)
        assert trial(tab) == "Video 1 of 5"
        b.reload()  # its token was replaced, and the participant has answered
        start(b)
        assert "ask the researcher" in b.inner_text("#message")
        auth = {"Authorization": f"Bearer {server.admin_token}"}
        link = httpx.post(f"{server.url}/api/admin/resume-link/1", headers=auth).json()["url"]
        b.goto(link)
        assert trial(b) == "Video 1 of 5" and "resume" not in b.url
        answer_on(b)
        assert trial(b) == "Video 2 of 5"
    finally:
        server.stop()
    con = sqlite3.connect(tmp_path / "study.db")
    assert con.execute("SELECT COUNT(*), SUM(starts) FROM participants").fetchone() == (1, 4)
    assert con.execute("SELECT COUNT(*) FROM answers").fetchone() == (2,)
    con.close()
