"""Session-wide test setup: keep ROS 2 traffic private to this test run.

At import (before any test module imports rclpy) this sets
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a ``ROS_DOMAIN_ID`` chosen for this pytest
session, so two test runs on one machine never hear each other. The domain is
``1 + pid % 101`` (1..101), or the value of ``SINS_ALIGN_TEST_DOMAIN`` when that is set.
"""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parent.parent


def _session_domain_id() -> str:
    forced = os.environ.get('SINS_ALIGN_TEST_DOMAIN')
    if forced:
        if not forced.isdigit() or not 0 <= int(forced) <= 232:
            raise ValueError(f'SINS_ALIGN_TEST_DOMAIN must be an integer 0..232, got {forced!r}')
        return forced
    return str(1 + os.getpid() % 101)


os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_DOMAIN_ID'] = _session_domain_id()


def pytest_report_header(config):
    return (f"ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']} "
            f"ROS_AUTOMATIC_DISCOVERY_RANGE={os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE']}")


@pytest.fixture(scope='session')
def repo_root() -> Path:
    """The repository root (the parent of test/)."""
    return REPO_ROOT
