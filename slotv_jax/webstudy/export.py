"""Export a study database as tables that ``python -m slotv_jax.study import`` reads unchanged.

``python -m slotv_jax.study export --db FILE --out DIR`` writes four CSV files:

- ``answers.csv``: ``trajectory, tau, guess, participant, condition, confidence,
  response_ms, stimulus, round, position, reloads, answered`` — one row per answer of a main
  trial (practice trials and attention checks are left out); ``condition`` is the
  camera, ``participant`` an anonymous ``p<number>``, ``response_ms`` the time from the
  end of the clip to the click, ``position`` the trial's place in the participant's
  random order, ``reloads`` how often the page was reloaded on this trial (each reload
  plays the clip again), ``answered`` the UTC time it was stored;
- ``trajectories.csv`` and ``goals.csv``: the answered trajectories and their goals
  (``trajectory, t, x, y, z`` and ``trajectory, goal, x, y, z``);
- ``participants.csv``: ``participant, external_id, study_id, session_id, round,
  started, finished, trials, answered, attention_checks, attention_passed,
  completion_code`` — to pay people and to check attention.

``drop_failed_attention=True`` (``--drop-failed-attention``) leaves out the answers of
participants who failed an attention check.

>>> export_tables(SQLiteStorage("study.db"), "answers/")  # doctest: +SKIP
{'answers': 120, 'trajectories': 10, 'participants': 12}
"""

from __future__ import annotations

import csv
import datetime
import io
from pathlib import Path

from slotv_jax.core.fileio import write_text
from slotv_jax.webstudy.database import Storage
from slotv_jax.webstudy.stimuli import goal_rows, trajectory_rows

ANSWER_COLUMNS = ("trajectory", "tau", "guess", "participant", "condition", "confidence",
                  "response_ms", "stimulus", "round", "position", "reloads",
                  "answered")  # fmt: skip
PARTICIPANT_COLUMNS = ("participant", "external_id", "study_id", "session_id", "round",
                       "started", "finished", "trials", "answered", "attention_checks",
                       "attention_passed", "completion_code")  # fmt: skip
TABLES = ("answers", "trajectories", "goals", "participants")


def _iso(t: float | None) -> str:
    if t is None:
        return ""
    return datetime.datetime.fromtimestamp(t, datetime.UTC).isoformat(timespec="milliseconds")


def _csv(header, rows) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    w.writerows(rows)
    return buf.getvalue()


def _answer_row(a: dict) -> list:
    conf = "" if a["confidence"] is None else a["confidence"]
    return [a["trajectory"], repr(float(a["tau"])), a["guess"], f"p{a['participant']}",
            a["camera"], conf, f"{a['response_ms']:.0f}", a["stimulus"], a["round"],
            a["position"], a["shown"], _iso(a["answered"])]  # fmt: skip


def _participant_row(p: dict) -> list:
    return [f"p{p['participant']}", p["external_id"] or "", p["study_id"] or "",
            p["session_id"] or "", p["round"], _iso(p["created"]), _iso(p["finished"]),
            p["trials"], p["answered"], p["attention_answered"] or 0,
            p["attention_passed"] or 0, p["completion_code"]]  # fmt: skip


def tables(storage: Storage, *, drop_failed_attention: bool = False) -> dict[str, str]:
    """The four exported tables as CSV text, by name (see the module docstring)."""
    people = storage.participants()
    failed = {
        p["participant"]
        for p in people
        if (p["attention_passed"] or 0) < (p["attention_answered"] or 0)
    }
    answers = [
        a
        for a in storage.answers()
        if a["kind"] == "trial" and not (drop_failed_attention and a["participant"] in failed)
    ]
    traj, goals = storage.trajectory_tables()
    used = list(dict.fromkeys(a["trajectory"] for a in answers))
    return {
        "answers": _csv(ANSWER_COLUMNS, [_answer_row(a) for a in answers]),
        "trajectories": _csv(
            ("trajectory", "t", "x", "y", "z"), trajectory_rows({k: traj[k] for k in used})
        ),
        "goals": _csv(
            ("trajectory", "goal", "x", "y", "z"), goal_rows({k: goals[k] for k in used})
        ),
        "participants": _csv(PARTICIPANT_COLUMNS, [_participant_row(p) for p in people]),
    }


def export_tables(
    storage: Storage, out: str | Path, *, drop_failed_attention: bool = False
) -> dict[str, int]:
    """Write ``answers.csv``, ``trajectories.csv``, ``goals.csv``, ``participants.csv``.

    Each file is written to a temporary name and renamed. Returns the rows written.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tabs = tables(storage, drop_failed_attention=drop_failed_attention)
    for name, text in tabs.items():
        write_text(out / f"{name}.csv", text)
    rows = {k: list(csv.reader(io.StringIO(v)))[1:] for k, v in tabs.items()}
    return {
        "answers": len(rows["answers"]),
        "trajectories": len({r[0] for r in rows["trajectories"]}),
        "participants": len(rows["participants"]),
    }
