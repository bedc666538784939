"""Metric ``kinova``: the Kinova Gen3 whole-arm manipulation tasks (paper §IV-B).

The built-in Kinova tasks select ``metrics: [default, object, kinova]`` with
``metric_params.object: ball``: the ``object`` metric (``hydroilqr.metrics.objects``) gives the
ball's positions, target error, height gain and the links that touched it, and plots
``ball.png``; ``kinova`` adds ``max_arm_<b>_faces`` (most contact polygons between the arm and
the ball at one state), the name the Kinova results have always used for the object metric's
``max_robot_<b>_faces``.

``kinova`` also stands alone for older task files (``metrics: [default, kinova]``, the ball
named by ``metric_params.ball``, default ``ball``): it gives the ``object`` metric's values
(the same ones, computed once per solution) and its plot as well.
"""

from __future__ import annotations

from hydroilqr.metrics.objects import (
    HEADLINE,
    object_metrics,
    object_values,
    plot_files,
    plot_object,
    validate_kinova,
)
from hydroilqr.metrics.registry import Metric, register


def kinova_metrics(task, sol) -> dict:
    """The ``object`` metric's values (computed once per solution, whichever of the two asks
    first) and ``max_arm_<b>_faces``."""
    name, _, faces = object_values(task, sol)
    return {**object_metrics(task, sol), f"max_arm_{name}_faces": faces}


register(
    Metric(
        "kinova",
        compute=kinova_metrics,
        plot=plot_object,
        files=plot_files,
        validate=validate_kinova,
        headline=HEADLINE,
        moves_object=True,
    )
)
