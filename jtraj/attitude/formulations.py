"""How the quaternion of a rigid body enters the transcription: the two formulations compared
by "Planning with Attitude" (Section V), one contract (`AbstractFormulation`).

- ``naive`` (`NaiveFormulation`): the quaternion is a plain vector of R^4. Dynamics defects
  ``x_{k+1} - rk4(x_k, u_k)`` (nx rows), attitude costs ``w/2 |q - q_ref|^2`` and attitude
  targets (waypoints, goal) ``q - q_ref = 0`` (4 rows), with ``q_ref`` on the quaternion branch
  that the motion follows (a 360 degree flip ends at ``[-1, 0, 0, 0]``).
- ``attitude`` (`AttitudeFormulation`): attitude-aware. Defects in the error state (eq. 25;
  ``nx - 1`` rows): position/velocity/other differences and the Rodrigues parameter
  ``cayley_inv(L(q_pred)^T q_{k+1})`` of the rotation from the RK4 prediction to the next
  knot; attitude costs are the geodesic cost ``w (1 - |q_ref^T q|)`` (eq. 40), whose gradient
  and Hessian in the rotation coordinates are eqs. 41-42 (JAX differentiates through it;
  the `jtraj.quaternion` tests check that autodiff composed with ``G(q)`` equals them);
  attitude targets are ``cayley_inv(L(q_ref)^T q) = 0`` (3 rows). Because the solver still
  sees the four quaternion coordinates, and the error-state defect only fixes the direction of
  ``q_{k+1}`` (it is invariant under scaling), a unit-norm constraint ``|q_k|^2 = 1`` is added at
  every knot after the first, which also removes the RK4 norm drift the naive defect carries.

Both formulations weigh attitude equally to first order on the unit sphere
(``1/2 |q - q_ref|^2 = 1 - q_ref^T q``).
"""

from __future__ import annotations

import abc
import dataclasses
from typing import ClassVar

import jax

from jtraj import quaternion as quat
from jtraj.attitude import models as M
from jtraj.registry import lookup

__all__ = ["AbstractFormulation", "NaiveFormulation", "AttitudeFormulation", "FORMULATIONS", "get"]


class AbstractFormulation(abc.ABC):
    """How the quaternion is treated by the transcription. Methods act on ONE knot.

    - ``defect(x_next, x_pred)``: dynamics defect rows (``defect_dim(nx)``);
    - ``attitude_cost(q, q_ref)``: scalar, multiplied by the knot's attitude weight;
    - ``attitude_error(q, q_ref)``: rows of an attitude target constraint (``target_dim``);
    - ``unit_norm``: whether ``|q|^2 = 1`` rows are added at every free knot.
    """

    name: ClassVar[str]
    target_dim: ClassVar[int]
    unit_norm: ClassVar[bool]

    @abc.abstractmethod
    def defect_dim(self, nx: int) -> int:
        """See the class docstring."""

    @abc.abstractmethod
    def defect(self, x_next: jax.Array, x_pred: jax.Array) -> jax.Array:
        """See the class docstring."""

    @abc.abstractmethod
    def attitude_cost(self, q: jax.Array, q_ref: jax.Array) -> jax.Array:
        """See the class docstring."""

    @abc.abstractmethod
    def attitude_error(self, q: jax.Array, q_ref: jax.Array) -> jax.Array:
        """See the class docstring."""


@dataclasses.dataclass(frozen=True)
class NaiveFormulation(AbstractFormulation):
    """Quaternion as a vector of R^4: additive defects, costs and targets.

    A target is the 4 rows ``q - q_ref = 0``, as a naive user writes it (and as the paper's
    code writes the barrel roll's goal). With the unit norm that the RK4 step keeps to
    O(h^5), one of the 4 rows is all but redundant: the constraint Jacobian is rank-deficient
    (`tests/test_attitude_models.py`), which the paper's ALTRO (an augmented Lagrangian)
    tolerates and Ipopt's Newton steps do not. Much of the naive variant's failure under Ipopt
    comes from that row, not from additive calculus alone (docs/measurements.md: with the
    vector part's 3 rows as the target, all else naive, the barrel roll solves in 13
    iterations and the satellite slew in 43)."""

    name: ClassVar[str] = "naive"
    target_dim: ClassVar[int] = 4
    unit_norm: ClassVar[bool] = False

    def defect_dim(self, nx: int) -> int:
        return nx

    def defect(self, x_next, x_pred):
        return x_next - x_pred

    def attitude_cost(self, q, q_ref):
        d = q - q_ref
        return 0.5 * d @ d

    def attitude_error(self, q, q_ref):
        return q - q_ref


@dataclasses.dataclass(frozen=True)
class AttitudeFormulation(AbstractFormulation):
    """Error-state defects (eq. 25), geodesic cost (eq. 40), Cayley-map targets, unit norm."""

    name: ClassVar[str] = "attitude"
    target_dim: ClassVar[int] = 3
    unit_norm: ClassVar[bool] = True

    def defect_dim(self, nx: int) -> int:
        return nx - 1

    def defect(self, x_next, x_pred):
        return M.error_state(x_next, x_pred)

    def attitude_cost(self, q, q_ref):
        return quat.geodesic_cost(q, q_ref)

    def attitude_error(self, q, q_ref):
        return quat.cayley_inv(quat.L(q_ref).T @ q)


FORMULATIONS: dict[str, AbstractFormulation] = {"naive": NaiveFormulation(), "attitude": AttitudeFormulation()}


def get(variant: str | AbstractFormulation) -> AbstractFormulation:
    """A formulation from its name in `FORMULATIONS` (or the formulation itself)."""
    if isinstance(variant, AbstractFormulation):
        return variant
    return lookup(FORMULATIONS, variant, "variant")
