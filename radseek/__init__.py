"""radseek: shared contracts of the stack (zenoh topics, board wire format, frame record, dataset types,
coordinates, geometry).

The architecture packages (``detector_fw_sim``, ``vehicle_sim``, ``mission``, ``estimator``, ``planner``)
each own one part of the system; this package holds only what they must agree on, and imports no other
radseek package. Reading and writing files is :mod:`radseek_io`; the ``radseek`` command is :mod:`radseek_cli`.
"""

__version__ = "0.1.0"
