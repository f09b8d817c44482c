"""Every QoS profile of the sdhn graph, defined once and chosen by name (docs/ros-graph.md).

A publisher and its subscribers must use the same profile: a reliable subscriber never matches a
best-effort publisher, and a transient-local subscriber gets nothing latched from a volatile one.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Lock-step traffic (observations, actions, team state, episode summaries): nothing may be lost,
# and a deep enough queue absorbs a burst while a callback runs.
STEP = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=64,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

# Policy weights: late joiners (a restarted actor) must receive the latest version at once.
LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

# Visual or diagnostic streams (sampled hypergraphs): dropping one is harmless.
SENSOR = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=4,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)
