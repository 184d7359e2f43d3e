"""How a search ended, as a value (issue 31 item 3): the stop rules of ``mission.search`` and ``mission.team``
and the mission's abort (``mission.mission_process``) each name one :class:`Outcome`; the decision's
``reason`` stays the text for people. ``mission_summary.json``, ``summary.json`` and the campaign rows carry
it as ``"outcome"`` (its value, next to ``"reason"`` / ``"stop_reason"``)."""

from __future__ import annotations

from enum import StrEnum


class Outcome(StrEnum):
    """The search's end (``mission.search.Decision.outcome``; None while it goes on)."""

    FOUND = "found"  # 1-sigma below stop_sigma_m, stable, fit good
    DRIFT_LIMITED = "drift_limited"  # found: 1-sigma stopped falling at the odometry-drift floor
    PATTERN_FLOWN = "pattern_flown"  # a lattice / lawnmower baseline flew its pattern
    BUDGET_SPENT = "budget_spent"  # dwell budget spent (in exploration or search) before a stop rule held
    MISFIT = "misfit"  # dwell budget spent while the last fit failed its goodness of fit
    NO_FRONTIER = "no_frontier"  # exploration found no frontier left
    ABORTED = "aborted"  # the vehicle left the search (failsafe, landed)
    RETIRED = "retired"  # a team vehicle boxed in by its teammates left the search (the team's goes on)

    @property
    def found(self) -> bool:
        """The source was found (a stop rule held): ``found`` or ``drift_limited``."""
        return self in (Outcome.FOUND, Outcome.DRIFT_LIMITED)

    @property
    def located(self) -> bool:
        """The search ended on its own criterion with an estimate to report (``radseek run`` exit 0): found,
        or a baseline pattern flown to its end."""
        return self.found or self is Outcome.PATTERN_FLOWN

    @property
    def aborted(self) -> bool:
        """The vehicle left the search before it ended (``aborted`` or ``retired``)."""
        return self in (Outcome.ABORTED, Outcome.RETIRED)


def parse_outcome(value: object) -> Outcome | None:
    """``value`` as an :class:`Outcome` (None for None, "" or a value no member has: a summary written before
    the key existed)."""
    try:
        return Outcome(value) if value else None
    except ValueError:
        return None


__all__ = ["Outcome", "parse_outcome"]
