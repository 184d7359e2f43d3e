"""radseek: shared contracts of the stack (CLI entry point, zenoh topics, dataset format, geometry).

The four architecture packages (``detector_fw_sim``, ``mission``, ``estimator``, ``planner``) each
own one part of the system; this package holds only what they must agree on.
"""

__version__ = "0.1.0"
