"""Run an unchanged MAVSDK-Python example on a sped-up clock: each ``asyncio.sleep``/``time.sleep`` the script
itself calls waits 1/FACTOR of what it asks, and the vehicle runs with its ``--speedup`` multiplied by FACTOR,
so every wait of the script still spans the same simulated time (as PX4 SITL at a speed factor). Sleeps inside
MAVSDK and asyncio are left alone. Usage: python run_sped_up.py FACTOR SCRIPT [ARGS...]

The example's fixed ports move where the test says (``example_ports``)."""

import asyncio
import os
import runpy
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from example_ports import move_ports_from_env  # noqa: E402

factor = float(sys.argv[1])
script = os.path.abspath(sys.argv[2])
_async_sleep, _sleep = asyncio.sleep, time.sleep


def _scaled(delay: float) -> float:
    return delay / factor if sys._getframe(2).f_code.co_filename == script else delay


def async_sleep(delay, *args, **kwargs):
    return _async_sleep(_scaled(delay), *args, **kwargs)


def sleep(delay):
    return _sleep(_scaled(delay))


asyncio.sleep, time.sleep = async_sleep, sleep
move_ports_from_env()

sys.argv = sys.argv[2:]
sys.path.insert(0, os.path.dirname(script))
runpy.run_path(script, run_name="__main__")
