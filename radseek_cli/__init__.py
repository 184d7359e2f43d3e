"""radseek's command-line layer: the ``radseek`` console command (:mod:`radseek_cli.main`) and the tools it
runs that belong to no one package (inspection, record, view, and the dataset tools localize, compare,
diagnose and replay, which alone of them read a dataset's truth.json to report errors).

It sits above every other layer and may import any of them; nothing imports it (tests/test_architecture.py).
``python -m radseek_cli`` is the ``radseek`` command.
"""
