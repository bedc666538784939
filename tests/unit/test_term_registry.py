"""A term type added outside the package (a toy config type and residual registered here):
the task format takes it (its keys, its checks, `hydroilqr schema`'s term types), the cost
composes it with the activations and windows every term has, and the finite-difference
Jacobian test of test_terms.py checks it without a test body of its own."""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np
import pytest

from hydroilqr import Task
from hydroilqr.cli import main
from hydroilqr.model.activations import Bounds, SoftMin
from hydroilqr.model.residuals import RESIDUALS, Residual, register
from hydroilqr.model.windows import Ramp, Window
from hydroilqr.problem.errors import ConfigError
from hydroilqr.problem.schema import task_schema
from hydroilqr.problem.terms import TERM_TYPES, TermConfig
from tests.unit.test_terms import N, assert_jacobians_match_central_differences


@dataclass
class ToyTerm(TermConfig):
    """``toy``: the product of a point's x and y (m²) against a target or bounds."""

    kind: ClassVar[str] = "toy"

    body: str = ""
    point: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    target: Any = None
    min: float | None = None
    max: float | None = None

    def check(self, key: str) -> None:
        if not self.body:
            raise ConfigError(f"{key}.body: required")
        if self.target is not None and not isinstance(self.target, (int, float)):
            raise ConfigError(f"{key}.target: expected a number")


class Toy(Residual):
    """r = p_x · p_y (m²) of a point P fixed on a body, against a target or bounds."""

    config = ToyTerm

    def __init__(self, cfg, kin, key):
        super().__init__(cfg, kin, key)
        self.frame = kin.frame(cfg.body, f"{key}.body")
        self.point = np.asarray(cfg.point, float)

    def activation(self):
        c = self.cfg
        lo = c.target if c.target is not None else (-math.inf if c.min is None else c.min)
        hi = c.target if c.target is not None else (math.inf if c.max is None else c.max)
        return Bounds(lo, hi)

    def value(self, kin, x, time):
        p = kin.position(self.frame, self.point)
        return np.array([p[0] * p[1]]), p[0] * p[1], p

    def jacobian(self, kin, x, p):
        J = np.zeros((1, kin.nx))
        Jp = kin.jq(self.frame, self.point)
        J[0, : kin.nq] = p[1] * Jp[0] + p[0] * Jp[1]
        return J


def schema_term_types(schema: dict) -> list[str]:
    """The term types a schema lists: one definition per type, each naming its type."""
    refs = [r["$ref"].rsplit("/", 1)[1] for r in schema["definitions"]["TermConfig"]["anyOf"]]
    return [t for r in refs for t in schema["definitions"][r]["properties"]["type"]["enum"]]


@pytest.fixture
def toy():
    """The toy type, registered for one test and removed after it."""
    register(Toy)
    yield Toy
    del RESIDUALS["toy"], TERM_TYPES["toy"]


TOYS = [
    {"name": "xy", "type": "toy", "body": "gripper", "point": [0, 0, 0.1], "target": 0.01,
     "weight": 3.0, "ramp": [0.5, 2.0]},
    {"name": "xy_low", "type": "toy", "body": "ball", "max": -1.0, "weight": 2.0,
     "softmin": 1.0e-3, "after": 0.01},
]  # fmt: skip


def test_a_registered_toy_term_is_checked_by_the_registrys_fd_test(toy):
    task = Task.load("kinova-forward", smoke=True, overrides={"cost.terms": TOYS, "num_steps": N})
    terms = task.cost.task_terms
    xy, low = terms.terms
    assert isinstance(xy.residual, Toy) and xy.time == Window(None, None, Ramp(0.5, 2.0))
    assert low.aggregate == SoftMin(1.0e-3)
    rng = np.random.default_rng(5)
    X = np.tile(task.x0, (N + 1, 1))
    X[:, :7] += 0.3 * rng.standard_normal((N + 1, 7))
    X = task.dynamics.layout.normalize(X)
    assert terms.stage_costs(X).sum() > 0.0
    assert_jacobians_match_central_differences(terms, X, "toy")


def test_the_task_format_takes_the_toy_type_its_keys_and_its_checks(toy, capsys):
    assert "toy" in schema_term_types(task_schema())
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert "toy" in schema_term_types(schema)
    toy_keys = set(schema["definitions"]["ToyTerm"]["properties"])
    assert {"body", "point", "target", "min", "max", "weight", "softmin"} <= toy_keys
    assert "margin" not in toy_keys
    bad = [
        ({"name": "t", "type": "toy", "body": "gripper", "margin": 0.1},
         "cost.terms.t.margin: a toy term has no margin"),
        ({"name": "t", "type": "toy", "point": [0, 0, 0]}, "cost.terms.t.body: required"),
    ]  # fmt: skip
    for term, message in bad:
        with pytest.raises(ConfigError, match=re.escape(message)):
            Task.load("kinova-forward", smoke=True, overrides={"cost.terms": [term]})


def test_without_the_registration_the_type_is_unknown():
    assert "toy" not in RESIDUALS
    assert "toy" not in schema_term_types(task_schema())
    with pytest.raises(ConfigError, match="cost.terms.xy.type: unknown term type"):
        Task.load("kinova-forward", smoke=True, overrides={"cost.terms": TOYS[:1]})
