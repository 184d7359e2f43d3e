"""The router's QoS policy for the stack's keys: no publisher can make the router close another's connection.

zenoh 1.x closes a whole transport when a non-droppable message (congestion control BLOCK) cannot be queued
toward it for ``transport/link/tx/queue/congestion_control/block/wait_before_close`` (5 s): a session that
floods with BLOCK toward a slow subscriber got that subscriber's connection cut, and everything it would have
received in between lost (issue 34). The router therefore rewrites, on ingress, every put and delete on
``radseek/**`` to congestion control DROP (under overload a sample is dropped, the connection stays) and
priority ``data``, whatever the publisher asked; the vehicle's ``pose`` and ``sim/*`` keys get ``data_high``,
their own transmit queue, so a flood of detector or mission keys cannot starve them. Only the vehicle's users
may put those keys (``radseek.zenoh_auth``), so nobody else can buy that priority.
"""

from __future__ import annotations

from radseek import topics

#: the keys the vehicle puts that keep a queue of their own ahead of everything else
PRIORITY_TOPICS = (topics.POSE, "sim/**")


def network_qos() -> list[dict]:
    """zenoh's ``qos/network`` section for the router. The rules apply in order, a later one over an earlier
    one: every radseek put DROP at ``data``, then the vehicle's keys at ``data_high``."""
    every = {"id": "radseek-drop", "messages": ["put", "delete"], "flows": ["ingress"],
             "key_exprs": [f"{topics.PREFIX}/**"], "overwrite": {"congestion_control": "drop", "priority": "data"}}
    vehicle = {"id": "radseek-vehicle-first", "messages": ["put", "delete"], "flows": ["ingress"],
               "key_exprs": [f"{topics.PREFIX}/*/{t}" for t in PRIORITY_TOPICS],
               "overwrite": {"congestion_control": "drop", "priority": "data_high"}}
    return [every, vehicle]
