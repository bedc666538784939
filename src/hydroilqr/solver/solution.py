"""The result of a solve: trajectory, feedback gains and per-iteration statistics."""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hydroilqr.io.files import atomic_savez
from hydroilqr.io.rundir import solution_file
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.inputs import MAX_ARRAY_FILE_BYTES, check_npz

PHASES = ("rollout", "derivatives", "backward_pass", "line_search")


def load_run_solution(path: str | Path, key: str) -> tuple[Solution, Path]:
    """The Solution of a solved run given as its directory or its solution.npz, and the file's
    path; ConfigError naming ``key`` (the option that pointed there) if it cannot be read."""
    path = solution_file(path)
    try:
        return Solution.load(path), path
    except ValueError as e:  # foreign file or arrays that disagree
        why = str(e).removeprefix(f"{path}: ")
        raise ConfigError(f"{key}: cannot read {path}: {why}") from None
    except KeyError as e:  # an npz without one of a solution's arrays
        missing = str(e.args[0] if e.args else "?").split(" is not a file")[0]
        raise ConfigError(
            f"{key}: cannot read {path}: not a solution file (no array {missing!r})"
        ) from None
    except Exception as e:  # noqa: BLE001 - missing or torn file
        raise ConfigError(f"{key}: cannot read {path} ({type(e).__name__})") from None


@dataclass
class Solution:
    """An iLQR solution.

    X: [N+1, nx] states, U: [N, nu] inputs, K: [N, nu, nx] feedback gains and
    kappa: [N, nu] feedforward terms of eqs. (7)-(8), t: [N+1] time grid (s),
    costs: [iterations+1] cost before the first and after every iteration,
    iteration_seconds: wall time per iteration, phase_seconds: phase -> per-iteration seconds
    (rollout, derivatives, backward_pass, line_search).

    ``reason``: the test that stopped the solve; ``status``: what the result is worth, one of
    converged, stalled, max_iterations, line_search_failed, no_progress, interrupted,
    callback, deadline, failed (defined in ``hydroilqr.solver.stopping``; "" when unknown,
    e.g. a file from an older version or an MPC run); ``converged`` is true only for
    converged and stalled (a convergence test held after the plan improved on its initial
    guess). ``explain(solution, task)`` (``hydroilqr.solver.explain``) says why in a sentence.
    """

    X: np.ndarray
    U: np.ndarray
    K: np.ndarray
    kappa: np.ndarray
    t: np.ndarray
    costs: np.ndarray
    iteration_seconds: list[float]
    phase_seconds: dict[str, list[float]]
    converged: bool
    reason: str
    derivatives: str
    eps: list[float] = field(default_factory=list)
    mu: list[float] = field(default_factory=list)
    extra: dict = field(default_factory=dict)  # e.g. receding-horizon per-resolve stats
    status: str = ""

    def __repr__(self) -> str:  # the arrays' shapes, not their thousands of numbers
        shapes = ", ".join(
            f"{k} {list(np.shape(getattr(self, k)))}" for k in ("X", "U", "K", "kappa", "t")
        )
        return (
            f"Solution({shapes}; status={self.status!r}, reason={self.reason!r}, "
            f"converged={self.converged}, "
            f"iterations={self.iterations}, initial_cost={self.initial_cost:.6g}, "
            f"final_cost={self.final_cost:.6g}, total_seconds={self.total_seconds:.3g})"
        )

    @property
    def iterations(self) -> int:
        return len(self.iteration_seconds)

    @property
    def initial_cost(self) -> float:
        """The cost of the initial guess on the task's model (a continuation's first cost is
        its first stage model's; the task's own is kept in ``extra``; for an ensemble solve
        after a warm start, its objective's), as in summary.json."""
        return float(self.extra.get("task_initial_cost", self.costs[0]))

    @property
    def final_cost(self) -> float:
        return float(self.costs[-1])

    @property
    def total_seconds(self) -> float:
        return float(np.sum(self.iteration_seconds))

    def stats(self) -> dict:
        return {
            "converged": bool(self.converged),
            "reason": self.reason,
            "status": self.status,
            "iterations": self.iterations,
            "final_cost": self.final_cost,
            "initial_cost": self.initial_cost,
            "costs": [float(c) for c in self.costs],
            "iteration_seconds": [float(s) for s in self.iteration_seconds],
            "phase_seconds": {k: [float(x) for x in v] for k, v in self.phase_seconds.items()},
            "total_seconds": self.total_seconds,
            "derivatives": self.derivatives,
        }

    def save(self, path: str | Path) -> Path:
        """Writes an .npz with the arrays and the statistics (as JSON inside) and returns its
        path: ``path`` (``.npz`` appended if missing), or ``path/solution.npz`` if ``path`` is
        a directory (as in a run directory). ``Solution.load`` reads either back."""
        path = Path(path)
        if path.is_dir():
            path = path / "solution.npz"
        elif path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        if not path.parent.is_dir():  # else numpy names the temporary file below
            raise FileNotFoundError(f"Solution.save({str(path)!r}): no directory {path.parent}")
        atomic_savez(
            path,
            X=self.X,
            U=self.U,
            K=self.K,
            kappa=self.kappa,
            t=self.t,
            costs=self.costs,
            meta=np.array(
                json.dumps({**self.stats(), "eps": self.eps, "mu": self.mu, "extra": self.extra})
            ),
        )
        return path

    @staticmethod
    def load(path: str | Path) -> Solution:
        """From a file written by ``save`` (the path given to it, with or without ``.npz``), or
        a run directory holding solution.npz."""
        path = solution_file(path)
        check_npz(path, "solution file", MAX_ARRAY_FILE_BYTES)
        try:
            d = np.load(path, allow_pickle=False)
        except (ValueError, EOFError, zipfile.BadZipFile):  # OSErrors pass as they are
            raise ValueError(f"{path}: not a file written by Solution.save") from None
        with d:
            meta = json.loads(str(d["meta"]))
            sol = Solution(
                X=d["X"],
                U=d["U"],
                K=d["K"],
                kappa=d["kappa"],
                t=d["t"],
                costs=d["costs"],
                iteration_seconds=meta["iteration_seconds"],
                phase_seconds=meta["phase_seconds"],
                converged=meta["converged"],
                reason=meta["reason"],
                derivatives=meta["derivatives"],
                eps=meta.get("eps", []),
                mu=meta.get("mu", []),
                extra=meta.get("extra", {}),
                status=meta.get("status", ""),
            )
        sol.check_shapes(path)
        for name in ("X", "U", "K", "t"):  # a solve never writes these; an edited file might
            if not np.isfinite(getattr(sol, name)).all():
                raise ValueError(f"{path}: its {name} holds non-finite (NaN or infinite) values")
        return sol

    def check_shapes(self, where: str | Path = "solution") -> None:
        """ValueError unless X [N+1, nx], U [N, nu], K [N, nu, nx], kappa [N, nu], t [N+1]
        agree with each other."""
        X, U, K, kappa, t = (np.asarray(a) for a in (self.X, self.U, self.K, self.kappa, self.t))
        ok = X.ndim == 2 and U.ndim == 2 and X.shape[0] == U.shape[0] + 1 and t.shape == X.shape[:1]
        if ok:
            N, nu, nx = U.shape[0], U.shape[1], X.shape[1]
            ok = K.shape in ((N, nu, nx), (0,)) and kappa.shape in ((N, nu), (0,))
        if not ok:
            raise ValueError(
                f"{where}: arrays disagree (X {list(X.shape)}, U {list(U.shape)}, "
                f"K {list(K.shape)}, kappa {list(kappa.shape)}, t {list(t.shape)}; expected "
                "X [N+1, nx], U [N, nu], K [N, nu, nx], kappa [N, nu], t [N+1])"
            )
