"""The study as plain functions: participants, their trials, answers, media, progress.

The web layer (:mod:`slotv_jax.webstudy.server`) validates requests and calls these;
nothing here knows about HTTP. A participant is identified by a random token (256 bits,
``secrets.token_urlsafe``); storage keeps only its SHA-256, so a copy of the database
does not let anyone answer in a participant's name. A token is checked whole: storage
finds the row by the token's hash and :func:`hmac.compare_digest` compares the full hash
again in constant time (a backend that matched loosely would still not let a near miss in).

Starting and resuming (the threat model is in the README, "Running a study with people"):
the external ids (``PROLIFIC_PID`` ...) come from the study URL and are not secret. A
start for an external id that has no answer stored yet is *resumable*: it re-issues that
participant (same row, same trials) to a new token, so someone whose start reply was lost
(a killed server, the network, another browser, cleared cookies) goes on where they
were. Once an answer is stored, only the participant's token reaches their trials: a
start with that id and without the token is refused (:class:`Conflict`, 409) with what to
do, and the researcher can issue a resume link (:meth:`StudyService.reissue`).

A participant's *state* is what their page shows next (jsPsych's timeline, one trial at
a time): ``{"stage": "trial", ...}`` with the next unanswered trial, or
``{"stage": "done", "code": ...}``. A refresh, the back button or a lost connection asks
for the state again and lands on the same trial.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import secrets
import threading
from pathlib import Path

from slotv_jax.webstudy import design, stimuli
from slotv_jax.webstudy.database import Conflict, Storage, unanswered

MAX_RESPONSE_MS = 3_600_000.0  # one hour: longer response times are rejected
CONFIDENCE = (1, 5)  # the confidence scale (1: a guess, 5: sure)
log = logging.getLogger("slotv_jax.study")
MAX_TOKEN = 100  # characters of a participant token (they have 43)
ALREADY_ANSWERED = (  # shown as it is on the participant's page
    "This participant id has already answered in another browser or session. Please go on "
    "in the browser where you started, or ask the researcher for a link to continue."
)
ID_PARAMS = {  # external ids taken from the study URL (Prolific, MTurk, plain names)
    "external_id": ("PROLIFIC_PID", "workerId", "participant"),
    "study_id": ("STUDY_ID", "hitId", "study"),
    "session_id": ("SESSION_ID", "assignmentId", "session"),
}


class Invalid(ValueError):
    """The request is malformed or breaks a rule of the study (answered as 400)."""


class Unauthorized(Exception):
    """No participant holds the request's token (answered as 401)."""


class Forbidden(Exception):
    """The request asks for something that is not the participant's."""


def token_hash(token: str) -> str:
    """SHA-256 (hex) of a participant token: what storage keeps."""
    return hashlib.sha256(token.encode()).hexdigest()


class StudyService:
    """One study: a stimulus folder (rounds), its settings and a storage backend."""

    def __init__(self, stimdir: str | Path, storage: Storage):
        self.stimdir = Path(stimdir)
        self.storage = storage
        self.settings = stimuli.read_settings(self.stimdir)
        self.sets: dict[int, stimuli.StimulusSet] = {}
        self._by_id: dict[tuple[int, str], dict] = {}
        self._lock = threading.Lock()
        self.refresh(strict=True)
        if not self.sets:
            raise ValueError(f"--stimuli {self.stimdir}: no stimulus set ({stimuli.MANIFEST})")

    # ----------------------------------------------------------------- rounds

    def refresh(self, *, strict: bool = False) -> list[int]:
        """Load rounds that appeared in the folder since the last call; their numbers.

        A round already in storage must have the same manifest as on disk (a stimulus
        set must not change under the answers given to it). A round that fails its checks
        raises with ``strict`` (at start-up); otherwise it is logged and left out, and the
        study goes on with the rounds it has (it is tried again at the next start).
        """
        with self._lock:
            new = []
            for r in stimuli.find_rounds(self.stimdir):
                if r in self.sets:
                    continue
                try:
                    self._load(r)
                except ValueError as e:
                    if strict:
                        raise
                    log.error("round %d left out: %s", r, e)
                    continue
                new.append(r)
            return new

    def _load(self, r: int) -> None:
        st = stimuli.load_stimulus_set(stimuli.round_dir(self.stimdir, r))
        if st.round != r:
            raise ValueError(
                f"{st.path / stimuli.MANIFEST}: field 'round' is {st.round}, expected {r}"
            )
        if not self.storage.load_round(r, st.manifest, st.trajectories, st.goals):
            if self.storage.manifest(r) != st.manifest:
                raise ValueError(
                    f"{st.path / stimuli.MANIFEST}: round {r} differs from the one "
                    "stored in the database (stimuli must not change mid-study)"
                )
        self.sets[r] = st
        for s in st.manifest["stimuli"]:
            self._by_id[(r, s["id"])] = s

    # ----------------------------------------------------------- participants

    def start(self, ids: dict[str, str | None], user_agent: str | None) -> str:
        """A new participant with their drawn trials, or the resumed participant of an
        external id without an answer yet (see the module docstring); returns the token.
        :class:`Conflict` when the external id has answered already."""
        self.refresh()
        token = secrets.token_urlsafe(32)
        seed = secrets.randbits(63)
        code = self.settings["completion_code"] or secrets.token_hex(4).upper()
        k = self.settings["trials_per_participant"]
        n_att = self.settings["attention_checks"]

        def plan(stims, counts, seed):
            return design.plan_trials(stims, counts, k=k, n_attention=n_att, seed=seed)

        try:
            self.storage.create_participant(
                token_hash(token), {**ids, "user_agent": user_agent}, plan, seed, code,
                resume=True,
            )  # fmt: skip
        except Conflict:
            raise Conflict(ALREADY_ANSWERED) from None
        return token

    def begin(
        self, token: str | None, ids: dict[str, str | None], user_agent: str | None
    ) -> tuple[dict, str | None]:
        """The participant of a start request and their new token (``None``: keep the one
        they have). A valid token is kept (a refreshed consent page, a second tab) unless
        the ids name another external participant (a shared computer); otherwise
        :meth:`start`."""
        p = self.participant(token)
        ext = ids.get("external_id")
        if p is not None and (
            not ext or (p["external_id"], p["study_id"]) == (ext, ids.get("study_id"))
        ):
            return p, None
        token = self.start(ids, user_agent)
        return self.require(token), token

    def reissue(self, participant: int) -> str:
        """A new token for a participant (their old one stops working): the researcher's
        resume link for someone who answered and then lost their browser's cookie.
        :class:`Forbidden` for an unknown participant."""
        token = secrets.token_urlsafe(32)
        if not self.storage.set_token(participant, token_hash(token)):
            raise Forbidden("no such participant")
        return token

    def participant(self, token: str | None) -> dict | None:
        """The participant of a token (``None`` for a missing or unknown token)."""
        if not isinstance(token, str) or not token or len(token) > MAX_TOKEN:
            return None
        digest = token_hash(token)
        p = self.storage.participant(digest)
        if p is None or not hmac.compare_digest(p["token_sha256"].encode(), digest.encode()):
            return None
        return p

    def state(self, participant: dict, *, shown: bool = False, trials=None) -> dict:
        """What the participant's page shows next (see the module docstring).

        ``trials``: the participant's trials if the caller has them (saves a query).
        """
        if trials is None:
            trials = self.storage.trials(participant["participant"])
        nxt = unanswered(trials)
        if nxt is None:
            return {
                "stage": "done",
                "code": participant["completion_code"],
                "url": self.settings["completion_url"],
            }
        if shown:
            self.storage.mark_shown(participant["participant"], nxt["position"])
        s = self._by_id[(nxt["round"], nxt["id"])]
        size = self.sets[nxt["round"]].manifest["size"]
        practice = sum(t["kind"] == "practice" for t in trials)
        pos = nxt["position"]
        return {
            "stage": "trial",
            "position": pos,
            "practice": nxt["kind"] == "practice",
            "number": max(pos - practice + 1, 0),
            "count": len(trials) - practice,
            "goals": nxt["goals"],
            "goal_pixels": [[x / size[0], y / size[1]] for x, y in s.get("goal_pixels") or []],
            "clip": f"/api/media/{pos}/clip",
            "still": f"/api/media/{pos}/still",
            "confidence": self.settings["confidence"],
        }

    def answer(
        self,
        participant: dict,
        position: int,
        guess: str,
        confidence: int | None,
        response_ms: float,
    ) -> dict:
        """Store one answer (once) and return ``{"duplicate": bool, "state": ...}``.

        The position must be one of the participant's trials, answered already (a repeated
        submission: the first answer stays) or the next unanswered one; the guess one of
        that trial's goals. :class:`Invalid` otherwise (:class:`Forbidden` for a trial that is
        not theirs). The state is read after the answer is committed, so a duplicate's reply
        names the trial after it too.
        """
        trials = self.storage.trials(participant["participant"])
        if not 0 <= position < len(trials):
            raise Forbidden("no such trial")
        trial = trials[position]
        nxt = unanswered(trials)
        if trial["guess"] is None and (nxt is None or position != nxt["position"]):
            raise Invalid("position: answer the trials in order")
        if guess not in trial["goals"]:
            raise Invalid(f"guess: expected one of {trial['goals']}")
        stored, _ = self.storage.answer(
            participant["participant"], position, guess, confidence, response_ms
        )
        # The reply is read after the write: ``trials`` was read before it, and a concurrent
        # twin of this answer may have stored it (and the participant gone on) since.
        return {"duplicate": not stored, "state": self.state(participant)}

    def require(self, token: str | None) -> dict:
        """The participant of a token, or :class:`Unauthorized`."""
        p = self.participant(token)
        if p is None:
            raise Unauthorized("no participant: start the study from its first page")
        return p

    def state_for(self, token: str | None) -> dict:
        """:meth:`state` of a token's participant (counts a showing of the trial)."""
        return self.state(self.require(token), shown=True)

    def answer_for(self, token: str | None, *args) -> dict:
        """:meth:`answer` for a token's participant."""
        return self.answer(self.require(token), *args)

    def media_for(self, token: str | None, position: int, which: str) -> Path:
        """:meth:`media` for a token's participant."""
        return self.media(self.require(token), position, which)

    def media(self, participant: dict, position: int, which: str) -> Path:
        """The clip or still of one of the participant's trials (answered or current)."""
        trials = self.storage.trials(participant["participant"])
        if which not in ("clip", "still") or not 0 <= position < len(trials):
            raise Forbidden("no such trial")
        nxt = unanswered(trials)
        if nxt is not None and position > nxt["position"]:
            raise Forbidden("not yet")
        t = trials[position]
        return self.sets[t["round"]].file(self._by_id[(t["round"], t["id"])], which)

    # ------------------------------------------------------------------ texts

    def texts(self) -> dict:
        """Title, consent and instructions (read from the folder at each call: editable)."""
        out = {"title": self.settings["title"], "confidence": self.settings["confidence"]}
        for name in ("consent", "instructions"):
            p = self.stimdir / f"{name}.html"
            out[name] = p.read_text() if p.is_file() else ""
        return out

    def progress(self) -> dict:
        """The admin page's tables (answers per stimulus and per participant)."""
        return self.storage.progress()
