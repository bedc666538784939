"""Task goals: declared in task files, validated on load, evaluated on a run's metrics."""

import pytest

from hydroilqr import ConfigError, Task
from hydroilqr.metrics.goals import evaluate, lookup, verdict_line
from hydroilqr.problem.goal import GoalCheck


def test_every_builtin_task_declares_a_goal():
    from hydroilqr.problem.files import list_tasks

    for name in list_tasks():
        assert Task.load(name, smoke=True).config.goal, name


def test_min_max_bounds():
    goal = {"err": GoalCheck(max=0.03), "lift": GoalCheck(min=0.1)}
    ok = evaluate(goal, {"err": 0.011, "lift": 0.2})
    assert ok["met"] is True and all(c["passed"] for c in ok["checks"])
    bad = evaluate(goal, {"err": 0.067, "lift": 0.2})
    assert bad["met"] is False
    assert bad["checks"][0]["passed"] is False and "0.067 > 0.03" in bad["checks"][0]["why"]
    assert verdict_line(bad).startswith("goal: FAIL (1/2 checks)")
    assert verdict_line(ok) == "goal: PASS (2/2 checks)"


def test_comparison_with_another_metric_and_nested_names():
    goal = {"diagonal": GoalCheck(above="lateral"), "duty.FL": GoalCheck(min=0.2)}
    assert evaluate(goal, {"diagonal": 0.16, "lateral": 0.15, "duty": {"FL": 0.3}})["met"]
    res = evaluate(goal, {"diagonal": 0.719, "lateral": 0.737, "duty": {"FL": 0.3}})
    assert res["met"] is False and "lateral" in res["checks"][0]["why"]
    # a tie is not "above"
    assert not evaluate(goal, {"diagonal": 0.5, "lateral": 0.5, "duty": {"FL": 0.3}})["met"]


def test_comparison_by_a_margin():
    goal = {
        "diagonal": GoalCheck(above="lateral", margin=0.2),
        "low": GoalCheck(below="high", margin=0.1),
    }
    ok = evaluate(goal, {"diagonal": 0.71, "lateral": 0.5, "low": 0.3, "high": 0.41})
    assert ok["met"] is True
    res = evaluate(goal, {"diagonal": 0.69, "lateral": 0.5, "low": 0.35, "high": 0.41})
    assert [c["passed"] for c in res["checks"]] == [False, False]
    assert "0.69 <= lateral 0.5 + 0.2" in res["checks"][0]["why"]
    assert "0.35 >= high 0.41 - 0.1" in res["checks"][1]["why"]
    assert res["checks"][0]["require"] == "> lateral + 0.2"
    t = Task.load("cheetah-trot-1.0", ["goal.diagonal_pair_overlap.margin=0.2"], smoke=True)
    assert t.config.goal["diagonal_pair_overlap"].margin == 0.2


def test_missing_or_nonfinite_metric_fails_its_check():
    goal = {"target_error_m": GoalCheck(max=0.03)}
    res = evaluate(goal, {})
    assert res["met"] is False and res["checks"][0]["why"] == "not reported by this run"
    res = evaluate(goal, {"target_error_m": float("nan")})
    assert res["met"] is False and "not a finite number" in res["checks"][0]["why"]


def test_no_goal_is_neither_pass_nor_fail():
    assert evaluate({}, {"x": 1.0}) == {"met": None, "checks": []}
    assert verdict_line(evaluate({}, {})) == "goal: none declared"


def test_dotted_lookup_prefers_whole_keys():
    assert lookup({"a.b": 1, "a": {"b": 2}}, "a.b") == 1
    assert lookup({"a": {"b": {"c": 3}}}, "a.b.c") == 3
    assert lookup({"a": 1}, "a.b") is None


@pytest.mark.parametrize(
    "override, message",
    [
        ("goal.final_angle_error_rad={}", "give at least one of"),
        ("goal.x={min: 2, max: 1}", "min 2 is above max 1"),
        ("goal.x={maximum: 1}", "unknown key"),
        ("goal.x={max: abc}", "expected a number"),
        ("goal.x={max: 1, margin: 0.1}", "goal.x.margin: a margin needs above or below"),
        ("goal.x={above: y, margin: -0.1}", "goal.x.margin: expected a number >= 0"),
    ],
)
def test_bad_goals_are_refused_on_load(override, message):
    with pytest.raises(ConfigError, match=message):
        Task.load("cartpole-wall", [override], smoke=True)


def test_goal_on_a_nested_metric_from_the_command_line():
    t = Task.load("cheetah-trot-1.0", ["goal.duty_factor.FL.min=0.2"], smoke=True)
    assert t.config.goal["duty_factor.FL"].min == 0.2


def test_each_check_records_its_slack_to_the_nearest_bound():
    """How far inside its nearest bound a value is (negative beyond it), in its units: what
    robustness's per-check spread reports (issue 54, item 6)."""
    goal = {
        "err": GoalCheck(max=0.02),
        "band": GoalCheck(min=1.0, max=3.0),
        "d": GoalCheck(above="lat", margin=0.2),
    }
    res = evaluate(goal, {"err": 0.0187, "band": 2.5, "d": 0.5, "lat": 0.1})
    slack = {c["metric"]: c["slack"] for c in res["checks"]}
    assert slack["err"] == pytest.approx(0.0013)
    assert slack["band"] == pytest.approx(0.5)  # nearer the max
    assert slack["d"] == pytest.approx(0.2)
    assert evaluate(goal, {"err": 0.03, "band": 0.5, "d": 0.2, "lat": 0.1})["checks"][0][
        "slack"
    ] == pytest.approx(-0.01)
