"""Why a plan is not executed: one line a lab reads, with the facts behind it."""

from __future__ import annotations

__all__ = ["Refused"]


class Refused(Exception):
    """A plan the robot would not execute as planned (a limit, a collision, the path).

    ``str(e)`` is one line: the first time (s, from the motion's start), then the joint and
    limit, or the colliding pair, or how far the tool leaves the planned path. ``facts``
    holds the same in fields (``t``, ``check``, and per check e.g. ``joint``, ``value``,
    ``limit`` or ``pair``). Not a ``ValueError``: the input was well formed, the motion is
    what fails; commands report it and exit with 1.
    """

    def __init__(self, line: str, **facts):
        super().__init__(line)
        self.facts = facts
