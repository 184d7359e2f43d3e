"""The in-flight source estimate as a typed record (issue 31 item 3, "Typed contracts").

:class:`SourceEstimate` is the record ``estimator.inflight.InflightEstimator`` makes after every dwell, as the
search (``mission.search``, ``mission.team``), the mission's summary, the report, the campaign and the
benchmarks read it. Its converters are the one place that knows the other two forms:

* the JSON object of ``mission_summary.json`` (``estimate``, ``estimates``) and ``summary.json``
  (``estimate``): :meth:`SourceEstimate.from_json` / :meth:`SourceEstimate.to_json`, keys unchanged;
* the zenoh ``estimate`` message (``radseek.topics.Estimate``): :meth:`SourceEstimate.from_topic` /
  :meth:`SourceEstimate.to_topic`.

Covariance layout, declared once: ``covariance`` is the (3, 3) covariance of the position (x, y, z), m^2,
ENU, symmetric positive semi-definite (``estimator.inflight.repair_covariance``), as the JSON carries it. The
topic's per-source 4 x 4 block over (x, y, z, cps_at_1m) holds it as its upper-left 3 x 3; the strength's row
and column are not part of this record (NaN when sent, "unknown" in the topic's layout). The localizer's
4M x 4M ``covariance_`` is the estimator's own (``estimator.localizers.base``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from radseek import topics
from radseek.geometry import semi_major_axis

#: the record's keys, in the order ``estimator.inflight`` writes them (``ellipse_95``, ``bound_m``: only after
#: ``InflightEstimator.finalize``); any other key rides along in ``extra``
JSON_KEYS = ("dwell", "x", "y", "z", "cps_at_1m", "background_cps", "covariance", "sigma_m", "effects", "params",
             "converged", "p_value", "drift_floor_m", "pose_sd_m", "ellipse_95", "bound_m")
_REQUIRED = ("x", "y", "covariance")


@dataclass(frozen=True, eq=False)
class SourceEstimate:
    """One source estimate: state, position covariance (module docstring: (3, 3) over x, y, z, m^2), 1-sigma
    and fit quality (``estimator.inflight``'s record)."""

    x: float  # m, ENU
    y: float
    z: float
    cps_at_1m: float  # source strength: net count rate at 1 m (cps)
    background_cps: float
    covariance: np.ndarray  # (3, 3) m^2 over (x, y, z), read-only
    sigma_m: float = math.inf  # 1-sigma x-y semi-major axis (m) if trustworthy, else inf (inflight.sigma_m)
    p_value: float = math.nan  # goodness of fit (deviance test); nan: not known
    converged: bool = True
    dwell: int = 0  # dwell points flown when it was made
    effects: tuple[str, ...] = ()  # the model's effects (e.g. wall_attenuation, second_source)
    params: Mapping[str, float] = field(default_factory=dict)  # other fitted parameters (a wall's mu, ...)
    drift_floor_m: float = math.nan  # the 1-sigma the odometry drift alone allows (inflight.drift_floor_m)
    pose_sd_m: float = math.nan  # the largest horizontal pose sd reported so far (inflight.pose_sd_m)
    ellipse_95: Mapping[str, float] | None = None  # a_m, b_m, angle_deg (after InflightEstimator.finalize)
    bound_m: float | None = None  # drift-aware bound, rms horizontal (after InflightEstimator.finalize)
    extra: Mapping[str, Any] = field(default_factory=dict)  # any other key of the JSON object, kept as is

    def __post_init__(self) -> None:
        cov = np.array(self.covariance, dtype=float)
        if cov.shape != (3, 3):
            raise ValueError(f"covariance must be (3, 3) over (x, y, z), got shape {cov.shape}")
        cov.flags.writeable = False
        object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "effects", tuple(self.effects))

    @property
    def position(self) -> np.ndarray:
        """(3,) x, y, z (m)."""
        return np.array([self.x, self.y, self.z])

    # ------------------------------------------------------------------------------ JSON (summary files)

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SourceEstimate:
        """The record from its JSON object (``estimator.inflight``'s dict, ``mission_summary.json``); keys a
        record written before them lacks take their defaults (z 0, strength and background nan), and an older
        record's 4 x 4 covariance over (x, y, z, cps_at_1m) gives its 3 x 3. KeyError without x, y or covariance."""
        missing = [k for k in _REQUIRED if k not in data]
        if missing:
            raise KeyError(f"estimate record lacks {', '.join(missing)}")
        ell = data.get("ellipse_95")
        bound = data.get("bound_m")
        cov = np.asarray(data["covariance"], dtype=float)
        return cls(x=float(data["x"]), y=float(data["y"]), z=float(data.get("z", 0.0)),
                   cps_at_1m=float(data.get("cps_at_1m", math.nan)),
                   background_cps=float(data.get("background_cps", math.nan)),
                   covariance=cov[:3, :3] if cov.shape == (4, 4) else cov,
                   sigma_m=float(data.get("sigma_m", math.inf)), p_value=float(data.get("p_value", math.nan)),
                   converged=bool(data.get("converged", True)), dwell=int(data.get("dwell", 0)),
                   effects=tuple(data.get("effects", ())),
                   params={str(k): float(v) for k, v in dict(data.get("params", {})).items()},
                   drift_floor_m=float(data.get("drift_floor_m", math.nan)),
                   pose_sd_m=float(data.get("pose_sd_m", math.nan)),
                   ellipse_95=None if ell is None else {str(k): float(v) for k, v in dict(ell).items()},
                   bound_m=None if bound is None else float(bound),
                   extra={k: v for k, v in data.items() if k not in JSON_KEYS})

    def to_json(self) -> dict[str, Any]:
        """The JSON object, keys and order as ``estimator.inflight`` writes them (``ellipse_95`` and ``bound_m``
        only once set), then ``extra``."""
        out: dict[str, Any] = {
            "dwell": int(self.dwell), "x": float(self.x), "y": float(self.y), "z": float(self.z),
            "cps_at_1m": float(self.cps_at_1m), "background_cps": float(self.background_cps),
            "covariance": self.covariance.tolist(), "sigma_m": float(self.sigma_m), "effects": list(self.effects),
            "params": {k: float(v) for k, v in self.params.items()}, "converged": bool(self.converged),
            "p_value": float(self.p_value), "drift_floor_m": float(self.drift_floor_m),
            "pose_sd_m": float(self.pose_sd_m)}
        if self.ellipse_95 is not None:
            out["ellipse_95"] = dict(self.ellipse_95)
        if self.bound_m is not None:
            out["bound_m"] = float(self.bound_m)
        out.update(self.extra)
        return out

    # ------------------------------------------------------------------------------ zenoh ``estimate``

    @classmethod
    def from_topic(cls, msg: topics.Estimate, source: int = 0, **fields: Any) -> SourceEstimate:
        """Source ``source`` of an ``estimate`` message: its state, background and the upper-left 3 x 3 of its
        4 x 4 covariance block, symmetrised. The message carries no fit quality: ``sigma_m`` is the x-y
        semi-major axis (inf if not finite), the rest defaults unless given in ``fields``. A message that
        breaks the layout raises ``topics.PayloadError``."""
        msg.validate()
        s = msg.sources[source]
        block = np.asarray(msg.covariance_block(source), dtype=float)[:3, :3]
        cov = (block + block.T) / 2
        sigma = semi_major_axis(cov[:2, :2]) if np.isfinite(cov[:2, :2]).all() else math.inf
        values: dict[str, Any] = {"sigma_m": sigma, **fields}
        return cls(x=float(s["x"]), y=float(s["y"]), z=float(s["z"]), cps_at_1m=float(s["cps_at_1m"]),
                   background_cps=float(msg.background_cps), covariance=cov, **values)

    def to_topic(self, t: float = 0.0, method: str = "inflight") -> topics.Estimate:
        """One-source ``estimate`` message: the covariance in the upper-left 3 x 3 of the 4 x 4 block, the
        strength's row and column NaN (unknown), no CRLB."""
        n = len(topics.ESTIMATE_STATE)
        block = np.full((n, n), math.nan)
        block[:3, :3] = self.covariance
        msg = topics.Estimate(t=float(t), method=method,
                              sources=[{"x": float(self.x), "y": float(self.y), "z": float(self.z),
                                        "cps_at_1m": float(self.cps_at_1m)}],
                              background_cps=float(self.background_cps), covariance=block.ravel().tolist())
        msg.validate()
        return msg

    def replace(self, **changes: Any) -> SourceEstimate:
        """A copy with ``changes`` (``dataclasses.replace``)."""
        return replace(self, **changes)


__all__ = ["JSON_KEYS", "SourceEstimate"]
