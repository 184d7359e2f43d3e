"""Fly a QGroundControl .plan file (``radseek mission --plan FILE``): its mission, geofence and rally
points are uploaded through MAVSDK's mission_raw (the importer QGC users rely on), then the vehicle is
armed, the mission started and followed until it is finished and the vehicle has landed (or, for a
mission that ends in the air, is holding)."""

from __future__ import annotations

import asyncio
from pathlib import Path

from mission.client import action, connection, mission_upload, telemetry


async def fly_plan(path: Path, url: str, timeout_s: float = 3600.0, log=print) -> dict:
    conn = await connection.connect(url, timeout_s=60)
    try:
        await connection.wait_healthy(conn, timeout_s=60)
        mc = mission_upload.MissionControl(conn)
        data = await mc._do("import_qgroundcontrol_mission", mc._mr.import_qgroundcontrol_mission(str(path)))
        mission, fence, rally = list(data.mission_items), list(data.geofence_items), list(data.rally_items)
        log(f"{path}: {len(mission)} mission items, {len(fence)} fence items, {len(rally)} rally points")
        if fence:
            await mc.retried("upload_geofence", lambda: mc._mr.upload_geofence(fence))
        if rally:
            await mc.retried("upload_rally_points", lambda: mc._mr.upload_rally_points(rally))
        await mc.upload(mission)
        tel = telemetry.TelemetryWatch(conn)
        await action.Actions(conn).arm()
        await mc.start()
        log("mission started")
        await mc.wait_finished(timeout_s=timeout_s)
        landed = mission and mission[-1].command in (20, 21)  # RTL or LAND last
        if landed:
            await tel.wait_in_air(False, timeout_s=timeout_s)
        log("mission finished" + (", landed" if landed else ""))
        return {"mission_items": len(mission), "fence_items": len(fence), "rally_points": len(rally),
                "landed": bool(landed)}
    finally:
        await conn.close()


def run(path: Path, url: str) -> dict:
    return asyncio.run(fly_plan(path, url))
