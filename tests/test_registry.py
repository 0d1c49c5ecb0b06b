"""Learner plugins are found by name; unknown names list the choices."""

from __future__ import annotations

import pytest

from learners.base import available, get_learner


def test_builtin_learners():
    assert {"em", "oracle"} <= set(available())
    assert get_learner("em").name == "em"
    assert get_learner("oracle").name == "oracle"


def test_unknown_learner_lists_choices():
    with pytest.raises(ValueError, match="choose from: .*em.*oracle"):
        get_learner("nope")


def test_entry_point_plugins_are_listed(monkeypatch):
    import learners.base as base

    class EP:
        name, value = "mine", "learners.oracle:OracleLearner"

    monkeypatch.setattr(base, "entry_points", lambda group: [EP()] if group == base.ENTRY_POINT_GROUP else [])
    assert available()["mine"] == "learners.oracle:OracleLearner"
    assert get_learner("mine").name == "oracle"
