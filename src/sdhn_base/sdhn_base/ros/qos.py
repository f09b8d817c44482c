"""Every QoS profile of the sdhn graph, defined once and chosen by name (docs/ros-graph.md).

A publisher and its subscribers must use the same profile: a reliable subscriber never matches a
best-effort publisher, and a transient-local subscriber gets nothing latched from a volatile one.
"""

from __future__ import annotations

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

# Lock-step traffic (observations, actions, team state, episode summaries): nothing may be lost.
# In the loop itself at most 2 messages per topic are ever outstanding; the depth is for the
# observers (trainer, recorder), whose callbacks may fall behind for a while, and it must hold on
# the writer's side too (a reliable KEEP_LAST writer forgets unacknowledged samples beyond it).
# From measured rates: the fastest loop reaches ~1,200 team steps/s (bench_ros, N=4; ~130/s at
# N=20), and an observer may stall up to 0.2 s (the trainer's executor lag, once its learner
# moved out of process, stays below that: trainer.status.json, executor_lag_max_ms), so
# 1,200/s x 0.2 s = 240 -> 256. Memory only matters when a queue really fills (~0.3 kB/sample).
STEP_DEPTH = 256
STEP = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=STEP_DEPTH,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

# An actor's observations under the simulator's realtime clock: the world does not wait, so an
# actor that fell behind acts on the newest observation and skips the older ones (a robot's
# perception does the same). Matches STEP writers: history depth is not part of QoS matching.
STEP_NEWEST = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
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

# A recorder of a latched topic: it matches LATCHED writers (late joiners still get only the
# latest version) but keeps every version that reaches it. With LATCHED's depth 1 on the reader,
# a version still waiting for the recorder's callback is overwritten by the next one (seen as a
# recording with 1 of 2 weights versions when they were published back to back).
LATCHED_RECORDER = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=16,
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

# /diagnostics, as diagnostic_updater publishes it (reliable, volatile): a reliable writer also
# matches best-effort readers (Foxglove, rqt_robot_monitor), one array per node per second.
DIAGNOSTICS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)

# Standard viewer topics (robot poses, an actor's target pose): the newest pose is what counts, a
# viewer that falls behind loses old ones, and a reliable writer matches every kind of reader.
POSES = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=4,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
