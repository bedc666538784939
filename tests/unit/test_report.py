"""output.report: the output directory of a run."""

from __future__ import annotations

import pytest

from hydroilqr.problem.errors import ConfigError


def test_output_dir_with_unreadable_results_is_left_alone(tmp_path):
    from hydroilqr.output.report import output_dir

    (tmp_path / "summary.json").write_text("{torn")
    with pytest.raises(ConfigError, match="summary.json is unreadable"):
        output_dir(tmp_path, "cartpole-wall")
