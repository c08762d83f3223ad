"""Simulated participants that take a study over HTTP, as a browser would.

Each participant starts (consent, URL ids), then for every trial fetches the clip and the
still, chooses a goal and posts the answer, retrying on a lost connection with the same
body (the server stores it once). A *guesser* chooses the goal:

- :func:`uniform_guesser`: a goal at random (load tests);
- :class:`LabelerGuesser`: a participant who answers like a hand-crafted observer. It
  recognises the stimulus from the still it was shown (the still's SHA-256 is in the
  manifest), takes the points of the motion up to τ, and draws the goal from the
  labeler's probabilities (:ref:`concepts-labelers`): a stand-in for people, to try the study
  pipeline end to end before anyone takes part.
- :class:`PopulationGuesser`: participants of a population of simulated people
  (:mod:`slotv_jax.observers.population`): each participant draws their own parameters
  (viewpoint, inference rule, temperature, memory) once, then answers every trial from
  their own guess distribution on the points up to τ, lapses included. A guesser with a
  ``participant(i)`` method gives participant i their own guesser in :func:`run_crowd`.

>>> import asyncio
>>> asyncio.run(run_crowd("http://127.0.0.1:8000", 20, uniform_guesser(0)))  # doctest: +SKIP
"""

from __future__ import annotations

import asyncio
import functools
import hashlib
import random
import ssl
import time
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import httpx
import jax
import numpy as np

from slotv_jax.observers import labelers, population
from slotv_jax.webstudy import stimuli

Guesser = Callable[[dict, bytes], str]  # (trial state, still bytes) -> goal label


class Result(NamedTuple):
    """What one simulated participant did."""

    answers: list[tuple[int, str]]  # (position, guess) acknowledged by the server
    latencies: list[float]  # seconds per answer request (the successful attempt)
    duplicates: int  # answers the server reported as already stored
    code: str | None  # the completion code (None: not finished)


def uniform_guesser(seed: int) -> Guesser:
    """A goal at random."""
    rng = random.Random(seed)
    return lambda state, still: rng.choice(state["goals"])


class _Motion(NamedTuple):
    """A stimulus's motion as a participant saw it."""

    labels: list[str]  # the goals' labels, in slot order
    xyz: np.ndarray  # (T, 3) float32, the whole motion
    seen: int  # points up to τ (at least 2)
    goals: np.ndarray  # (8, 3) float32
    goal_mask: np.ndarray  # (8,) bool


class _Stimuli:
    """Every stimulus of a study folder, found by the SHA-256 of its still."""

    def __init__(self, stimdir: str | Path):
        self.stimdir = stimdir
        self.by_still: dict[str, tuple[dict, stimuli.StimulusSet]] = {}
        for r in stimuli.find_rounds(stimdir):
            st = stimuli.load_stimulus_set(stimuli.round_dir(stimdir, r), verify=False)
            for s in st.manifest["stimuli"]:
                self.by_still[s["still_sha256"]] = (s, st)

    def find(self, still: bytes) -> tuple[dict, stimuli.StimulusSet]:
        """The manifest entry and set of the stimulus whose still this is; a still that is
        none of the folder's (the server serves another study) is a ``ValueError``."""
        found = self.by_still.get(hashlib.sha256(still).hexdigest())
        if found is None:
            raise ValueError(
                f"--stimuli {self.stimdir}: the server showed a still that is none of this "
                "folder's stimuli (does it serve another study folder?)"
            )
        return found

    def motion(self, still: bytes) -> _Motion:
        s, st = self.find(still)
        pts = np.array(st.trajectories[s["trajectory"]], np.float64)
        seen = max(2, int(np.sum(pts[:, 0] <= s["tau"] + 1e-9)))
        goals = np.zeros((8, 3), np.float32)
        mask = np.zeros(8, bool)
        g = st.goals[s["trajectory"]]
        goals[: len(g)] = [row[1:] for row in g]
        mask[: len(g)] = True
        return _Motion([row[0] for row in g], pts[:, 1:].astype(np.float32), seen, goals, mask)


class LabelerGuesser:
    """Answers like a labeler (``dragan``, ``effdist``, ``fastapp``; see the module doc)."""

    def __init__(self, stimdir: str | Path, labeler: str = "dragan", seed: int = 0):
        if labeler not in ("dragan", "effdist", "fastapp"):
            raise ValueError(f"labeler: expected dragan, effdist or fastapp, got {labeler!r}")
        self.fn = getattr(labelers, labeler)
        self.rng = np.random.default_rng(seed)
        self.stimuli = _Stimuli(stimdir)

    def probs(self, still: bytes) -> tuple[list[str], np.ndarray]:
        """The labeler's goal probabilities for the stimulus whose still this is."""
        m = self.stimuli.motion(still)
        n = len(m.labels)
        p = np.asarray(self.fn(m.xyz[: m.seen], m.goals, m.goal_mask), np.float64)[:n]
        return m.labels, p / p.sum()

    def __call__(self, state: dict, still: bytes) -> str:
        names, p = self.probs(still)
        return str(self.rng.choice(names, p=p))


_participant_probs = jax.jit(population.participant_probs)


class Crowd(NamedTuple):
    """Participants who each have their own guesser, ``participant(i)``, in :func:`run_crowd`."""

    participant: Callable[[int], Guesser]


class PopulationGuesser:
    """Participants of a population (see the module doc): participant i draws their
    parameters from ``fold_in(key(seed), i)`` (:func:`population.draw_participants`) and
    their guesses from ``numpy.random.default_rng([seed, i])``.

    ``population``: a :class:`population.Population`, ``default``, ``homogeneous`` or the
    path of a population JSON file (checked here, before any participant starts).
    """

    def __init__(self, stimdir: str | Path, pop: population.Population | str = "default",
                 seed: int = 0):  # fmt: skip
        self.population = pop if isinstance(pop, population.Population) else (
            population.get_population(pop))  # fmt: skip
        self.seed = seed
        self.stimuli = _Stimuli(stimdir)

    def participant(self, i: int) -> PopulationParticipant:
        """Participant ``i``, with their own parameters."""
        key = jax.random.fold_in(jax.random.key(self.seed), i)
        people = population.draw_participants(self.population, key, 1)
        return PopulationParticipant(self, people, np.random.default_rng([self.seed, i]))


class PopulationParticipant:
    """One participant of a :class:`PopulationGuesser`: a :data:`Guesser`."""

    def __init__(self, crowd: PopulationGuesser, people: population.Participants, rng):
        self.crowd, self.people, self.rng = crowd, people, rng

    def parameters(self) -> dict:
        """The participant's draw: viewpoint, rule, beta, alpha."""
        p = self.people
        return {
            "viewpoint": self.crowd.population.viewpoints[int(p.viewpoint[0])][0],
            "rule": population.RULES[int(p.rule[0])],
            "beta": float(p.beta[0]),
            "alpha": float(p.alpha[0]),
        }

    def probs(self, still: bytes) -> tuple[list[str], np.ndarray]:
        """This participant's guess distribution (lapses included) for the stimulus whose
        still this is."""
        m = self.crowd.stimuli.motion(still)
        y = _participant_probs(self.people, m.xyz, m.goals, m.goal_mask, np.int32(m.seen))
        p = np.asarray(y[0], np.float64)[: len(m.labels)]
        return m.labels, p / p.sum()

    def __call__(self, state: dict, still: bytes) -> str:
        names, p = self.probs(still)
        return str(self.rng.choice(names, p=p))


class Refused(ValueError):
    """A request the server refused with a client error (4xx), with the server's own reason.

    ``participant``: the external id it was sent for (``None``: none); ``status``: the HTTP
    status; ``error``: the server's message (``{"error": ...}`` of the reply, or ``""``).
    """

    def __init__(self, participant: str | None, method: str, path: str, status: int,
                 reason: str, error: str):  # fmt: skip
        self.participant, self.method, self.path = participant, method, path
        self.status, self.reason, self.error = status, reason, error
        who = f"participant {participant}: " if participant is not None else ""
        super().__init__(f"{who}the server refused {method} {path} ({status} {reason})"
                         + (f": {error}" if error else ""))  # fmt: skip


def _checked(r: httpx.Response, participant: str | None) -> httpx.Response:
    """``r`` if it succeeded, else :class:`Refused` with the server's reason."""
    if r.is_success:
        return r
    try:
        error = r.json().get("error", "")
    except (ValueError, AttributeError):  # not JSON (a proxy's page) or not an object
        error = ""
    raise Refused(participant, r.request.method, r.request.url.path, r.status_code,
                  r.reason_phrase, str(error))  # fmt: skip


async def _request(client: httpx.AsyncClient, method: str, url: str, deadline: float, **kw):
    """One request, retried on connection errors and 5xx until ``deadline`` (monotonic)."""
    wait = 0.05
    while True:
        try:
            r = await client.request(method, url, **kw)
            if r.status_code < 500:
                return r
        except httpx.TransportError:
            pass
        if time.monotonic() + wait > deadline:
            raise TimeoutError(f"{method} {url}: no answer from the server")
        await asyncio.sleep(wait)
        wait = min(wait * 2, 1.0)


@functools.cache
def _tls_context() -> ssl.SSLContext:
    """The certificate-verifying TLS context of every participant's client (httpx's
    default), made once: making it loads the CA bundle, about 15 ms of CPU each time, which
    the 120 simulated participants of the study guide's walk paid 120 times."""
    return httpx.create_ssl_context()


async def run_participant(
    base_url: str,
    guess: Guesser,
    *,
    ids: dict[str, str] | None = None,
    think: Callable[[], float] = lambda: 0.0,
    media: bool = True,
    max_trials: int | None = None,
    timeout: float = 60.0,
    cookies: httpx.Cookies | None = None,
    log: list | None = None,
) -> tuple[Result, httpx.Cookies]:
    """Take the study as one participant (or go on with ``cookies`` of an earlier run).

    ``think()`` seconds pass before each answer; ``max_trials`` stops early (a participant
    who leaves); ``timeout`` bounds the whole run. Returns the result and the cookies
    (the participant's token) to go on later. Each acknowledged answer is also appended
    to ``log`` as it comes, as (participant id, position, guess). A request the server
    refuses (4xx: an id that has answered already, a bad answer) raises :class:`Refused`.
    """
    deadline = time.monotonic() + timeout
    pid = (ids or {}).get("PROLIFIC_PID")
    res = Result([], [], 0, None)
    dup = 0
    async with httpx.AsyncClient(
        base_url=base_url, cookies=cookies, timeout=10.0, verify=_tls_context()
    ) as c:
        if cookies is None:
            r = await _request(c, "POST", "/api/start", deadline,
                               json={"consent": True, "ids": ids or {}})  # fmt: skip
        else:
            r = await _request(c, "GET", "/api/state", deadline)
        state = _checked(r, pid).json()
        while state["stage"] == "trial" and (max_trials is None or len(res.answers) < max_trials):
            still = b""
            if media:
                _checked(await _request(c, "GET", state["clip"], deadline), pid)
                r = await _request(c, "GET", state["still"], deadline)
                still = _checked(r, pid).content
            await asyncio.sleep(think())
            body = {"position": state["position"], "guess": guess(state, still),
                    "confidence": 3, "response_ms": 1000}  # fmt: skip
            t0 = time.perf_counter()
            r = await _request(c, "POST", "/api/answer", deadline, json=body)
            res.latencies.append(time.perf_counter() - t0)
            out = _checked(r, pid).json()
            dup += out["duplicate"]
            res.answers.append((body["position"], body["guess"]))
            if log is not None:
                log.append((pid, body["position"], body["guess"]))
            state = out["state"]
        cookies = c.cookies
    code = state.get("code") if state["stage"] == "done" else None
    return res._replace(duplicates=dup, code=code), cookies


async def run_crowd(
    base_url: str,
    n: int,
    guess: Guesser,
    *,
    think: Callable[[], float] = lambda: 0.0,
    timeout: float = 120.0,
    media: bool = True,
    first: int = 0,
) -> list[Result]:
    """``n`` participants taking the study concurrently: participants ``first`` to
    ``first + n - 1``, ids ``sim-FIRST``, ``sim-FIRST+1``, ... (a later crowd on the same
    server starts after the earlier ones: the server refuses a new start under an id that
    has answered).

    A ``guess`` with a ``participant(i)`` method (:class:`PopulationGuesser`) gives
    participant i the guesser ``guess.participant(i)``; any other is shared by all.

    The first error ends the crowd: the participants still running are cancelled, and the
    error of the lowest-numbered participant that failed is raised (for example
    :class:`Refused` for ``sim-FIRST`` when an earlier crowd used that id).
    """
    if not (isinstance(first, int) and first >= 0):
        raise ValueError(f"first: expected an integer >= 0, got {first!r}")
    per_person = hasattr(guess, "participant")
    tasks = [
        asyncio.ensure_future(run_participant(
            base_url,
            guess.participant(i) if per_person else guess,
            ids={"PROLIFIC_PID": f"sim-{i}"},
            think=think,
            timeout=timeout,
            media=media,
        ))
        for i in range(first, first + n)
    ]  # fmt: skip
    await asyncio.wait(tasks, return_when=asyncio.FIRST_EXCEPTION)
    failed = [t for t in tasks if t.done() and not t.cancelled() and t.exception()]
    if failed:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)  # let them end
        raise failed[0].exception()
    return [t.result()[0] for t in tasks]
