"""The threads one analysis may use (core.threads): the environment's word, else the cores the
process may run on; GLR's default follows it and gives the same results on any count."""
from __future__ import annotations

import os

import pytest

from flight_fdi.core.errors import CoreError
from flight_fdi.core.glr import GlrConfig
from flight_fdi.core.threads import ENV, usable_threads


def test_the_environment_sets_the_threads(monkeypatch):
    monkeypatch.setenv(ENV, "3")
    assert usable_threads() == 3
    monkeypatch.setenv(ENV, " 1 ")
    assert usable_threads() == 1


def test_without_the_environment_the_cores_of_the_process_count(monkeypatch):
    monkeypatch.delenv(ENV, raising=False)
    assert usable_threads() == len(os.sched_getaffinity(0))


@pytest.mark.parametrize("bad", ["0", "-2", "two", "1.5"])
def test_a_bad_value_is_a_clear_error(monkeypatch, bad):
    monkeypatch.setenv(ENV, bad)
    with pytest.raises(CoreError, match=ENV):
        usable_threads()


def test_glr_threads_default_to_the_process_budget_and_are_validated():
    assert GlrConfig().threads is None
    assert GlrConfig(threads=1).threads == 1
    for bad in (0, True, 1.5):
        with pytest.raises(CoreError, match="threads"):
            GlrConfig(threads=bad)
