"""What playback says about saturated commands (issue 39, 3): advice for the policy and
phase where they happened."""

from __future__ import annotations

from types import SimpleNamespace

from hydroilqr.control.playback import _saturation_warning


def _warn(policy: str, saturated: int, in_hold: int) -> str:
    ctl = SimpleNamespace(saturated=saturated, hold_saturated=in_hold)
    return _saturation_warning({"saturated_fraction": 0.62}, ctl, SimpleNamespace(policy=policy))


def test_pd_saturation_advises_gains_and_speed():
    w = _warn("pd", 100, 0)
    assert w.startswith("62% of the commands hit the effort limits")
    assert "lower --kp/--kd, or a slower --speed" in w


def test_ilqr_saturation_in_the_plan_does_not_advise_pd_options():
    w = _warn("ilqr", 100, 10)
    assert "--kp" not in w and "--speed" not in w
    assert "90% of them while playing the plan" in w and "plan's own gains" in w


def test_ilqr_saturation_in_the_hold_advises_the_hold_gains():
    w = _warn("ilqr", 100, 80)
    assert "mostly in the hold after the plan" in w and "--rest-max 0 skips it" in w
    assert "--kp" not in w  # (refused with --policy ilqr)
