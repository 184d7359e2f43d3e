"""Pure battery model: the charge drains with flight time (faster when flying fast), slowly when armed
on the ground, and the voltage sags with charge."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class BatteryParams:
    hover_endurance_s: float = 1200.0  # s of hover from full, (10, 36000]
    idle_fraction: float = 0.05  # drain when armed on the ground, relative to hover, [0, 1]
    speed_penalty: float = 0.1  # extra drain at 5 m/s, relative (quadratic in speed), [0, 1]
    cells: int = 4  # series cells, [1, 12]
    low_threshold: float = 0.25  # remaining fraction that triggers return to launch, [0, 1]
    critical_threshold: float = 0.10  # remaining fraction that triggers landing, [0, 1]

    def __post_init__(self) -> None:
        if not (10 < self.hover_endurance_s <= 36000):
            raise ValueError(f"hover_endurance_s={self.hover_endurance_s} must be in (10, 36000]")
        if not (0 <= self.critical_threshold <= self.low_threshold <= 1):
            raise ValueError("need 0 <= critical_threshold <= low_threshold <= 1")


def drain(remaining: float, dt: float, armed: bool, in_air: bool, speed: float, p: BatteryParams) -> float:
    """Remaining fraction after ``dt`` s."""
    if not armed:
        return remaining
    rate = 1.0 / p.hover_endurance_s
    rate *= (1.0 + p.speed_penalty * (speed / 5.0) ** 2) if in_air else p.idle_fraction
    return max(0.0, remaining - rate * dt)


def voltage(remaining: float, p: BatteryParams) -> float:
    """Pack voltage (V): 3.5 V per cell empty, 4.2 V full."""
    return p.cells * (3.5 + 0.7 * min(max(remaining, 0.0), 1.0))
