"""Sampling planners over spline knots: predictive sampling, CEM (with iCEM's additions), MPPI.

A pure function of callables and arrays (in the style of trajax): ``search(evaluate, decode,
nominal, scale, settings)`` perturbs a plan's knots θ: [K, m] (K knots of m inputs), turns
each sample into the arrays a rollout takes with ``decode(θ) -> command`` and asks
``evaluate([command, ...]) -> costs`` for their costs, in the order given (a sample whose
rollout fails costs inf). It returns data and writes nothing.

Each iteration draws every sample's noise centrally from one ``numpy.random.Generator``
seeded with ``settings.seed``, before any is evaluated; where and in how many batches
``evaluate`` runs them cannot change a sample, a cost or the best (ties go to the earlier
sample). Noise is ε·σ with σ: [K, m] (``settings.noise`` times ``scale``: [m]) and ε of a
1/f^β power spectrum along the knots (``colored_noise`` β; iCEM, Pinneri et al. 2020: β = 2
gives smooth, temporally correlated plans, β = 0 white noise). Samples are clipped to
``lower`` / ``upper``: [m] or [K, m] (e.g. effort or joint limits; equal bounds pin a knot).

Methods (``settings.method``):

- ``predictive`` (Howell et al. 2022, mujoco_mpc): the current plan and samples around it;
  the best becomes the plan. σ stays fixed.
- ``cem``: the mean and a per-knot σ are refit to the ``elites`` best of the iteration's
  samples and the elites kept from the previous one (a fraction ``elite_memory``, iCEM), with
  ``smoothing`` weight on the previous values; σ never falls below a tenth of its start.
- ``mppi``: the mean becomes the exp(−(J − J_min) / (λ·spread))-weighted average of the
  samples, λ = ``temperature``, spread the iteration's finite cost range.

Every method evaluates its current mean as sample 0, so the best cost never rises.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

METHODS = ("predictive", "cem", "mppi")
#: CEM's σ is kept above this fraction of its starting value.
MIN_NOISE_FRACTION = 0.1


@dataclass
class Candidate:
    """A sample kept among the search's best: its knots θ: [K, m], command, cost, where."""

    knots: np.ndarray
    command: np.ndarray
    cost: float
    iteration: int
    index: int


@dataclass
class SamplingResult:
    """What a search found. ``best``: the lowest-cost sample; ``candidates``: the best
    ``keep`` distinct samples, lowest cost first; ``mean``: [K, m] the final mean;
    ``costs``: [iterations, samples] every sample's cost (inf: failed rollout); ``history``:
    per iteration {best_cost, iteration_best, median, noise, seconds}; ``interrupted``: Ctrl+C
    (or a callback) ended it early, with what was found until then."""

    best: Candidate
    candidates: list[Candidate]
    mean: np.ndarray
    costs: np.ndarray
    history: list[dict] = field(default_factory=list)
    interrupted: bool = False
    seconds: float = 0.0
    windows: list[dict] = field(default_factory=list)  # a receding search's windows

    @property
    def samples(self) -> int:
        return int(self.costs.size)

    @property
    def best_costs(self) -> np.ndarray:
        """The best cost so far after each iteration: [iterations]."""
        return np.array([h["best_cost"] for h in self.history])


def colored_noise(rng: np.random.Generator, beta: float, shape: tuple) -> np.ndarray:
    """Normal samples of unit variance with a 1/f^β power spectrum along the last axis:
    ``shape`` = (..., n) (β = 0: white). iCEM's construction (``colorednoise``): random
    Fourier coefficients scaled by f^(−β/2) (the mean's by the lowest frequency's, 1/n),
    transformed back and divided by their exact standard deviation."""
    n = shape[-1]
    if beta == 0 or n < 2:
        return rng.standard_normal(shape)
    f = np.fft.rfftfreq(n)
    f[0] = 1.0 / n
    s = f ** (-beta / 2.0)
    coeff = rng.standard_normal((*shape[:-1], len(f), 2)) * s[:, None]
    z = coeff[..., 0] + 1j * coeff[..., 1]
    real = [0, len(f) - 1] if n % 2 == 0 else [0]  # coefficients of a real signal
    z[..., real] = z[..., real].real * math.sqrt(2)
    complex_ = np.ones(len(f), bool)
    complex_[real] = False
    # var y_t = (Σ_real 2 s² + Σ_complex 4 s²) / n², the same at every t
    var = (2.0 * np.sum(s[real] ** 2) + 4.0 * np.sum(s[complex_] ** 2)) / n**2
    return np.fft.irfft(z, n=n, axis=-1) / math.sqrt(var)


@dataclass
class _State:
    mean: np.ndarray
    sigma: np.ndarray
    elites: list = field(default_factory=list)  # cem: (cost, knots) kept from the last iteration


def search(
    evaluate: Callable[[list[np.ndarray]], Sequence[float]],
    decode: Callable[[np.ndarray], np.ndarray],
    nominal: np.ndarray,
    scale: np.ndarray,
    settings,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    keep: int = 1,
    on_iteration: Callable[[dict], bool | None] | None = None,
) -> SamplingResult:
    """Searches over knots θ: [K, m] from ``nominal`` θ0: [K, m].

    ``evaluate(commands) -> costs`` (a list of decoded samples in, one cost each out),
    ``decode(θ) -> command``; ``scale``: [m] the noise unit per input; ``settings``: any
    object with method, samples, iterations, noise, elites, elite_memory, colored_noise,
    smoothing, temperature, seed (``problem.search.SearchConfig``); ``lower``/``upper``: [m]
    or [K, m] bounds on θ (None: unbounded); ``keep``: how many distinct best samples to return;
    ``on_iteration(info)`` after each iteration (info: the history entry and ``iteration``);
    returning True stops the search. Ctrl+C (KeyboardInterrupt) ends it with the best so far
    (``interrupted``)."""
    if settings.method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {settings.method!r}")
    nominal = np.asarray(nominal, float)
    rng = np.random.default_rng(int(settings.seed))
    lo = np.full(nominal.shape, -np.inf) if lower is None else np.asarray(lower, float)
    hi = np.full(nominal.shape, np.inf) if upper is None else np.asarray(upper, float)
    sigma0 = settings.noise * np.broadcast_to(np.asarray(scale, float), nominal.shape).copy()
    st = _State(np.clip(nominal, lo, hi), sigma0.copy())
    best: list[Candidate] = []
    rows: list[np.ndarray] = []
    history: list[dict] = []
    t_start = time.perf_counter()
    interrupted = False
    try:
        for it in range(int(settings.iterations)):
            t0 = time.perf_counter()
            thetas = _draw(rng, st, settings, lo, hi)
            commands = [decode(th) for th in thetas]
            costs = _as_costs(evaluate(commands), len(thetas))
            rows.append(costs)
            _remember(best, thetas, commands, costs, it, max(1, keep))
            _update(st, thetas, costs, settings, sigma0)
            finite = costs[np.isfinite(costs)]
            info = {
                "iteration": it,
                "best_cost": best[0].cost if best else math.inf,
                "iteration_best": float(costs.min()),
                "median": float(np.median(finite)) if finite.size else math.inf,
                "failed": int(costs.size - finite.size),
                "noise": float(np.mean(st.sigma / np.where(sigma0 > 0, sigma0, 1.0))),
                "seconds": time.perf_counter() - t0,
            }
            history.append(info)
            if on_iteration is not None and on_iteration(info):
                interrupted = True
                break
    except KeyboardInterrupt:
        interrupted = True
        if not best:
            raise
    costs_arr = np.array(rows) if rows else np.zeros((0, int(settings.samples)))
    return SamplingResult(
        best=best[0],
        candidates=best,
        mean=st.mean,
        costs=costs_arr,
        history=history,
        interrupted=interrupted,
        seconds=time.perf_counter() - t_start,
    )


def _as_costs(costs, n: int) -> np.ndarray:
    c = np.asarray(costs, float).reshape(-1)
    if c.shape != (n,):
        raise ValueError(f"evaluate returned {c.size} costs for {n} samples")
    return np.where(np.isfinite(c), c, np.inf)  # NaN: a failed rollout


def _draw(rng: np.random.Generator, st: _State, settings, lo, hi) -> np.ndarray:
    """The iteration's samples: [S, K, m], sample 0 the current mean (CEM: then the kept
    elites). All noise is drawn here, from ``rng`` alone."""
    S = int(settings.samples)
    K, m = st.mean.shape
    kept = [th for _, th in st.elites] if settings.method == "cem" else []
    fresh = S - 1 - len(kept)
    eps = colored_noise(rng, float(settings.colored_noise), (max(fresh, 0), m, K))
    noise = np.transpose(eps, (0, 2, 1)) * st.sigma  # [fresh, K, m]
    out = np.concatenate([st.mean[None], *(th[None] for th in kept), st.mean + noise])
    return np.clip(out[:S], lo, hi)


def _remember(best: list, thetas, commands, costs, it: int, keep: int) -> None:
    """Keeps the ``keep`` lowest-cost distinct samples seen (earlier ones win ties)."""
    for i in np.argsort(costs, kind="stable")[:keep]:
        c = float(costs[i])
        if not math.isfinite(c):
            break
        if any(np.array_equal(b.knots, thetas[i]) for b in best):
            continue
        best.append(Candidate(thetas[i].copy(), np.asarray(commands[i]).copy(), c, it, int(i)))
    best.sort(key=lambda b: (b.cost, b.iteration, b.index))
    del best[keep:]


def _update(st: _State, thetas: np.ndarray, costs: np.ndarray, settings, sigma0) -> None:
    if not np.isfinite(costs).any():
        return  # every rollout failed: keep the plan and the spread
    if settings.method == "predictive":
        i = int(np.argmin(costs))  # (sample 0 is the mean: it moves only to a better one)
        st.mean = thetas[i].copy()
    elif settings.method == "cem":
        _update_cem(st, thetas, costs, settings, sigma0)
    else:
        _update_mppi(st, thetas, costs, settings)


def _update_cem(st: _State, thetas, costs, settings, sigma0) -> None:
    # (the kept elites were samples 1.. of this iteration: their costs are among these)
    E = min(int(settings.elites), int(np.isfinite(costs).sum()))
    order = np.argsort(costs, kind="stable")[:E]
    elites = thetas[order]
    a = float(settings.smoothing)
    st.mean = a * st.mean + (1 - a) * elites.mean(axis=0)
    spread = elites.std(axis=0) if E > 1 else st.sigma
    st.sigma = np.maximum(a * st.sigma + (1 - a) * spread, MIN_NOISE_FRACTION * sigma0)
    n_keep = int(round(settings.elite_memory * E))
    st.elites = [(float(costs[i]), thetas[i].copy()) for i in order[:n_keep]]


def _update_mppi(st: _State, thetas, costs, settings) -> None:
    ok = np.isfinite(costs)
    c = costs[ok]
    spread = float(c.max() - c.min())
    if spread <= 0:
        return
    w = np.exp(-(c - c.min()) / (float(settings.temperature) * spread))
    st.mean = np.tensordot(w / w.sum(), thetas[ok], axes=1)
