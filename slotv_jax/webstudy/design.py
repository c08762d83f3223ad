"""The study design: which stimuli a new participant sees, and in which order.

Rules:

- **one τ per trajectory**: a participant sees each trajectory at most once, at one stop
  time τ and from one camera, so that an earlier, longer view cannot inform a later guess;
- **balanced answers**: a new participant gets the ``k`` trajectories with the fewest
  answers so far (answered, or assigned to a participant still active), and of each the
  stimulus (τ, camera) with the fewest answers. Ties are broken at random. The answers
  per trajectory then differ by at most one, and so do the answers per stimulus within
  a trajectory (tested with hypothesis);
- **random order**: the chosen trials are shuffled per participant (the order is stored
  with the trials); attention checks (τ = 1 motions, whose goal is plain to see) go at
  random positions after the first trial, and the practice trial comes first.

>>> stims = [Stimulus(0, "a", "trial"), Stimulus(1, "a", "trial"), Stimulus(2, "b", "trial")]
>>> sorted(plan_trials(stims, {0: 1}, k=None, n_attention=0, seed=0))  # a: 1, b: 2
[1, 2]
"""

from __future__ import annotations

import random
from collections.abc import Mapping, Sequence
from typing import NamedTuple

KINDS = ("trial", "attention", "practice")  # the kinds of stimuli a manifest may hold


class Stimulus(NamedTuple):
    """One stimulus as the design sees it."""

    key: int  # the stimulus' key in storage
    trajectory: str  # the trajectory it shows
    kind: str  # "trial", "attention" or "practice"


def plan_trials(
    stimuli: Sequence[Stimulus],
    counts: Mapping[int, int],
    *,
    k: int | None,
    n_attention: int,
    seed: int,
) -> list[int]:
    """The ordered stimulus keys of a new participant (see the module docstring).

    ``counts`` maps stimulus keys to their answers so far (missing: 0); ``k`` is the
    number of main trials (``None``: one per trajectory); ``n_attention`` the attention
    checks (at most the number of attention stimuli); ``seed`` makes the draw
    reproducible. The practice trial (the first practice stimulus) comes first.
    """
    rng = random.Random(seed)
    by_traj: dict[str, list[Stimulus]] = {}
    for s in stimuli:
        if s.kind not in KINDS:
            raise ValueError(f"stimulus {s.key}: kind {s.kind!r} is not one of {KINDS}")
        if s.kind == "trial":
            by_traj.setdefault(s.trajectory, []).append(s)
    # ---- the least-answered stimulus of each trajectory (random among ties)
    best: list[tuple[int, float, Stimulus]] = []
    for traj in sorted(by_traj):
        cands = by_traj[traj]
        low = min(counts.get(s.key, 0) for s in cands)
        pick = rng.choice([s for s in cands if counts.get(s.key, 0) == low])
        total = sum(counts.get(s.key, 0) for s in cands)
        best.append((total, rng.random(), pick))
    # ---- the k trajectories with the fewest answers
    best.sort(key=lambda b: (b[0], b[1]))
    n = len(best) if k is None else min(k, len(best))
    main = [b[2].key for b in best[:n]]
    rng.shuffle(main)
    # ---- attention checks at random positions (never first), practice first
    trajs = {s.trajectory for s in stimuli if s.kind == "trial"}
    checks = [s for s in stimuli if s.kind == "attention" and s.trajectory not in trajs]
    checks.sort(key=lambda s: (counts.get(s.key, 0), rng.random()))
    for s in checks[: max(0, n_attention)]:
        main.insert(rng.randint(1, len(main)) if main else 0, s.key)
    practice = [s.key for s in stimuli if s.kind == "practice"][:1]
    return practice + main
