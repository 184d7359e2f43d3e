"""The opt-in Foxglove live view: a client speaking the Foxglove WebSocket protocol (subprotocol
foxglove.sdk.v1, as the Foxglove app does) sees /map and the radseek topics advertised with their JSON
schemas, and receives /map updates after poses, a plan and an estimate are published on zenoh."""

import asyncio
import json
import struct
import time

import pytest
import websockets

from radseek import topics
from radseek.dataset import Wall
from radseek.zenoh_session import open_session
from radseek_cli.live_view import LiveView, MapState

WAIT_S = 60.0  # bounds waiting only


def test_map_state_draws_walls_track_plan_and_estimate_ellipse():
    st = MapState(((0, 0, 0), (10, 8, 3)), [Wall((1.0, 1.0), (5.0, 1.0), 0.2, 2.5)])
    st.update(topics.POSE, {"x": 1.0, "y": 2.0, "z": 1.5, "yaw": 0.0})
    st.update(topics.POSE, {"x": 2.0, "y": 2.0, "z": 1.5, "yaw": 0.0})
    st.update(topics.PLAN, topics.Plan(t=1.0, path=[2, 2, 1.5, 0, 4, 4, 1.5, 0], dwell_points=[4, 4, 1.5, 0]).to_dict())
    cov = [0.0] * 16
    cov[0], cov[5], cov[10] = 0.04, 0.09, 0.01
    source = {"x": 5, "y": 4, "z": 0, "cps_at_1m": 900}
    st.update(topics.ESTIMATE, topics.Estimate(t=1.0, method="mle", sources=[source], background_cps=30.0,
                                               covariance=cov).to_dict())
    assert not st.update(topics.PLAN, {"t": 1.0, "dwell_points": [[4, 4, 1.5, 0]]})  # not the layout: not drawn
    assert st.track == [(1.0, 2.0, 1.5), (2.0, 2.0, 1.5)] and st.vehicle == (2.0, 2.0, 1.5, 0.0)
    assert st.path == [[2, 2, 1.5], [4, 4, 1.5]] and st.dwells == [[4, 4, 1.5]]
    (centre, sigma), = st.sources
    assert centre == [5, 4, 0] and sigma == pytest.approx([0.2, 0.3, 0.1])  # 1-sigma ellipsoid axes
    assert len(st.scene().encode()) > 200  # a foxglove.SceneUpdate with walls, track, path, dwells, estimate


async def _client(port: int, publish, subprotocol: str = "foxglove.sdk.v1") -> tuple[dict, bytes]:
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=[subprotocol]) as ws:
        assert ws.subprotocol == subprotocol
        channels: dict[str, dict] = {}
        deadline = time.monotonic() + WAIT_S
        want = {"/map", "/" + topics.key(topics.POSE), "/" + topics.key(topics.HISTOGRAM)}
        subscribed = False
        while time.monotonic() < deadline:
            publish()
            try:
                raw = await asyncio.wait_for(ws.recv(), 0.3)
            except TimeoutError:
                continue
            if isinstance(raw, str):
                msg = json.loads(raw)
                if msg.get("op") == "advertise":
                    channels.update({c["topic"]: c for c in msg["channels"]})
                if want <= set(channels) and not subscribed:
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": 7, "channelId": channels["/map"]["id"]}]}))
                    subscribed = True
            elif subscribed and raw[0] == 1 and struct.unpack_from("<I", raw, 1)[0] == 7:
                return channels, raw  # a /map message
        raise TimeoutError(f"advertised {sorted(channels)}")


@pytest.mark.slow
@pytest.mark.parametrize("subprotocol", ["foxglove.sdk.v1", "foxglove.websocket.v1"])
def test_foxglove_client_sees_the_map_and_topics(router, subprotocol):
    """Both protocol generations: foxglove.websocket.v1 is what Lichtblick, older Foxglove and the npm reference
    client send (the SDK's own server answers it with HTTP 400)."""
    session = open_session(None, router)
    view = LiveView(session, port=0, bounds=((0, 0, 0), (10, 8, 3)), walls=[])
    k = [0]

    def publish():
        k[0] += 1
        session.put(topics.key(topics.POSE), topics.Pose(t=0.1 * k[0], x=1, y=2, z=1.5, yaw=0, var_x=0.01,
                                                          var_y=0.01, var_z=0.01, var_yaw=0.01).to_bytes())
        session.put(topics.key(topics.HISTOGRAM), json.dumps({"t": 0.1 * k[0], "counts": [1] * 32}).encode())

    try:
        channels, data = asyncio.run(_client(view.port, publish, subprotocol))
    finally:
        view.close()
        session.close()
    assert channels["/map"]["schemaName"] == "foxglove.SceneUpdate" and len(data) > 13
    pose = channels["/" + topics.key(topics.POSE)]
    assert pose["encoding"] == "json" and "var_x" in json.loads(pose["schema"])["properties"]
