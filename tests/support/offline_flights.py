"""Offline flights of the default search (``launch.offline.fly_offline``) shared by the tests that only read them.

A flight costs 1-3 s of CPU, and the same seed's honest flight is read by several tests (in several modules, on
both xdist workers): flown once per run (``once_per_run``), each test gets its own copy. Reproducible by design:
``test_the_same_seed_flies_the_same_search_after_other_flights`` holds that a seed flies the same search whatever
was flown before it in the process.
"""

from __future__ import annotations

import pickle

import pytest

from tests.support.once_per_run import once_per_run


def default_flight(tmp_path_factory: pytest.TempPathFactory, seed: int):
    """``fly_offline(load_scene(), SearchConfig(), seed=seed)``, a private copy of the run's one flight."""
    from detector_fw_sim.scene import load_scene
    from launch.offline import fly_offline
    from mission.search import SearchConfig

    flight = once_per_run(tmp_path_factory, f"default-flight-seed-{seed}",
                          lambda _folder: fly_offline(load_scene(), SearchConfig(), seed=seed))
    return pickle.loads(pickle.dumps(flight, protocol=pickle.HIGHEST_PROTOCOL))
