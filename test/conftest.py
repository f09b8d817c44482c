"""Test-wide setup: every run gets its own ROS domain, localhost-only discovery and a log dir.

The variables go into ``os.environ`` before any test starts, so node processes that tests spawn
inherit them and parallel test runs on one machine never see each other's topics.
"""

from __future__ import annotations

import os
import random
import tempfile

import pytest


def _unique_domain_id() -> int:
    # Valid ROS 2 domain ids on Linux are 0..101 without colliding with ephemeral ports; 0 is the
    # default that stray processes use, so draw from 1..101.
    seeded = random.Random(f"{os.getpid()}-{os.times().elapsed}")
    return seeded.randint(1, 101)


def pytest_configure(config: pytest.Config) -> None:
    os.environ.setdefault("ROS_DOMAIN_ID", str(_unique_domain_id()))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("ROS_LOG_DIR", tempfile.mkdtemp(prefix="sdhn-roslog-"))
    os.environ.setdefault("RCUTILS_COLORIZED_OUTPUT", "0")
    os.environ["PYTHONUNBUFFERED"] = "1"


def pytest_report_header(config: pytest.Config) -> str:
    return f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} ROS_LOG_DIR={os.environ['ROS_LOG_DIR']}"
