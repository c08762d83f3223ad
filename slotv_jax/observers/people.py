"""Simulated people of either kind, behind one set of names: a population of the
population model (:class:`slotv_jax.observers.population.Population`) or a member of the
zoo of people outside it (:class:`slotv_jax.observers.zoo.ZooMember`, a researcher's own
included). The simulated study, the scoring of plans and the loop ask these functions for
people's guesses and probabilities, whichever kind the people are.

(The scoring of plans by either kind is :func:`slotv_jax.planning.evaluation.population_scorer`.)

Names (``--population`` of the people loop): ``default``, ``homogeneous``, ``random:K``, a
population JSON file, ``suite`` (the suite's populations), a zoo member's name
(:func:`slotv_jax.observers.zoo.zoo_names`), ``zoo`` (every member), or
``module:function`` (a function returning a :class:`~slotv_jax.observers.zoo.ZooMember`:
:func:`slotv_jax.observers.zoo.load_people`).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import jax
from jaxtyping import Array, Bool, Float, Int

from slotv_jax.observers import population as population_lib
from slotv_jax.observers import zoo
from slotv_jax.world import scene

People = population_lib.Population | zoo.ZooMember

SUITE = "suite"  # every population of the suite
ZOO = "zoo"  # every member of the zoo

__all__ = ["SUITE", "ZOO", "People", "expand", "get_people", "guesses_batch", "people_config",
           "people_name", "study_camera"]  # fmt: skip
#: The camera a simulated study of a population is filmed from (the dataset's): a population's
#: people watch from several of the scene's cameras, and none of them is the study's alone.
STUDY_CAMERA = "observer"


def _is_user_people(spec: str) -> bool:
    return ":" in spec and not spec.startswith(population_lib.RANDOM_PREFIX)


def expand(specs: Iterable[str]) -> list[str]:
    """Comma-separated names with ``suite`` and ``zoo`` expanded, each once, in order."""
    out: list[str] = []
    for s in (s.strip() for s in specs):
        names = (
            population_lib.suite_specs()
            if s == SUITE
            else zoo.zoo_names()
            if s == ZOO
            else [s]
            if s
            else []
        )
        out += [n for n in names if n not in out]
    return out


def get_people(spec: str) -> People:
    """The people a name gives (the module docstring's names); a ValueError naming every
    form for anything else."""
    spec = str(spec)
    if spec in zoo.MEMBERS and not Path(spec).is_file():
        return zoo.MEMBERS[spec]
    if _is_user_people(spec):
        return zoo.load_people(spec)
    try:
        return population_lib.get_population(spec)
    except ValueError as e:
        if "no such file" not in str(e):
            raise
        raise ValueError(
            f"population: expected {', '.join(population_lib.PRESETS)}, "
            f"{population_lib.RANDOM_PREFIX}K (the K-th draw), {SUITE}, a population JSON "
            f"file, a zoo member ({', '.join(zoo.zoo_names())}), {ZOO}, or module:function "
            f"(your own people), got {spec!r}"
        ) from None


def people_name(spec: str, people: People) -> str:
    """The ``population`` value of the results: a zoo member's own name (a researcher's
    too), ``default``, ``homogeneous``, ``random:K``, or a population file's stem."""
    if isinstance(people, zoo.ZooMember):
        return people.name
    if spec in population_lib.PRESETS or spec.startswith(population_lib.RANDOM_PREFIX):
        return spec
    return Path(spec).stem


def study_camera(people: People) -> scene.Camera:
    """The camera a simulated study of ``people`` films its clips from, which the lab would
    know (the motion reader's image view): a zoo member's own camera, or for a member who
    reads the table plane and for a population, the dataset's camera
    (:data:`STUDY_CAMERA`)."""
    if isinstance(people, zoo.ZooMember) and people.view in zoo.ZOO_CAMERAS:
        return zoo.zoo_camera(people.view)
    return scene.camera(STUDY_CAMERA)


def people_config(people: People) -> dict[str, Any]:
    """What a results document keeps of the people: a population's fields, or a zoo
    member's name, camera, temperature centre, parameter ranges and reference."""
    if isinstance(people, zoo.ZooMember):
        return {
            "zoo": people.name,
            "view": people.view,
            "beta": people.beta,
            "ranges": {p: [lo, hi] for p, lo, hi in people.ranges},
            "sigma_log": zoo.SIGMA_LOG,
            "lapse": list(zoo.LAPSE_RANGE),
            "reference": people.reference,
        }
    return people.to_dict()


def guesses_batch(
    people: People,
    keys: jax.Array,
    xyz: Float[Array, "B T 3"],
    goals: Float[Array, "B 8 3"],
    goal_mask: Bool[Array, "B 8"],
    seen: Int[Array, " B"],
    n: int,
) -> Int[Array, "B n"]:
    """``n`` fresh people's guesses for each of B stimuli (stimulus b's people drawn from
    ``keys[b]``), each person with their own parameters."""
    if isinstance(people, zoo.ZooMember):
        return zoo.sample_zoo_guesses_batch(people, keys, xyz, goals, goal_mask, seen, n)
    return population_lib.sample_guesses_batch(people, keys, xyz, goals, goal_mask, seen, n)
