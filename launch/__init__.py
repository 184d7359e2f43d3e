"""Launchers: the tools that set up a simulated world and run the flight software against it.

``run_cli`` (``radseek run``) starts the router, the board emulator, the mock autopilot and the mission
process and writes ``truth.json`` and the report after the flight; ``offline`` flies the same search
brain in-process for seeded benchmarks; ``plan_cli`` (``radseek plan``) reads a scene's map. They may
see the truth, so they live apart from ``mission``, ``estimator`` and ``planner``, which never do.
"""
