"""Run an unchanged MAVSDK-Python example (``from mavsdk import System``) with ``mavsdk_grpc`` standing in
for ``mavsdk``, in a venv whose ``mavsdk`` is the native 4.x binding: what an integrator does when
radseek and their gRPC code share one environment (``import mavsdk_grpc as mavsdk``, but without
editing the script). Usage: python run_as_mavsdk_grpc.py SCRIPT [ARGS...]"""

import importlib
import importlib.abc
import importlib.util
import os
import runpy
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from example_ports import move_ports_from_env  # noqa: E402


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Resolves ``mavsdk`` and ``mavsdk.X`` to ``mavsdk_grpc`` and ``mavsdk_grpc.X``."""

    def find_spec(self, name, path=None, target=None):
        if name == "mavsdk" or name.startswith("mavsdk."):
            return importlib.util.spec_from_loader(name, self)
        return None

    def create_module(self, spec):
        return importlib.import_module("mavsdk_grpc" + spec.name[len("mavsdk"):])

    def exec_module(self, module):
        pass


sys.meta_path.insert(0, _Alias())
move_ports_from_env()
script = sys.argv[1]
sys.argv = sys.argv[1:]
runpy.run_path(script, run_name="__main__")
