"""Idempotent mission calls are tried again when MAVSDK times out (a lost ACK on a lossy link), and only then.

The faults are injected into a stand-in for MAVSDK's MissionRaw plugin (the retry rule is the real one); the
real lossy link is exercised by tests/test_mavsdk_packet_loss.py and the injected-faults stack test.
"""

from __future__ import annotations

import asyncio

import pytest
from mavsdk.plugins.mission_raw import MissionRawError, MissionRawResult

from mission.client.mission_upload import MissionControl, MissionFailed
from mission.client.retry import TRANSFER_ATTEMPTS


class FlakyMissionRaw:
    """Each call fails with the next of ``faults`` (a MissionRawResult name), then succeeds."""

    def __init__(self, faults: list[str]):
        self.faults = list(faults)
        self.calls: list[str] = []

    async def _call(self, name: str) -> None:
        self.calls.append(name)
        if self.faults:
            raise MissionRawError(getattr(MissionRawResult, self.faults.pop(0)), name)

    def start_mission(self):
        return self._call("start_mission")

    def set_current_mission_item(self, seq: int):
        return self._call(f"set_current {seq}")

    def upload_mission(self, items):
        return self._call("upload_mission")


def _control(faults: list[str]) -> tuple[MissionControl, FlakyMissionRaw]:
    mc = MissionControl.__new__(MissionControl)  # no vehicle: the plugin is the stand-in
    mc._mr, mc.items = FlakyMissionRaw(faults), []
    return mc, mc._mr


@pytest.mark.parametrize("call", ["start", "set_current", "upload"])
def test_a_timed_out_idempotent_call_is_tried_again_until_it_succeeds(call):
    mc, mr = _control(["TIMEOUT"] * (TRANSFER_ATTEMPTS - 1))
    args = {"start": (), "set_current": (3,), "upload": ([],)}[call]
    asyncio.run(getattr(mc, call)(*args))
    assert len(mr.calls) == TRANSFER_ATTEMPTS and len(set(mr.calls)) == 1


def test_a_call_that_keeps_timing_out_fails_after_the_last_try():
    mc, mr = _control(["TIMEOUT"] * TRANSFER_ATTEMPTS)
    with pytest.raises(MissionFailed) as err:
        asyncio.run(mc.start())
    assert len(mr.calls) == TRANSFER_ATTEMPTS
    assert "start_mission" in str(err.value) and "TIMEOUT" in str(err.value)


def test_a_refusal_is_not_tried_again():
    mc, mr = _control(["DENIED"])
    with pytest.raises(MissionFailed) as err:
        asyncio.run(mc.start())
    assert mr.calls == ["start_mission"] and "DENIED" in str(err.value)


class FlakyAction:
    """MAVSDK's Action plugin stand-in: each call fails with the next of ``faults`` (an ActionResult name)."""

    def __init__(self, faults: list[str]):
        self.faults = list(faults)
        self.calls: list[str] = []

    def __getattr__(self, name: str):
        from mavsdk.plugins.action import ActionError, ActionResult

        async def call(*args):
            self.calls.append(name)
            if self.faults:
                raise ActionError(getattr(ActionResult, self.faults.pop(0)), name)
        return call


def _actions(faults: list[str]):
    from mission.client.action import Actions

    acts = Actions.__new__(Actions)  # no vehicle: the plugin is the stand-in
    acts._action = FlakyAction(faults)
    return acts, acts._action


@pytest.mark.parametrize("call", ["arm", "takeoff", "land", "return_to_launch", "hold", "disarm"])
def test_a_timed_out_action_is_tried_again_until_it_succeeds(call):
    acts, plugin = _actions(["TIMEOUT"] * (TRANSFER_ATTEMPTS - 1))
    asyncio.run(getattr(acts, call)())
    assert len(plugin.calls) == TRANSFER_ATTEMPTS and len(set(plugin.calls)) == 1


def test_an_action_that_keeps_timing_out_or_is_refused_fails_with_its_result():
    from mission.client.action import ActionFailed

    acts, plugin = _actions(["TIMEOUT"] * TRANSFER_ATTEMPTS)
    with pytest.raises(ActionFailed, match="arm: TIMEOUT"):
        asyncio.run(acts.arm())
    assert len(plugin.calls) == TRANSFER_ATTEMPTS
    acts, plugin = _actions(["COMMAND_DENIED"])
    with pytest.raises(ActionFailed, match="takeoff: COMMAND_DENIED"):
        asyncio.run(acts.takeoff())
    assert plugin.calls == ["takeoff"]
