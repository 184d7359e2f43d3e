"""Occupancy map, dwell-time controller, OMPL random-tree next-best-dwell-point planner with the
gain of paper 003 eq. 6, exploration and baseline search patterns. Never talks to the vehicle.

Entry points for the mission layer (see docs/planner.md)::

    from planner.dwell_controller import DwellController          # one per dwell: update(t, counts, dt, flags)
    from planner.belief import SourceBelief, DwellHistory          # SourceBelief.from_estimate(msg)
    from planner.occupancy import OccupancyMap                     # OccupancyMap.from_scenario(scenario)
    from planner.exploration import exploration_done, plan_exploration
    from planner.next_best import plan_next_dwell                  # -> DwellPlan; .to_topic(t) -> topics.Plan
"""
