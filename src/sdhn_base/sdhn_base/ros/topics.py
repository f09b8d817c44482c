"""Every topic name of the sdhn graph, and the one rule for a team namespace (docs/ros-graph.md).

A team lives under one namespace, e.g. ``/sdhn``. Team-level topics are named relative to it
(``state``, ``episode``, ``policy/weights``, ``hypergraph``), robot topics relative to the robot's
own namespace ``robot_<i>`` under it (``obs``, ``action``). Nodes that run in the team namespace
(the simulator) create their topics with these relative names and ROS resolves them under the
node's namespace; nodes that sit elsewhere (an actor in ``/sdhn/robot_3`` reading the team's
weights, an observer started without a namespace) join them with :func:`absolute`.

No ROS import here: cores, tests and scripts use the same names.
"""

from __future__ import annotations

import re

# Team-level topics, relative to the team namespace.
STATE = "state"  # sdhn_msgs/TeamState, STEP
EPISODE = "episode"  # sdhn_msgs/EpisodeSummary, STEP
WEIGHTS = "policy/weights"  # sdhn_msgs/PolicyWeights, LATCHED
HYPERGRAPH = "hypergraph"  # sdhn_msgs/Hypergraph, SENSOR
POSES = "poses"  # geometry_msgs/PoseArray (frame map, cell centres, 1 cell = 1 m), POSES
# Robot topics, relative to the robot's namespace robot_<i>.
OBS = "obs"  # sdhn_msgs/RobotObservation, STEP
ACTION = "action"  # sdhn_msgs/RobotAction, STEP
TARGET_POSE = "target_pose"  # geometry_msgs/PoseStamped: the cell the next action moves to, POSES

# ROS-wide standard topics (absolute; shared by every node of every team).
DIAGNOSTICS = "/diagnostics"  # diagnostic_msgs/DiagnosticArray, DIAGNOSTICS

# Foxglove channels of the viz node and of recordings with viz (absolute: not team topics).
VIZ_SCENE = "/viz/scene"
VIZ_HYPERGRAPH = "/viz/hypergraph"
VIZ_P_H = "/viz/hypergraph/p_h"
VIZ_METRICS = "/viz/metrics"
VIZ_EPISODES = "/viz/episodes"

DEFAULT_TEAM_NS = "/sdhn"
TEAM_NS_RULE = ("an absolute namespace without a trailing '/': one or more /-separated tokens, "
                "each a letter followed by letters, digits or single underscores, e.g. /sdhn")
_TEAM_NS = re.compile(r"^(/[A-Za-z][A-Za-z0-9_]*)+$")
_ROBOT_TOPIC = re.compile(r"^robot_(\d+)/(obs|action)$")


class NamespaceError(ValueError):
    """A team namespace that breaks the rule; the message says the rule. A node that raises it
    while being built stops like on any bad parameter (``sdhn_base.ros.runner``: one line,
    exit 2)."""


def is_team_ns(value: object) -> bool:
    """Whether ``value`` follows the one namespace rule (see :data:`TEAM_NS_RULE`)."""
    return isinstance(value, str) and bool(_TEAM_NS.match(value)) and "__" not in value


def check_team_ns(value: object, field: str = "team_ns") -> str:
    """The one namespace check, made once where a node (or the launcher) takes its namespace;
    returns ``value`` unchanged. ``field`` names where the value came from in the error."""
    if not is_team_ns(value):
        raise NamespaceError(f"{field}: got {value!r}; allowed: {TEAM_NS_RULE}")
    assert isinstance(value, str)
    return value


def robot(i: int) -> str:
    """The namespace of robot ``i`` relative to the team namespace."""
    return f"robot_{i}"


def robot_obs(i: int) -> str:
    return f"{robot(i)}/{OBS}"


def robot_action(i: int) -> str:
    return f"{robot(i)}/{ACTION}"


def robot_target_pose(i: int) -> str:
    return f"{robot(i)}/{TARGET_POSE}"


def robot_of(relative: str) -> tuple[int, str] | None:
    """(robot id, 'obs' | 'action') of a robot topic relative to the team namespace."""
    m = _ROBOT_TOPIC.match(relative)
    return (int(m.group(1)), m.group(2)) if m else None


def absolute(team_ns: str, relative: str) -> str:
    """``relative`` resolved under ``team_ns``, a namespace already checked by
    :func:`check_team_ns` where it was taken (it is not checked again per topic)."""
    return f"{team_ns}/{relative}"


def relative_to(team_ns: str, topic: str) -> str | None:
    """The part of ``topic`` under ``team_ns`` ('/sdhn/robot_2/obs' -> 'robot_2/obs'), else None."""
    prefix = team_ns.rstrip("/") + "/"
    return topic[len(prefix):] if topic.startswith(prefix) else None


def team_of(topic: str, relative: str) -> str | None:
    """The team namespace of ``topic`` if it ends with ``/relative`` ('/sdhn/state' -> '/sdhn')."""
    suffix = "/" + relative
    if not topic.endswith(suffix) or len(topic) == len(suffix):
        return None
    return topic[: -len(suffix)]
