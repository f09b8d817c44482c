"""The one team-namespace rule and the topic names (sdhn_base.ros.topics), without ROS."""

from __future__ import annotations

import pytest

from sdhn_base.ros import topics


@pytest.mark.parametrize("ns", ["/sdhn", "/lab/team_2", "/a", "/sdhn_launch_on_failure"])
def test_namespaces_that_follow_the_rule(ns: str) -> None:
    assert topics.is_team_ns(ns) and topics.check_team_ns(ns) == ns


@pytest.mark.parametrize("ns", ["sdhn", "/sdhn/", "/", "", "/1team", "/a__b", "/a b", "//a",
                                "/a/_b", 3, None])
def test_namespaces_that_break_the_rule(ns: object) -> None:
    assert not topics.is_team_ns(ns)
    with pytest.raises(topics.NamespaceError, match=r"team_ns: .*allowed: an absolute namespace"):
        topics.check_team_ns(ns)


def test_names_resolve_under_the_team_and_robot_namespaces() -> None:
    assert topics.absolute("/sdhn", topics.STATE) == "/sdhn/state"
    assert topics.absolute("/t/x", topics.WEIGHTS) == "/t/x/policy/weights"
    assert topics.absolute("/sdhn", topics.robot_obs(3)) == "/sdhn/robot_3/obs"
    assert topics.absolute("/sdhn", topics.robot_action(12)) == "/sdhn/robot_12/action"


def test_topics_are_read_back() -> None:
    assert topics.robot_of("robot_12/action") == (12, "action")
    assert topics.robot_of("robot_x/obs") is None and topics.robot_of("state") is None
    assert topics.relative_to("/sdhn", "/sdhn/robot_2/obs") == "robot_2/obs"
    assert topics.relative_to("/sdhn", "/sdhnx/state") is None
    assert topics.team_of("/sdhn/state", topics.STATE) == "/sdhn"
    assert topics.team_of("/lab/t/policy/weights", topics.WEIGHTS) == "/lab/t"
    assert topics.team_of("/state", topics.STATE) is None
    assert topics.team_of("/sdhn/other", topics.STATE) is None
