"""An input subscription whose reliability follows what the publishers offer.

Large messages (a 640x480 PointCloud2 is 3.7-4.9 MB) sent by a *reliable* publisher to a
*best-effort* subscription are fragmented and never repaired: with the middleware's
defaults every such frame is lost, while reliable on both sides delivers each one.  A
reliable subscription, on the other hand, does not match a best-effort publisher at all.
So, like rosbag2's recorder, :class:`AdaptiveSubscription` (mode ``auto``) looks at the
QoS of the topic's publishers (``get_publishers_info_by_topic``) and subscribes reliable
when every publisher is reliable, best effort otherwise (and best effort while there is no
publisher yet: it matches any).  :meth:`AdaptiveSubscription.update` re-checks and
re-creates the subscription when the choice changes, e.g. when a publisher appears after
the node started; the node calls it from a timer.  Modes ``reliable`` and
``best_effort`` fix the reliability.  Durability is always volatile (it matches
volatile and transient-local publishers).
"""

from __future__ import annotations

from typing import Any, Callable

from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

__all__ = ["AdaptiveSubscription", "RELIABILITY_MODES"]

#: Allowed values of the node's ``qos_reliability``.
RELIABILITY_MODES = ("auto", "best_effort", "reliable")
_POLICY = {"best_effort": ReliabilityPolicy.BEST_EFFORT, "reliable": ReliabilityPolicy.RELIABLE}


class AdaptiveSubscription:
    """One subscription of ``node`` whose reliability is fixed or follows the publishers.

    Parameters
    ----------
    node : rclpy.node.Node
        Owner of the subscription.
    msg_type : type
        Message class.
    topic : str
        Topic name relative to the node (remappings and namespace apply).
    callback : callable
        Called with each message.
    depth : int
        History depth (keep last), in [1, inf).
    mode : {'auto', 'best_effort', 'reliable'}
        ``auto``: reliable iff every publisher of the topic is reliable.
    """

    def __init__(self, node: Node, msg_type: type, topic: str, callback: Callable[[Any], None],
                 depth: int, mode: str) -> None:
        if mode not in RELIABILITY_MODES:
            raise ValueError(f"mode must be one of {', '.join(RELIABILITY_MODES)}, got {mode!r}")
        self._node, self._type, self._callback = node, msg_type, callback
        self._depth, self.mode = int(depth), mode
        self.topic_name = node.resolve_topic_name(topic)
        self.reliability: str | None = None  # of the current subscription
        self.subscription = None
        self.update()

    def _wanted(self) -> str | None:
        """Return the reliability to subscribe with; None to keep the current one."""
        if self.mode != "auto":
            return self.mode
        publishers = self._node.get_publishers_info_by_topic(self.topic_name)
        if not publishers:  # keep what matched so far; best effort matches anyone
            return None if self.reliability else "best_effort"
        reliable = all(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE
                       for p in publishers)
        return "reliable" if reliable else "best_effort"

    def update(self) -> bool:
        """Re-check the publishers; re-subscribe if the reliability must change.

        Returns
        -------
        bool
            True when the subscription was (re-)created.
        """
        wanted = self._wanted()
        if wanted is None or wanted == self.reliability:
            return False
        if self.subscription is not None:
            self._node.destroy_subscription(self.subscription)
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=self._depth,
                         reliability=_POLICY[wanted], durability=DurabilityPolicy.VOLATILE)
        self.subscription = self._node.create_subscription(self._type, self.topic_name,
                                                           self._callback, qos)
        changed = self.reliability is not None
        self.reliability = wanted
        if changed or self.mode == "auto":
            self._node.get_logger().info(
                f"subscribed to '{self.topic_name}' {wanted.replace('_', ' ')}"
                + (" (qos_reliability auto: publishers "
                   f"{'all reliable' if wanted == 'reliable' else 'not all reliable or none yet'})"
                   if self.mode == "auto" else ""))
        return True
