"""The typed in-flight estimate (``radseek.estimate.SourceEstimate``, issue 31 item 3): its covariance layout and
its converters to and from the summary JSON and the zenoh ``estimate`` message."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from planner.belief import SourceBelief
from radseek import topics
from radseek.estimate import JSON_KEYS, SourceEstimate

COV = [[0.04, 0.01, 0.0], [0.01, 0.09, 0.002], [0.0, 0.002, 0.25]]


def _record(**over) -> dict:
    """A record as ``estimator.inflight.InflightEstimator.update`` then ``finalize`` write it."""
    rec = {"dwell": 7, "x": 1.5, "y": -2.25, "z": 0.0, "cps_at_1m": 1600.0, "background_cps": 31.5,
           "covariance": COV, "sigma_m": 0.3, "effects": ["wall_attenuation"], "params": {"wall0.mu": 0.4},
           "converged": True, "p_value": 0.42, "drift_floor_m": 0.12, "pose_sd_m": 0.15,
           "ellipse_95": {"a_m": 0.74, "b_m": 0.48, "angle_deg": 71.0}, "bound_m": 0.21}
    rec.update(over)
    return rec


def test_json_round_trip_keeps_keys_order_and_values():
    rec = _record()
    est = SourceEstimate.from_json(rec)
    assert est.effects == ("wall_attenuation",) and est.params == {"wall0.mu": 0.4} and est.dwell == 7
    assert est.to_json() == rec and list(est.to_json()) == list(rec) == list(JSON_KEYS)
    # through the file as mission_summary.json writes it (inf sigma included)
    again = SourceEstimate.from_json(json.loads(json.dumps(est.replace(sigma_m=math.inf).to_json())))
    assert again.sigma_m == math.inf and again.to_json()["covariance"] == COV


def test_json_before_finalize_and_from_older_records():
    rec = _record()
    del rec["ellipse_95"], rec["bound_m"]
    est = SourceEstimate.from_json(rec)
    assert est.ellipse_95 is None and est.bound_m is None
    assert est.to_json() == rec  # no keys added before the mission finalizes it
    old = {k: rec[k] for k in ("x", "y", "z", "cps_at_1m", "background_cps", "covariance", "sigma_m")}
    old["note"] = "kept"
    est = SourceEstimate.from_json(old)
    assert math.isnan(est.p_value) and math.isnan(est.drift_floor_m) and est.converged and est.dwell == 0
    assert est.to_json()["note"] == "kept"
    # before estimator.inflight the record held the localizer's 4 x 4 over (x, y, z, cps_at_1m)
    four = np.eye(4) * 100.0
    four[:3, :3] = COV
    est = SourceEstimate.from_json({"x": 1.0, "y": 2.0, "covariance": four.tolist(), "sigma_m": 0.3})
    np.testing.assert_array_equal(est.covariance, COV)
    assert est.z == 0.0 and math.isnan(est.cps_at_1m)
    with pytest.raises(KeyError, match="covariance"):
        SourceEstimate.from_json({k: v for k, v in rec.items() if k != "covariance"})


def test_the_covariance_is_the_3x3_position_block():
    est = SourceEstimate.from_json(_record())
    assert est.covariance.shape == (3, 3) and not est.covariance.flags.writeable
    np.testing.assert_array_equal(est.position, [1.5, -2.25, 0.0])
    with pytest.raises(ValueError, match=r"\(3, 3\)"):
        SourceEstimate(0.0, 0.0, 0.0, 1.0, 0.0, np.eye(4))  # the topic's 4 x 4 is not this record's layout


def test_topic_round_trip():
    est = SourceEstimate.from_json(_record())
    msg = topics.Estimate.from_bytes(est.to_topic(t=12.5, method="mle").to_bytes())  # validates the layout
    assert msg.t == 12.5 and msg.method == "mle" and msg.crlb is None
    block = np.asarray(msg.covariance_block(0))
    np.testing.assert_array_equal(block[:3, :3], est.covariance)
    assert np.isnan(block[3]).all() and np.isnan(block[:, 3]).all()  # the strength's: unknown
    back = SourceEstimate.from_topic(msg, p_value=est.p_value, dwell=est.dwell)
    for key in ("x", "y", "z", "cps_at_1m", "background_cps", "p_value", "dwell"):
        assert getattr(back, key) == getattr(est, key), key
    np.testing.assert_array_equal(back.covariance, est.covariance)
    assert back.sigma_m == pytest.approx(math.sqrt(np.linalg.eigvalsh(np.asarray(COV)[:2, :2]).max()))


def test_from_topic_reads_a_localizer_message_as_the_planner_does():
    """A localizer's message (4 x 4 blocks over x, y, z, cps_at_1m, two sources): source 1's position block,
    symmetrised; the planner's belief of the message is the same numbers."""
    full = np.arange(16.0).reshape(4, 4) / 100 + np.eye(4)
    src = {"x": 1.0, "y": 2.0, "z": 0.5, "cps_at_1m": 900.0}
    msg = topics.Estimate(t=3.0, method="mle", sources=[src, {**src, "x": 4.0}], background_cps=25.0,
                          covariance=[*np.eye(4).ravel().tolist(), *full.ravel().tolist()])
    est = SourceEstimate.from_topic(msg, source=1)
    assert est.x == 4.0 and est.background_cps == 25.0
    np.testing.assert_allclose(est.covariance, (full[:3, :3] + full[:3, :3].T) / 2)
    belief = SourceBelief.from_estimate(msg, source=1)
    np.testing.assert_array_equal(belief.covariance, est.covariance)
    np.testing.assert_array_equal(belief.mean, est.position)
    with pytest.raises(topics.PayloadError):
        SourceEstimate.from_topic(topics.Estimate(t=0.0, method="x", sources=[src], background_cps=1.0,
                                                  covariance=[1.0, 0.0, 0.0, 1.0]))
