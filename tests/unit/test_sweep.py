"""studies.sweep pure logic: values and grids."""

from __future__ import annotations

import pytest


def test_parse_values_and_grid_edges():
    from hydroilqr.problem.config import ConfigError
    from hydroilqr.studies.sweep import grid, parse_values

    assert parse_values("linspace:0:0.3:4") == [0.0, 0.1, 0.2, 0.3]  # not 0.09999999999999999
    with pytest.raises(ConfigError, match="positive START and STOP"):
        parse_values("logspace:1:0:3")
    with pytest.raises(ConfigError, match="positive START and STOP"):
        parse_values("logspace:1:-10:3")
    g = grid([("a", [1, 2]), ("b", [3, 4, 5])])
    assert g == [{"a": a, "b": b} for a in (1, 2) for b in (3, 4, 5)]  # first varies slowest
