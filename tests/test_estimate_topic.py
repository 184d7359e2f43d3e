"""Producer -> zenoh topic -> consumer: a fitted localizer's estimate reaches the planner's belief intact."""

import threading
import time

import numpy as np

from benchmarks.analytic_flights import lattice_flight
from estimator.localizers import make_localizer
from planner.belief import SourceBelief
from radseek import topics
from radseek.zenoh_session import open_session


def test_a_localizer_estimate_crosses_zenoh_into_the_planner_belief(router):
    ds = lattice_flight(0)
    loc = make_localizer("mle", n_starts=1).fit(ds)
    sent = loc.to_estimate(t=12.5)
    cov = np.asarray(loc.covariance_)
    assert np.count_nonzero(cov[:3, :3] - np.diag(np.diag(cov[:3, :3]))), "want off-diagonal terms to carry"

    key = topics.key(topics.ESTIMATE)
    got: list[topics.Estimate] = []
    arrived = threading.Event()

    def on_estimate(sample) -> None:
        got.append(topics.Estimate.from_bytes(sample.payload.to_bytes()))  # validates the declared layout
        arrived.set()

    with open_session(connect=router) as producer, open_session(connect=router) as consumer:
        sub = consumer.declare_subscriber(key, on_estimate)
        pub = producer.declare_publisher(key)
        deadline = time.monotonic() + 20.0  # the subscription reaches the router asynchronously
        while not arrived.wait(0.1) and time.monotonic() < deadline:
            pub.put(sent.to_bytes())
        sub.undeclare()
    assert got, "no estimate arrived over zenoh"

    msg = got[0]
    assert msg == sent  # every covariance number survives the JSON round trip exactly
    assert len(msg.covariance) == topics.ESTIMATE_BLOCK * len(loc.sources_)
    np.testing.assert_array_equal(np.asarray(msg.covariance_block(0)), cov[:4, :4])

    belief = SourceBelief.from_estimate(msg)
    np.testing.assert_array_equal(belief.mean, loc.position_)
    np.testing.assert_allclose(belief.covariance, (cov[:3, :3] + cov[:3, :3].T) / 2, rtol=0, atol=1e-15)
    assert belief.cps_at_1m == loc.sources_[0]["cps_at_1m"] and belief.background_cps == loc.background_
