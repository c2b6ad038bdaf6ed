"""The parameter space: which physical parameters are inferred, their priors and transforms.

Coordinates ``theta`` (the identifiable parameters, in the order of :attr:`ParamSpace.names`):

* ``k1``, ``k2``: the free sliding friction coefficients, uniform prior on ``priors.friction``.
* mass, two objects, both masses free: ``phi = (m1 - m2) / (m1 + m2)``, the only mass
  quantity a velocity profile determines (dissertation 5; NOTES.md). Its prior is the one
  induced by independent uniform masses m1, m2 on ``priors.mass = (a, b)`` (see below).
* mass, two objects, one mass known: the other mass (``m1`` or ``m2``), uniform on
  ``priors.mass``; the known mass fixes the scale, so the free mass is identifiable.
* one-object scenes and scenes with both masses known have no mass parameter (a lone
  sliding object's motion does not depend on its mass).
* ``dt_release`` (s): the release time minus the tracker's estimate
  (``Observation.release_time``), uniform on +-``simulation.release_window`` (default 0.2 s),
  unless the scene sets ``simulation.fit_release: false``. The tracker estimates the release by
  fitting constant acceleration from rest to the first frames
  (:func:`~galileo_jax.observe.profile.estimate_release_time`, also where a hand hides the
  object at its release); any effect that bends the early
  motion (drag, an initial push) biases that estimate, which the physics then cannot absorb.
  Measured on a rendered video with quadratic drag (issue 3 note): the estimate was 13 ms
  early, and the profile RMSE at the TRUE physical parameters was 0.0081 m/s with the
  estimated release against 0.0016 m/s with the true one (noise floor 0.0032 m/s).
* the parameters of the simulated effects, last.

Prior on phi (derivation). Write m1 = M (1 + phi) / 2, m2 = M (1 - phi) / 2 with total
M = m1 + m2; the Jacobian is |d(m1, m2) / d(M, phi)| = M / 2. With (m1, m2) uniform on
(a, b)^2 (density 1 / (b - a)^2), the joint density of (M, phi) is M / (2 (b - a)^2) on the
set where both masses lie in (a, b), i.e. M in (M_lo, M_hi) with
M_lo = 2a / (1 - |phi|) and M_hi = 2b / (1 + |phi|). Integrating M out,

    p(phi) = (M_hi^2 - M_lo^2) / (4 (b - a)^2),   |phi| < (b - a) / (b + a),

which integrates to 1. For the dissertation's (a, b) = (0, 1) this is exactly
p(phi) = (1 + |phi|)^-2 on (-1, 1). Conditional on phi the total has density
p(M | phi) ∝ M on (M_lo, M_hi), whose inverse CDF is M = sqrt(M_lo^2 + u (M_hi^2 - M_lo^2))
for u ~ U(0, 1) (M = M_hi sqrt(u) when a = 0); :meth:`ParamSpace.masses_for_report` draws
masses this way, so reported m1, m2 are draws from the posterior under the uniform mass prior
(their spread is the prior's, not information from the video).

Unconstrained coordinates ``z`` (for samplers and optimisers): every coordinate lives on an
interval (lo, hi) and z = logit((theta - lo) / (hi - lo)); theta = lo + (hi - lo) sigmoid(z),
log |d theta / d z| = log(hi - lo) + log sigmoid(z) + log sigmoid(-z). :meth:`log_prior`
works in z and includes this log-Jacobian.

All array methods are pure JAX, ``jit``- and ``vmap``-able; leading batch axes are allowed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from galileo_jax.physics.model import NOMINAL_FRICTION, NOMINAL_MASS
from galileo_jax.physics.simulate import PhysParams
from galileo_jax.scene import Scene

#: Reference total mass (kg) used to turn phi into masses for the simulator when no mass is
#: known; the simulated dynamics depend on the masses only through their ratio.
REFERENCE_TOTAL_MASS = 2.0 * NOMINAL_MASS

#: Largest |phi| simulated (a mass ratio of about 2000): the default mass prior (0, 1) kg allows
#: phi in (-1, 1), and a draw at |phi| = 1 (a wide posterior's Gauss-Newton draws saturate there)
#: gives an object of zero mass, which MuJoCo cannot simulate ("inertia matrix is too close to
#: singular"; the object then never moved, and a held-out render's predicted rest positions
#: came out as the start positions, an interval that left out the estimate). Beyond this the
#: lighter object's mass no longer changes the motion.
PHI_SIMULATED_MAX = 0.999


@dataclass(frozen=True)
class ParamSpace:
    """Identifiable parameters of a scene, with priors and the unconstrained transform.

    Build with :meth:`from_scene`. Hashable and immutable, so it can be closed over by jitted
    functions.

    Attributes:
        names: coordinate names in order, e.g. ``("k1", "k2", "phi")``.
        lower: (d,) lower bound of each coordinate.
        upper: (d,) upper bound of each coordinate.
        kinds: per coordinate "friction", "phi", "mass", "release", "scale" or "effect".
        objects: per coordinate the object index (0 or 1; phi: -1).
        n_objects: number of objects in the scene.
        known_mass: (n_objects,) known mass in kg or None (free).
        known_friction: (n_objects,) known friction coefficient or None (free).
        mass_prior: (a, b) uniform prior range of a free mass in kg.
        mass_mode: "phi" (both masses free), "free" (one mass free, one known),
            "known" (both known) or "none" (one object: mass irrelevant).
        effects: the :class:`~galileo_jax.effects.Effect` objects whose parameters follow the
            physical ones (kind "effect", uniform prior on each parameter's bounds).
    """

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    kinds: tuple[str, ...]
    objects: tuple[int, ...]
    n_objects: int
    known_mass: tuple[float | None, ...]
    known_friction: tuple[float | None, ...]
    mass_prior: tuple[float, float]
    mass_mode: str
    effects: tuple = ()

    @classmethod
    def from_scene(cls, scene: Scene, effects=()) -> "ParamSpace":
        """The parameter space of ``scene`` (free parameters from ``scene.free_parameters()``),
        followed by the parameters of ``effects`` (in order).

        Raises:
            ValueError: the scene has no free parameter at all.
        """
        free = scene.free_parameters()
        n = scene.n_objects
        fa, fb = scene.priors.friction
        ma, mb = scene.priors.mass
        names, lower, upper, kinds, objects = [], [], [], [], []
        for i in range(n):
            if f"k{i + 1}" in free:
                names.append(f"k{i + 1}"); lower.append(fa); upper.append(fb)
                kinds.append("friction"); objects.append(i)
        free_masses = [i for i in range(n) if f"m{i + 1}" in free]
        if n == 1:
            mode = "none"
        elif len(free_masses) == 2:
            mode = "phi"
            c = (mb - ma) / (mb + ma)
            names.append("phi"); lower.append(-c); upper.append(c)
            kinds.append("phi"); objects.append(-1)
        elif len(free_masses) == 1:
            mode = "free"
            i = free_masses[0]
            names.append(f"m{i + 1}"); lower.append(ma); upper.append(mb)
            kinds.append("mass"); objects.append(i)
        else:
            mode = "known"
        if scene.simulation.fit_release:
            w = float(scene.simulation.release_window)
            names.append("dt_release"); lower.append(-w); upper.append(w)
            kinds.append("release"); objects.append(-1)
        if (scene.camera.scale_tolerance or 0.0) > 0:
            tol = float(scene.camera.scale_tolerance)
            names.append("scale_error"); lower.append(-tol); upper.append(tol)
            kinds.append("scale"); objects.append(-1)
        for e in effects:
            for p in e.params:
                names.append(p.name); lower.append(p.lower); upper.append(p.upper)
                kinds.append("effect"); objects.append(-1)
        if not names:
            raise ValueError(f"scene {scene.name!r} has no free parameter that affects the motion "
                             f"(free: {free or 'none'}); leave a friction (or, with two objects, a mass) unset")
        return cls(tuple(names), tuple(float(x) for x in lower), tuple(float(x) for x in upper),
                   tuple(kinds), tuple(objects), n,
                   tuple(o.mass for o in scene.objects), tuple(o.friction for o in scene.objects),
                   (float(ma), float(mb)), mode, tuple(effects))

    @property
    def effect_slice(self) -> slice:
        """Positions of the effect parameters in ``theta`` (they come last)."""
        n_eff = sum(1 for k in self.kinds if k == "effect")
        return slice(self.dim - n_eff, self.dim)

    @property
    def n_physical(self) -> int:
        """Number of base-model coordinates (frictions, mass, release), before the effect parameters."""
        return self.effect_slice.start

    def scale_factor(self, theta: jax.Array) -> jax.Array:
        """(...,) factor 1 + ``scale_error`` by which the camera's scale stretches the observed
        displacements (scene ``camera.scale_tolerance``); 1 if not fitted."""
        theta = jnp.asarray(theta)
        if "scale_error" not in self.names:
            return jnp.ones(theta.shape[:-1], theta.dtype)
        return 1.0 + theta[..., self.names.index("scale_error")]

    def release_offset(self, theta: jax.Array) -> jax.Array:
        """The release-time correction ``dt_release`` (s) of theta (..., d) -> (...); 0 if not fitted."""
        theta = jnp.asarray(theta)
        if "dt_release" not in self.names:
            return jnp.zeros(theta.shape[:-1], theta.dtype)
        return theta[..., self.names.index("dt_release")]

    # ------------------------------------------------------------------ basic properties
    @property
    def dim(self) -> int:
        """Number of coordinates d."""
        return len(self.names)

    @property
    def mass_identifiable(self) -> bool:
        """True when absolute masses are determined (a mass is known and the other free/known)."""
        return self.mass_mode in ("free", "known")

    def index(self, name: str) -> int:
        """Position of coordinate ``name`` in ``theta``.

        Raises:
            ValueError: ``name`` is not a coordinate of this space.
        """
        if name not in self.names:
            raise ValueError(f"no parameter {name!r}; this scene's parameters are {list(self.names)}")
        return self.names.index(name)

    def _bounds(self) -> tuple[jax.Array, jax.Array]:
        return jnp.asarray(self.lower, jnp.float64), jnp.asarray(self.upper, jnp.float64)

    # ------------------------------------------------------------------ transforms
    def from_unconstrained(self, z: jax.Array) -> jax.Array:
        """theta = lo + (hi - lo) sigmoid(z); shapes (..., d) -> (..., d)."""
        lo, hi = self._bounds()
        return lo + (hi - lo) * jax.nn.sigmoid(z)

    def to_unconstrained(self, theta: jax.Array) -> jax.Array:
        """z = logit((theta - lo) / (hi - lo)); shapes (..., d) -> (..., d).

        Values on or outside the bounds give +-inf or NaN (clip first if needed).
        """
        lo, hi = self._bounds()
        u = (jnp.asarray(theta) - lo) / (hi - lo)
        return jnp.log(u) - jnp.log1p(-u)

    def log_abs_det_jacobian(self, z: jax.Array) -> jax.Array:
        """sum_j log |d theta_j / d z_j|; shape (..., d) -> (...)."""
        lo, hi = self._bounds()
        return jnp.sum(jnp.log(hi - lo) + jax.nn.log_sigmoid(z) + jax.nn.log_sigmoid(-z), axis=-1)

    def dtheta_dz(self, z: jax.Array) -> jax.Array:
        """Diagonal of the Jacobian d theta / d z, shape (..., d)."""
        lo, hi = self._bounds()
        s = jax.nn.sigmoid(z)
        return (hi - lo) * s * (1.0 - s)

    # ------------------------------------------------------------------ prior
    def log_prior_theta(self, theta: jax.Array) -> jax.Array:
        """Normalised log prior density in theta coordinates; (..., d) -> (...).

        Frictions and a free mass: -log(hi - lo). phi: log((M_hi^2 - M_lo^2) / (4 (b - a)^2))
        (module docstring). Outside the bounds the result is -inf (or NaN at exactly the
        bound of phi where the density is 0).
        """
        theta = jnp.asarray(theta)
        lo, hi = self._bounds()
        out = jnp.zeros(theta.shape[:-1], theta.dtype)
        inside = jnp.all((theta > lo) & (theta < hi), axis=-1)
        for j, kind in enumerate(self.kinds):
            if kind == "phi":
                a, b = self.mass_prior
                p = jnp.abs(theta[..., j])
                m_hi = 2.0 * b / (1.0 + p)
                m_lo = 2.0 * a / (1.0 - p)
                out = out + jnp.log(jnp.maximum(m_hi**2 - m_lo**2, 0.0)) - math.log(4.0 * (b - a) ** 2)
            else:
                out = out - math.log(self.upper[j] - self.lower[j])
        return jnp.where(inside, out, -jnp.inf)

    def log_prior(self, z: jax.Array) -> jax.Array:
        """Log prior density of z (unconstrained), including the log-Jacobian; (..., d) -> (...)."""
        z = jnp.asarray(z)
        return self.log_prior_theta(self.from_unconstrained(z)) + self.log_abs_det_jacobian(z)

    def sample_prior(self, key: jax.Array, n: int) -> jax.Array:
        """n draws of theta from the prior, shape (n, d).

        phi is drawn exactly by drawing m1, m2 uniform on the mass prior box.
        """
        k_u, k_m = jax.random.split(key)
        lo, hi = self._bounds()
        theta = lo + (hi - lo) * jax.random.uniform(k_u, (n, self.dim), minval=1e-6, maxval=1.0 - 1e-6)
        for j, kind in enumerate(self.kinds):
            if kind == "phi":
                a, b = self.mass_prior
                m = jax.random.uniform(k_m, (n, 2), minval=a, maxval=b)
                m = jnp.maximum(m, 1e-6 * b)
                phi = (m[:, 0] - m[:, 1]) / (m[:, 0] + m[:, 1])
                c = self.upper[j]
                theta = theta.at[:, j].set(jnp.clip(phi, -c * (1 - 1e-6), c * (1 - 1e-6)))
        return theta

    # ------------------------------------------------------------------ physics
    def physical(self, theta: jax.Array) -> PhysParams:
        """Simulator parameters for ``theta`` (..., d).

        Known values come from the scene. With phi, masses are REFERENCE_TOTAL_MASS * (1 +- phi) / 2
        (only the ratio matters; |phi| at most :data:`PHI_SIMULATED_MAX`). Without a mass parameter,
        free masses take the nominal mass.

        Returns:
            :class:`PhysParams` with ``mass`` and ``friction`` of shape (..., n_objects).
        """
        theta = jnp.asarray(theta)
        batch = theta.shape[:-1]
        mass = [jnp.full(batch, m if m is not None else NOMINAL_MASS, theta.dtype) for m in self.known_mass]
        fric = [jnp.full(batch, k if k is not None else NOMINAL_FRICTION, theta.dtype) for k in self.known_friction]
        for j, (kind, i) in enumerate(zip(self.kinds, self.objects)):
            if kind == "friction":
                fric[i] = theta[..., j]
            elif kind == "mass":
                mass[i] = theta[..., j]
            elif kind == "phi":
                phi = jnp.clip(theta[..., j], -PHI_SIMULATED_MAX, PHI_SIMULATED_MAX)
                mass[0] = REFERENCE_TOTAL_MASS * (1.0 + phi) / 2.0
                mass[1] = REFERENCE_TOTAL_MASS * (1.0 - phi) / 2.0
        effects = theta[..., self.effect_slice] if self.effects else None
        return PhysParams(jnp.stack(mass, -1), jnp.stack(fric, -1), effects)

    def masses_for_report(self, theta: jax.Array, key: jax.Array) -> jax.Array:
        """Masses (kg) for reporting, one draw per sample; (..., d) -> (..., n_objects).

        * phi: total M drawn from p(M | phi) ∝ M on (M_lo, M_hi) (module docstring), then
          m1 = M (1 + phi) / 2, m2 = M (1 - phi) / 2. Not identifiable: the spread is the prior's.
        * one mass known: the known mass and the sampled free mass.
        * one object with a free mass: a draw from the uniform mass prior (mass is irrelevant).
        """
        theta = jnp.asarray(theta)
        batch = theta.shape[:-1]
        a, b = self.mass_prior
        u = jax.random.uniform(key, batch, theta.dtype)
        mass = [jnp.full(batch, m, theta.dtype) if m is not None else a + (b - a) * u for m in self.known_mass]
        for j, (kind, i) in enumerate(zip(self.kinds, self.objects)):
            if kind == "mass":
                mass[i] = theta[..., j]
            elif kind == "phi":
                phi = theta[..., j]
                p = jnp.abs(phi)
                m_hi = 2.0 * b / (1.0 + p)
                m_lo = 2.0 * a / (1.0 - p)
                total = jnp.sqrt(m_lo**2 + u * jnp.maximum(m_hi**2 - m_lo**2, 0.0))
                mass[0] = total * (1.0 + phi) / 2.0
                mass[1] = total * (1.0 - phi) / 2.0
        return jnp.stack(mass, -1)

    def as_dict(self, theta) -> dict[str, np.ndarray]:
        """{name: theta[..., j]} as NumPy arrays (for reports)."""
        theta = np.asarray(theta)
        return {n: theta[..., j] for j, n in enumerate(self.names)}


#: Share of a calibration nuisance's window (``dt_release``, ``scale_error``) within which an
#: estimate counts as at the window's end (:func:`nuisances_at_edge`).
EDGE_SHARE = 0.02


def nuisances_at_edge(space, theta, share: float = EDGE_SHARE) -> dict[int, str]:
    """{coordinate index: "lower" or "upper"} of the calibration nuisances (kinds "release" and
    "scale") of ``space`` (a :class:`ParamSpace` or any space with ``kinds``, ``lower`` and
    ``upper``) whose value in ``theta`` ((d,) physical) lies within ``share`` of its window's
    width from an end: there the window, not the video, stopped the fit (the coverage benchmark's
    world_62: a release hidden by a hand, dt_release at -0.2 s; world_29: scale_error at -3% where
    the truth needs +3%)."""
    theta = np.asarray(theta, np.float64)
    out = {}
    for j, (kind, lo, hi) in enumerate(zip(space.kinds, space.lower, space.upper)):
        if kind not in ("release", "scale"):
            continue
        margin = share * (hi - lo)
        if theta[j] <= lo + margin:
            out[j] = "lower"
        elif theta[j] >= hi - margin:
            out[j] = "upper"
    return out


class BoxSpaceMethods:
    """ParamSpace's transform and prior code for other spaces with the same fields (``names``,
    ``lower``, ``upper``, ``kinds``, ``mass_prior``): the joint space of several videos
    (:class:`~galileo_jax.inference.joint.JointSpace`) and the free coordinates of a problem
    with held parameters (:class:`~galileo_jax.inference.fixed.SubSpace`)."""

    dim = ParamSpace.dim
    index = ParamSpace.index
    _bounds = ParamSpace._bounds
    from_unconstrained = ParamSpace.from_unconstrained
    to_unconstrained = ParamSpace.to_unconstrained
    log_abs_det_jacobian = ParamSpace.log_abs_det_jacobian
    dtheta_dz = ParamSpace.dtheta_dz
    log_prior = ParamSpace.log_prior
    sample_prior = ParamSpace.sample_prior
    as_dict = ParamSpace.as_dict
