"""Run an unchanged MAVSDK-Python example on a sped-up clock: the vehicle runs with its ``--speedup``
multiplied by FACTOR, and each ``asyncio.sleep``/``time.sleep`` the script itself calls is shortened so that it
still spans the same simulated time (as PX4 SITL at a speed factor). Sleeps inside MAVSDK and asyncio are left
alone. Usage: python run_sped_up.py FACTOR SCRIPT [ARGS...]

With ``RADSEEK_SIM_CLOCK_FILE`` set (the test writes the vehicle's latest ``time_boot_ms`` there, in s), a sleep
of the script waits until the vehicle's clock has advanced by what it asks: on a loaded machine the vehicle runs
slower than FACTOR (it drops what it cannot catch up, it does not burst), and a sleep of 1/FACTOR of the wall
time would span less simulated flight than the script meant (do_orbit's 60 s orbit became 20-35 s, too short to
reach the circle). Without it (or before the vehicle's first telemetry) a sleep waits 1/FACTOR of the wall time.

The example's fixed ports move where the test says (``example_ports``)."""

import asyncio
import os
import runpy
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from example_ports import move_ports_from_env  # noqa: E402

SIM_CLOCK_ENV = "RADSEEK_SIM_CLOCK_FILE"
POLL_S = 0.01  # wall s between reads of the vehicle's clock

factor = float(sys.argv[1])
script = os.path.abspath(sys.argv[2])
clock_file = os.environ.get(SIM_CLOCK_ENV)
_async_sleep, _sleep = asyncio.sleep, time.sleep


def _from_script() -> bool:
    return sys._getframe(2).f_code.co_filename == script


def _sim_now():
    """The vehicle's clock (s) as the test last saw it; None before its first telemetry."""
    try:
        with open(clock_file) as fh:
            return float(fh.read())
    except (OSError, ValueError):
        return None


def _sim_until(delay: float):
    """The simulated time a sleep of ``delay`` ends at; None: no clock (or a sleep(0), which only yields), wait
    1/factor of the wall time."""
    now = _sim_now() if clock_file and delay > 0 else None
    return None if now is None else now + delay


async def _async_sim_sleep(end: float, result=None):
    while (_sim_now() or 0.0) < end:
        await _async_sleep(POLL_S)
    return result


def async_sleep(delay, *args, **kwargs):
    if not _from_script():
        return _async_sleep(delay, *args, **kwargs)
    end = _sim_until(delay)
    if end is None:
        return _async_sleep(delay / factor, *args, **kwargs)
    return _async_sim_sleep(end, *args, **kwargs)


def sleep(delay):
    if not _from_script():
        return _sleep(delay)
    end = _sim_until(delay)
    if end is None:
        return _sleep(delay / factor)
    while (_sim_now() or 0.0) < end:
        _sleep(POLL_S)


asyncio.sleep, time.sleep = async_sleep, sleep
move_ports_from_env()

sys.argv = sys.argv[2:]
sys.path.insert(0, os.path.dirname(script))
runpy.run_path(script, run_name="__main__")
