"""Shared fixtures. ``ros`` gives a private rclpy context + executor (see harness.py)."""
from __future__ import annotations

import pathlib

import pytest

REPO = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture
def ros():
    import harness  # imported lazily: tests of the pure core do not need rclpy

    h = harness.RosHarness()
    try:
        yield h
    finally:
        h.close()


@pytest.fixture(scope="session")
def repo_root() -> pathlib.Path:
    return REPO
