"""Occupancy map, dwell-time controller, OMPL random-tree next-best-dwell-point planner with the
gain of paper 003 eq. 6, exploration and baseline search patterns. Never talks to the vehicle."""
