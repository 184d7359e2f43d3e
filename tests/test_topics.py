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
