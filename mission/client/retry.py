"""Idempotent MAVSDK calls tried again when they time out: a lost COMMAND_ACK or final MISSION_ACK is a timeout in
MAVSDK after its own resends (it never resends a mission's last item, as with PX4), and on a lossy link that
happens (the injected-faults run: uploads, a mission start). A refusal is final."""

from __future__ import annotations

from collections.abc import Awaitable, Callable
from typing import Any

#: tries of an idempotent call that times out. Over a link losing 10 % of datagrams each way (--drop-rate 0.1,
#: speed-up 20) 2 of 60 ten-item uploads' first tries timed out on an idle machine and 7 of 60 with four CPU hogs
#: beside it (MAVSDK's 0.5 s wall timeouts): with 3 tries a loaded flight of ~10 uploads failed about once in 50 (a
#: clean-clone make test's injected-faults run: three timeouts in a row, "upload_mission: TIMEOUT"); with 6, about
#: 0.12^6 = 3e-6 an upload
TRANSFER_ATTEMPTS = 6


async def retry_on_timeout(call: str, start: Callable[[], Awaitable[Any]], error: type[Exception],
                           failed: Callable[[str, str], Exception]) -> Any:
    """``await start()`` (it makes the MAVSDK call), again when it raises ``error`` with result TIMEOUT, up to
    :data:`TRANSFER_ATTEMPTS` times; any other result, or the last timeout, raises ``failed(call, result name)``."""
    for attempt in range(1, TRANSFER_ATTEMPTS + 1):
        try:
            return await start()
        except error as exc:
            name = exc.result.name
            if name != "TIMEOUT" or attempt == TRANSFER_ATTEMPTS:
                raise failed(call, name) from None
