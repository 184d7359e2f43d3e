import pytest

from radseek import topics


def test_keys_live_under_prefix_and_vehicle():
    assert topics.key(topics.HISTOGRAM) == "radseek/uav0/detector/histogram"
    assert topics.key(topics.POSE, "uav7") == "radseek/uav7/pose"
    assert topics.topic_of("radseek/uav7/sim/truth_pose") == topics.SIM_TRUTH_POSE
    with pytest.raises(ValueError):
        topics.key(topics.POSE, "a/b")


def test_histogram_round_trip_and_validation():
    h = topics.Histogram(seq=3, board_time=0.3, t=0.3, duration=0.1, counts=[1] * 32, flags=topics.FLAG_GAP)
    back = topics.Histogram.from_bytes(h.to_bytes())
    assert back == h and back.total == 32 and back.rate == pytest.approx(320)
    with pytest.raises(topics.PayloadError, match="counts"):
        topics.Histogram.from_dict({**h.to_dict(), "counts": [1] * 31})
    with pytest.raises(topics.PayloadError, match=r"counts\[4\]"):
        topics.Histogram.from_dict({**h.to_dict(), "counts": [1] * 4 + [-1] + [1] * 27})
    with pytest.raises(topics.PayloadError, match="missing field 'seq'"):
        topics.Histogram.from_dict({k: v for k, v in h.to_dict().items() if k != "seq"})
    with pytest.raises(topics.PayloadError, match="not JSON"):
        topics.Histogram.from_bytes(b"\xff\x00")


def test_pose_rejects_negative_variance_and_nan():
    with pytest.raises(topics.PayloadError, match="var_x"):
        topics.Pose.from_dict({"t": 0, "x": 0, "y": 0, "z": 1, "yaw": 0, "var_x": -1})
    with pytest.raises(topics.PayloadError, match="finite"):
        topics.Pose.from_dict({"t": 0, "x": float("nan"), "y": 0, "z": 1, "yaw": 0})


def test_estimate_covariance_is_one_4x4_block_per_source():
    src = {"x": 1.0, "y": 2.0, "z": 0.0, "cps_at_1m": 900.0}
    block = [float(k) for k in range(topics.ESTIMATE_BLOCK)]
    est = topics.Estimate(t=1.0, method="mle", sources=[src, src], background_cps=30.0,
                          covariance=[*[-1.0] * 16, *block], crlb=[*block, *[float("nan")] * 16])
    back = topics.Estimate.from_bytes(est.to_bytes())
    assert back.covariance == est.covariance and back.covariance_block(1)[2] == [8.0, 9.0, 10.0, 11.0]
    assert back.covariance_block(0) == [[-1.0] * 4] * 4
    d = est.to_dict()
    with pytest.raises(topics.PayloadError, match="field 'covariance'.*2 source.*16 entries"):
        topics.Estimate.from_dict({**d, "covariance": block})
    with pytest.raises(topics.PayloadError, match=r"covariance\[31\]' must be a number"):
        topics.Estimate.from_dict({**d, "covariance": [*block, *block[:15], block]})  # a block as a list is not
    with pytest.raises(topics.PayloadError, match="field 'crlb'"):
        topics.Estimate.from_dict({**d, "crlb": block * 4})  # the 4M x 4M matrix is not either
    assert "crlb" not in topics.Estimate(**{**vars(est), "crlb": None}).to_dict()  # no bound: left out, not null
    with pytest.raises(topics.PayloadError, match="missing field 'covariance'"):
        topics.Estimate.from_dict({k: v for k, v in d.items() if k != "covariance"})
    with pytest.raises(topics.PayloadError, match=r"sources\[1\] lacks 'z'"):
        topics.Estimate.from_dict({**d, "sources": [src, {"x": 0.0, "y": 0.0, "cps_at_1m": 1.0}]})
