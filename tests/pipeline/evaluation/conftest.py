"""Shared fixture: the link budget (helpers live in synthetic_reads.py)."""

from __future__ import annotations

import pytest


@pytest.fixture
def budget():
    """The project's link budget (propagation.LinkBudget) with its defaults."""
    prop = pytest.importorskip("propagation")
    if not hasattr(prop, "LinkBudget"):
        pytest.skip("propagation.LinkBudget not available yet")
    return prop.LinkBudget()
