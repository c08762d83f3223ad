"""The people loop's configuration: the families it fits, :class:`LoopConfig` and its
presets (``quick`` on a CPU, ``paper`` on a GPU, ``tiny`` for the tests)."""

from __future__ import annotations

import dataclasses
import itertools
import json
import math

from slotv_jax import data as data_lib
from slotv_jax import planning
from slotv_jax.answers.pick import READER
from slotv_jax.asking import selection
from slotv_jax.core import validation
from slotv_jax.planning import caution
from slotv_jax.training import config as train_config

LEARNED = ("mlp", "slotv_plus", "dragan_archetype", "viewpoint_archetype", "mixture_archetype")
FITTED = {"dragan_fitted": "dragan", "nikolaidis_fitted": "nikolaidis"}  # family -> labeler
#: Each learned family started from what the labelers know instead of a random draw: θ₀ the
#: family's observer trained on the mixture of the dataset's labelers (the mean of their label
#: distributions, its preset's label protocol), then fitted on the answers with the same
#: updates (:func:`slotv_jax.experiments.people_loop.loop.pretrained_params`).
PRETRAINED = {f"{f}_pre": f for f in LEARNED}  # family -> the family it starts
#: READER, the motion reader (:mod:`slotv_jax.observers.reader`), always started from its prior
#: (:mod:`slotv_jax.answers.prior`: the labelers', drawn populations' and the zoo's guesses,
#: never the people the run is scored on), with the study's camera
#: (:func:`slotv_jax.observers.people.study_camera`), then fitted on the answers.
TRAINED = (*LEARNED, *PRETRAINED, READER)  # the families fitted by gradient steps on the answers
#: The researcher's pick (:mod:`slotv_jax.answers.pooling`): the log-linear pool of the
#: candidate families, weighted by the held-out likelihood of the answers, less the one
#: whose plans the other fits judge least legible (:func:`slotv_jax.answers.pick.trusted`);
#: answers alone.
PICK = "pick"
#: The pick by plans: the plans of the one family that the *other* families' fits judge the
#: most legible (:func:`slotv_jax.experiments.people_loop.loop.cross_judged`); answers alone.
PICK_CROSS = "pick_cross"
#: The cautious pick (issue: caution where answers are thin): the pick's pool over an
#: ensemble of its fits, planned for a lower confidence bound
#: (:func:`slotv_jax.planning.caution.lower_bound_observer`): the members are the pick's
#: pools of each cross-validation fold's fits (the folds it already fits to weigh the pool)
#: and of the fits on every answer, with the pick's weights; ``LoopConfig.caution`` κ.
CAUTIOUS = "pick_cautious"
DERIVED = (PICK, PICK_CROSS, CAUTIOUS)  # families made of the others
FAMILIES = (*LEARNED, *PRETRAINED, READER, *FITTED, *DERIVED)
#: The presets' families: the pre-trained ones are an experiment of their own (``--families``;
#: ``experiments/pretrain/``). The distance/approach mixture archetype joined them once the
#: whole suite had run with it at both presets (the records against
#: ``experiments/history/people_loop_no_mixture/``: the pool's worst population rose from
#: 68 to 80 % at the paper preset, 2,000 answers).
DEFAULT_FAMILIES = (*LEARNED, READER, *FITTED, PICK, PICK_CROSS)
CAMERA = "observer"  # the viewpoint of the fitted Nikolaidis baseline (the dataset's)
#: How the motion reader's prior is made (recorded in the document's config).
READER_PRIOR = {
    "sources": "the four labelers at their default temperatures, populations random:1000-1007, "
    "every zoo member but the people scored",
    "labels": "the mean of the sources' P(goal | motion seen up to τ) at every pool motion and τ",
    "protocol": "the reader's TrainConfig (its epochs, batch and optimiser), key 4000",
    "camera": "the study's (a zoo member's own camera, else the dataset's observer camera)",
}
#: How θ₀ of a pre-trained family is made (recorded in the document's config).
PRETRAIN_RECIPE = {
    "labels": "mean of the train split's labeler distributions (every labeler of the dataset)",
    "protocol": "the family's TrainConfig: its train_size, epochs, batch and optimiser",
    "seed": "1000 + the index of the family in LEARNED",
}


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """One people-loop experiment (module docstring)."""

    preset: str
    data: data_lib.DataConfig
    train_preset: str  # slotv_jax.training.config preset of the learned families
    planner: planning.PlannerConfig  # its taus: the prefix objective (the study's τ)
    sizes: tuple[int, ...] = (250, 500, 1000, 2000, 4000, 8000)  # answers after each round
    taus: tuple[float, ...] = (0.4, 0.7, 1.0)  # the study's stop times
    per_stimulus: int = 5  # answers (fresh participants) per asked stimulus
    strategies: tuple[str, ...] = ("random", "margin", "error")
    families: tuple[str, ...] = DEFAULT_FAMILIES
    select_family: str = "slotv_plus"  # the ensemble that active strategies ask
    members: int = 4  # its size E
    select_epochs: float = 2.0  # its warm-start passes over the answers per round
    pool: int = 2000  # motions of the train split (× len(taus) candidates)
    subset: int = 1000  # candidates an active strategy scores per round
    epochs: float = 20.0  # passes over the answer rows of each family's fit
    min_updates: int = 300  # at least this many updates per fit
    block: int = 100  # updates per compiled call
    problems: int = 12  # held-out planning problems
    eval_participants: int = 20  # evaluation study: guesses per plan and τ
    seeds: int = 2
    first_seed: int = 0
    overrides: tuple[str, ...] = ()  # TrainConfig key=value overrides of the MLP families
    pick_folds: int = 3  # K of the pick's out-of-fold predictions (folds by motion)
    #: Share of every round after the first asked about the planner's own plans of the
    #: study's scenes (:mod:`slotv_jax.experiments.people_loop.rounds`); 0: dataset motions
    #: only (every preset's default before 2026-12-08, ``experiments/zoo.md``).
    plan_share: float = 0.5
    #: κ of the cautious pick (``pick_cautious``): the standard deviations of its ensemble's
    #: log P(target) that the planner holds back (:mod:`slotv_jax.planning.caution`).
    caution: float = 1.0

    def __post_init__(self):
        s, per = self.sizes, self.per_stimulus
        if len(s) < 1 or list(s) != sorted(set(s)) or s[0] < per:
            raise ValueError(f"sizes: expected increasing answer counts >= per_stimulus, got {s}")
        if any(x % per for x in s):
            raise ValueError(f"sizes: expected multiples of per_stimulus ({per}), got {s}")
        if not (isinstance(per, int) and per >= 1):
            raise ValueError(f"per_stimulus: expected an int >= 1, got {per!r}")
        if tuple(sorted(set(self.taus))) != tuple(self.taus) or not all(
            0 < t <= 1 for t in self.taus
        ):
            raise ValueError(f"taus: expected increasing stop times in (0, 1], got {self.taus}")
        if self.planner.taus is None or tuple(self.planner.taus) != tuple(self.taus):
            raise ValueError("planner: expected the prefix objective at the study's taus")
        bad = [x for x in self.strategies if x not in selection.STRATEGIES]
        if (
            bad
            or "random" not in self.strategies
            or len(set(self.strategies)) < len(self.strategies)
        ):
            raise ValueError(
                f"strategies: expected 'random' and distinct names of {selection.STRATEGIES}, "
                f"got {list(self.strategies)}"
            )
        bad = [f for f in self.families if f not in FAMILIES]
        if bad or not self.families or len(set(self.families)) < len(self.families):
            raise ValueError(
                f"families: expected distinct names of {FAMILIES}, got {list(self.families)}"
            )
        for d in DERIVED:
            if d in self.families and len(self.candidates) < 2:
                raise ValueError(f"families: {d!r} needs at least two other families")
        if CAUTIOUS in self.families and PICK not in self.families:
            raise ValueError(f"families: {CAUTIOUS!r} is the pick's ensemble: it needs {PICK!r}")
        caution.check_caution(self.caution)
        if self.select_family not in LEARNED:
            raise ValueError(
                f"select_family: expected one of {LEARNED}, got {self.select_family!r}"
            )
        if s[-1] // per > self.pool * len(self.taus):
            raise ValueError(
                f"sizes: {s[-1] // per} stimuli asked, the pool holds {self.pool} motions × "
                f"{len(self.taus)} stop times"
            )
        k_max = max([s[0] // per] + [(b - a) // per for a, b in itertools.pairwise(s)])
        if self.subset < 2 * k_max and set(self.strategies) != {"random"}:
            raise ValueError(
                f"subset: expected >= twice the largest round ({k_max}), got {self.subset}"
            )
        for f in (
            "members",
            "pick_folds",
            "pool",
            "min_updates",
            "block",
            "problems",
            "eval_participants",
            "seeds",
        ):
            v = getattr(self, f)
            if not (isinstance(v, int) and v >= 1):
                raise ValueError(f"{f}: expected an int >= 1, got {v!r}")
        if not (self.epochs > 0 and self.select_epochs > 0):
            raise ValueError("epochs, select_epochs: expected > 0")
        if not (isinstance(self.plan_share, int | float) and 0 <= self.plan_share <= 1):
            raise ValueError(f"plan_share: expected a share in [0, 1], got {self.plan_share!r}")
        cap = len(self.planned) * self.problems * len(self.taus)
        later = max([0] + [(b - a) // per for a, b in itertools.pairwise(s)])
        if round(self.plan_share * later) > cap:
            raise ValueError(
                f"plan_share: {round(self.plan_share * later)} plan stimuli in a round, the "
                f"plans hold {cap} ({len(self.planned)} families × {self.problems} problems × "
                f"{len(self.taus)} stop times)"
            )
        validation.check_seeds("first_seed", self.first_seed, self.seeds, count_name="seeds")

    @property
    def candidates(self) -> tuple[str, ...]:
        """The families the picks choose from (every family of the run but the picks)."""
        return tuple(f for f in self.families if f not in DERIVED)

    @property
    def planned(self) -> tuple[str, ...]:
        """The families whose plans rounds of plans ask about: the candidates and the pick."""
        return self.candidates + ((PICK,) if PICK in self.families else ())

    def train_config(self, family: str) -> train_config.TrainConfig:
        """The TrainConfig that fits ``family`` (a learned or pre-trained one) on answers
        (:func:`slotv_jax.training.config.family`; the overrides apply to the MLPs; a
        pre-trained family has the config of the family it starts)."""
        if family not in TRAINED:
            raise ValueError(f"family: expected one of {TRAINED}, got {family!r}")
        family = PRETRAINED.get(family, family)
        cfg = train_config.family(self.train_preset, family)
        if family in ("mlp", "slotv_plus"):
            cfg = train_config.apply_overrides(cfg, self.overrides)
        return cfg

    def updates(self, rows: int, batch: int, epochs: float, least: int) -> int:
        """Updates of a fit on ``rows`` answer rows: ``epochs`` passes, at least ``least``,
        rounded up to whole blocks."""
        u = max(least, math.ceil(epochs * rows / batch))
        return self.block * math.ceil(u / self.block)

    def to_json(self) -> dict:
        d = dataclasses.asdict(self)
        if PICK not in self.families:  # irrelevant without the pick: records made before it match
            del d["pick_folds"]
        if not self.plan_share:  # dataset motions only: records made before it match
            del d["plan_share"]
        if CAUTIOUS not in self.families:  # records made before it match
            del d["caution"]
        used = {PRETRAINED.get(f, f) for f in self.families}
        d["train"] = {f: self.train_config(f).to_dict() for f in LEARNED if f in used}
        if any(f in PRETRAINED for f in self.families):  # records made before it match
            d["pretrain"] = PRETRAIN_RECIPE
        if READER in self.families:
            d["train"][READER] = self.train_config(READER).to_dict()
            d["reader_prior"] = READER_PRIOR
        return json.loads(json.dumps(d))


def quick() -> LoopConfig:
    """CPU preset: the quick dataset and networks (64/32; the motion reader 32/32), one seed,
    12 problems, 50-point plans of 30 steps, 1,000 and 2,000 answers picked at random (the
    paper preset's sizes, at which the targets are stated; the active strategies with
    ``--strategies random,margin,error``), half of the second round asked about the
    planner's own plans (rounds of plans; ``--plan-share 0`` for dataset motions only, the
    presets' default before 2026-12-08). Suite and zoo at one seed take about half an hour
    on a 2-core CPU; before 2026-12-07 it asked for 250-2,000 answers at 2 seeds and the
    reader was 64/64 (``experiments/suite_quick/``, ``experiments/zoo_quick/``: 79 minutes
    at one seed)."""
    taus = (0.4, 0.7, 1.0)
    return LoopConfig(
        "quick",
        data_lib.quick(),
        "quick",
        planning.PlannerConfig(n_points=50, iters=30, taus=taus),
        sizes=(1000, 2000),
        taus=taus,
        strategies=("random",),
        subset=2000,
        seeds=1,
    )


def paper() -> LoopConfig:
    """GPU preset: the paper's networks and dataset distribution (12,000 training motions, of
    which the pool takes 10,000, and the held-out scenes), 3 seeds, 100 problems, the
    default planner (100 points, 50 steps), 1,000 and 2,000 answers picked at random (the
    sizes the suite's targets are stated at; the record before the mixture archetype joined
    the families also ran 500, ``experiments/history/people_loop_no_mixture/``), half of
    the second round asked about the planner's own plans, as the quick preset."""
    taus = (0.4, 0.7, 1.0)
    return LoopConfig(
        "paper",
        dataclasses.replace(data_lib.paper(), n_train=12_000, n_eval=1_000, n_new_scenes=20),
        "paper",
        planning.PlannerConfig(taus=taus),
        sizes=(1000, 2000),
        taus=taus,
        strategies=("random",),
        pool=10000,
        subset=4000,
        problems=100,
        eval_participants=40,
        seeds=3,
        epochs=30.0,
        min_updates=1000,
        block=250,
    )


def tiny() -> LoopConfig:
    """The tests' preset: seconds on a CPU."""
    taus = (0.5, 1.0)
    d = data_lib.DataConfig(
        preset="tiny", n_train=120, n_eval=40, n_train_scenes=12, n_new_scenes=2, chunk_size=256
    )
    return LoopConfig(
        "tiny",
        d,
        "quick",
        planning.PlannerConfig(n_points=20, iters=3, taus=taus),
        sizes=(20, 40),
        taus=taus,
        per_stimulus=2,
        strategies=("random", "margin"),
        families=("mlp", "dragan_fitted", PICK, PICK_CROSS, CAUTIOUS),
        select_family="mlp",
        members=2,
        pool=60,
        subset=40,
        epochs=2.0,
        min_updates=20,
        block=10,
        problems=3,
        eval_participants=4,
        seeds=1,
        overrides=("hidden=16,8",),
        pick_folds=2,
    )


PRESETS = {"quick": quick, "paper": paper, "tiny": tiny}
