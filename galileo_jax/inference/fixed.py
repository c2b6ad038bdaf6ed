"""A problem with some parameters held at given values: fit the others.

:class:`FixedProblem` wraps any problem (a :class:`~galileo_jax.inference.problem.Problem` or a
:class:`~galileo_jax.inference.joint.JointProblem`) and exposes only its free coordinates, with
the interface the optimisers and samplers use. The held values and the positions of the free
coordinates are DATA (:class:`FixedData`), not code: every choice of which d parameters are
free shares one compiled program. ``diagnose`` uses this to fit the base model and each
"base + one effect" model inside ONE problem that holds all candidate effects, the effects
that are not being tested held at their neutral values (which give back the base model exactly,
``tests/test_effects.py``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.inference.problem import DEFAULT_FD_STEP, BatchedAPI, check_residual_args, fd_jacobian_fn
from galileo_jax.params import BoxSpaceMethods, ParamSpace


class FixedData(NamedTuple):
    """Data of a :class:`FixedProblem` (a pytree).

    Attributes:
        parent: the wrapped problem's data.
        z_fixed: (D,) the parent's unconstrained coordinates with the held values (the free
            entries are overwritten).
        free: (d,) int, positions of the free coordinates in the parent's.
    """

    parent: Any
    z_fixed: jax.Array
    free: jax.Array


@dataclass(frozen=True, eq=False)
class SubSpace(BoxSpaceMethods):
    """The free coordinates of a parameter space, with ParamSpace's (per-coordinate) transforms and prior.

    Attributes:
        names, lower, upper, kinds: of the free coordinates, in the parent's order.
        mass_prior: the parent's mass prior range (for a free phi's prior).
    """

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    kinds: tuple[str, ...]
    mass_prior: tuple[float, float] | None

    log_prior_theta = ParamSpace.log_prior_theta  # the rest: BoxSpaceMethods


class FixedProblem(BatchedAPI):
    """``parent`` with the coordinates named in ``fixed`` held at the given values.

    Arguments:
        parent: a problem (``space``, ``data``, ``static_key``, ``loglik_fn``, ``residual_fn``, ``likelihood``).
        fixed: {name: value} in the parent's physical coordinates, inside its bounds or on
            one (an effect's neutral value 0 of a one-sided parameter: z = -inf, which the
            transform maps back to the bound exactly).

    Raises:
        ValueError: an unknown name, a value outside the bounds, or nothing left free.
    """

    def __init__(self, parent, fixed: Mapping[str, float]):
        space = parent.space
        unknown = [n for n in fixed if n not in space.names]
        if unknown:
            raise ValueError(f"cannot hold {unknown}: the parameters are {list(space.names)}")
        theta = np.array([(space.lower[j] + space.upper[j]) / 2 for j in range(space.dim)])
        for name, value in fixed.items():
            j = space.names.index(name)
            if not space.lower[j] <= float(value) <= space.upper[j]:
                raise ValueError(f"held value {name} = {value} is outside its bounds [{space.lower[j]}, {space.upper[j]}]")
            theta[j] = float(value)
        free = [j for j, n in enumerate(space.names) if n not in fixed]
        if not free:
            raise ValueError("every parameter is held fixed; leave at least one free")
        self.parent = parent
        self.fixed = {n: float(v) for n, v in fixed.items()}
        self.free = tuple(free)
        self.space = SubSpace(tuple(space.names[j] for j in free), tuple(space.lower[j] for j in free),
                              tuple(space.upper[j] for j in free), tuple(space.kinds[j] for j in free),
                              getattr(space, "mass_prior", None))
        self.data = FixedData(parent.data, space.to_unconstrained(jnp.asarray(theta)),
                              jnp.asarray(free, jnp.int32))
        self.static_key = ("fixed", parent.static_key, len(free))
        self.max_batch = parent.max_batch
        self.likelihood = parent.likelihood
        self.simulator_engine = parent.simulator_engine
        parent_ll = parent.loglik_fn

        def loglik(z, data):
            return parent_ll(full_z(z, data), data.parent)

        self.loglik_fn = loglik

    def full_theta(self, theta) -> np.ndarray:
        """Parent coordinates (..., D) from free ones (..., d) (NumPy)."""
        theta = np.asarray(theta, np.float64)
        out = np.broadcast_to(np.asarray(self.parent.space.from_unconstrained(self.data.z_fixed), np.float64),
                              theta.shape[:-1] + (self.parent.space.dim,)).copy()
        out[..., list(self.free)] = theta
        return out

    def residual_fn(self, jacobian: str = "fd", fd_step: float = DEFAULT_FD_STEP) -> Callable[[jax.Array, Any], jax.Array]:
        """Pure ``f(z (d,), data) -> residuals`` of the parent at the completed coordinates;
        with "fd" the central differences are taken in the FREE coordinates only.

        Raises:
            ValueError: as the parent's ``residual_fn``.
        """
        check_residual_args(jacobian, fd_step, self.likelihood)
        parent_res = self.parent.residual_fn("ad", fd_step)

        def res(z, data):
            return parent_res(full_z(z, data), data.parent)

        return fd_jacobian_fn(res, fd_step) if jacobian == "fd" else res


def full_z(z: jax.Array, data: FixedData) -> jax.Array:
    """The parent's unconstrained coordinates (D,) with the free ones (d,) filled in (pure)."""
    return data.z_fixed.at[data.free].set(z)
