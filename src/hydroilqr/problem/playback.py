"""The choices of ``hydroilqr playback`` (control/playback.py): its policy and feed-forward."""

from __future__ import annotations

PLAYBACK_POLICIES = ("pd", "ilqr")  # playback: PD+ around the plan, or its iLQR gains
# playback's PD+ feed-forward: ū dynamically scaled to the speed, or the plan's unchanged
PLAYBACK_FEEDFORWARDS = ("scaled", "plan")
