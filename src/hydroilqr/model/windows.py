"""Time shaping of the task-space cost terms (model/terms.py): where a term counts along a
trajectory and its weight factor there.

* ``Terminal``: the last state only, factor 1.
* ``Window(after, until, ramp)``: a running term, at the steps 0..N-1 whose times lie in
  [after, until] (s, inclusive; default the whole trajectory), factor ``scale`` (the time step
  with ``running_cost_dt``, else 1) times its ``Ramp`` (default 1).
* ``Ramp(start, end)``: the factor linear from ``start`` at the window's start to ``end`` at
  its end (a window without ``until`` ends at the task's end).

Times are the task's (``t_k = t0 + k·dt``), so windows and moving targets hold across
receding-horizon windows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Tolerance (s) of a window's ends against the steps' times.
TIME_EPS = 1e-9


@dataclass(frozen=True)
class Terminal:
    def factors(self, times: np.ndarray, scale: float, end_time: float):
        """(active [N+1] bool, factor [N+1]) at the states' ``times`` [N+1]."""
        N = len(times) - 1
        active, factor = np.zeros(N + 1, bool), np.zeros(N + 1)
        active[N] = True
        factor[N] = 1.0
        return active, factor


@dataclass(frozen=True)
class Ramp:
    start: float
    end: float

    def factors(self, times: np.ndarray, after: float, end: float) -> np.ndarray:
        span = end - after
        s = np.clip((times - after) / span, 0.0, 1.0) if span > 0 else np.ones(len(times))
        return self.start + (self.end - self.start) * s


@dataclass(frozen=True)
class Window:
    after: float | None = None
    until: float | None = None
    ramp: Ramp | None = None

    def factors(self, times: np.ndarray, scale: float, end_time: float):
        """(active [N+1] bool, factor [N+1]) at the states' ``times`` [N+1]; the last state
        is a terminal term's (running terms: steps 0..N-1, as Q)."""
        N = len(times) - 1
        a = 0.0 if self.after is None else self.after
        b = np.inf if self.until is None else self.until
        on = (times >= a - TIME_EPS) & (times <= b + TIME_EPS)
        on[N] = False
        ramp = np.ones(N + 1)
        if self.ramp is not None:
            ramp = self.ramp.factors(times, a, end_time if self.until is None else self.until)
        return on, np.where(on, ramp * scale, 0.0)


def time_shaping(terminal: bool, after, until, ramp) -> Terminal | Window:
    """A term's time shaping from its keys (``ramp``: [] or [start, end])."""
    if terminal:
        return Terminal()
    return Window(after, until, Ramp(*ramp) if ramp else None)
