"""The System seam: ground-truth physics of one system, pure batched torch functions.

A state is ``s = (q, q̇)`` concatenated on the last axis, in one of the system's charts:
``angle`` (generalised coordinates) or ``cartesian`` (points in space, holonomic constraints
Φ(x) = 0). Every function takes any leading batch shape ``(..., 2n)``.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass

import torch
from torch import Tensor

from encons.infra.bounds import Declared
from encons.infra.errors import ChartError, ConfigError, PhysicsError
from encons.systems.constrained import DistanceConstraints, constrained_acceleration, full_mass_matrix


@dataclass(frozen=True)
class CartesianLayout:
    """How the Cartesian chart is laid out: ``n_points`` points in ``dim`` dimensions.

    ``bodies`` lists the point indices of each body. A body of one point is a point mass
    (parameters: mass). A body of ``1 + dim`` points is a rigid body in Finzi et al.'s chart:
    its centre of mass followed by ``dim`` unit body-axis points (parameters: mass and one
    axis "inertia" per axis point).
    """

    n_points: int
    dim: int
    bodies: tuple[tuple[int, ...], ...]

    @property
    def size(self) -> int:
        return self.n_points * self.dim


def point_mass_matrix(layout: CartesianLayout, params: list[Tensor]) -> Tensor:
    """The (n_points, n_points) mass matrix over points; the full one is ``kron(Mp, I_dim)``.

    ``params[b]`` holds body b's positive parameters: ``[m]`` for a point mass, or
    ``[m, I_1, …, I_dim]`` for a rigid body, whose kinetic energy is
    ``½ m |ẋ_c|² + ½ Σ_i I_i |ẋ_i − ẋ_c|²`` (Finzi et al. 2020, App. gyroscope).
    """
    ref = params[0]
    mp = torch.zeros(layout.n_points, layout.n_points, dtype=ref.dtype, device=ref.device)
    for points, p in zip(layout.bodies, params):
        idx = torch.tensor(points, device=ref.device)
        if len(points) == 1:
            block = p.reshape(1, 1)
        else:
            inertia = p[1:]
            top = torch.cat([(p[0] + inertia.sum()).reshape(1), -inertia])
            block = torch.cat([top.reshape(1, -1), torch.cat([-inertia[:, None], torch.diag(inertia)], 1)], 0)
        mp = mp.index_put((idx[:, None], idx[None, :]), block)
    return mp


def apply_point_matrix(mp: Tensor, v: Tensor, dim: int) -> Tensor:
    """Multiply ``kron(mp, I_dim)`` with vectors ``v`` of shape (..., n_points * dim)."""
    shaped = v.unflatten(-1, (mp.shape[0], dim))
    return torch.einsum("pq,...qd->...pd", mp, shaped).flatten(-2)


class System(Declared, abc.ABC):
    """True physics of one system.

    Subclasses set ``name``, ``charts`` (the first is the chart in which initial conditions
    are sampled and trajectories simulated) and ``common_chart`` (where metrics compare
    models), and implement the abstract methods for each chart they list.
    """

    config_key = "system"
    name: str
    charts: tuple[str, ...]
    common_chart: str
    layout: CartesianLayout | None = None
    known_physics: bool = True
    n_controls: int = 0  # width m of the exogenous inputs u the dynamics take
    angles: tuple[bool, ...] | None = None  # which generalised coordinates are angles (None: not declared)
    frame_shape: tuple[int, int] | None = None  # (H, W) of the frames it is also observed by (``render``)

    @property
    def base_chart(self) -> str:
        return self.charts[0]

    def input_matrix(self) -> Tensor:
        """B (n, m): input u enters the generalised forces as B u. Here the identity when m = n and (n, 0)
        without inputs; a system with 0 < m ≠ n inputs overrides it."""
        n = self.coord_dim(self.base_chart)
        if self.n_controls not in (0, n):
            raise ConfigError(
                f"system '{self.name}' has {self.n_controls} inputs for {n} coordinates and no "
                f"input_matrix(); allowed: a system that declares how u enters its equations"
            )
        return torch.eye(n, dtype=torch.float64)[:, : self.n_controls]

    def check_chart(self, chart: str) -> None:
        if chart not in self.charts:
            raise ChartError(f"system '{self.name}' has no '{chart}' chart; allowed: {', '.join(self.charts)}")

    @abc.abstractmethod
    def coord_dim(self, chart: str) -> int:
        """Number of coordinates n in ``chart`` (the state has 2n entries)."""

    @abc.abstractmethod
    def vector_field(self, s: Tensor, chart: str, u: Tensor | None = None) -> Tensor:
        """True ds/dt at states ``s`` in ``chart`` under inputs ``u`` (..., m); systems without
        inputs (``n_controls == 0``) may omit ``u``: it is passed only when there are inputs."""

    @abc.abstractmethod
    def energy(self, s: Tensor, chart: str) -> Tensor:
        """True total energy at states ``s`` in ``chart``; shape ``s.shape[:-1]``."""

    @abc.abstractmethod
    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        """``n`` initial states in the base chart, float64."""

    def sample_controls(self, n: int, generator: torch.Generator) -> Tensor | None:
        """Inputs (n, m) held constant over each of ``n`` trajectories, float64; None without inputs."""
        return None

    def sample_inputs(self, n: int, t: Tensor, generator: torch.Generator) -> Tensor | None:
        """Inputs (n, T, m) of ``n`` trajectories on times ``t`` (T,), ``u[:, k]`` held over [t_k, t_{k+1}],
        float64; None without inputs. Default: ``sample_controls``, constant over each trajectory."""
        u = self.sample_controls(n, generator)
        return None if u is None else u[:, None].expand(-1, len(t), -1)

    def units(self, chart: str) -> tuple[str, ...]:
        """The unit of each coordinate q in ``chart`` (its rate's: that per second), for figure axes.
        Default: rad in the angle chart (generalised coordinates of pendulums), m in the Cartesian one."""
        return ("rad" if chart == "angle" else "m",) * self.coord_dim(chart)

    def angle_entries(self, chart: str) -> Tensor | None:
        """Which of the 2n state entries in ``chart`` are angles (bool (2n,), for ``encons.numerics.metrics``): the
        declared ``angles`` in the angle chart (their rates are not); None where there are none."""
        if self.angles is None or not any(self.angles) or chart != "angle":
            return None
        return torch.tensor([*self.angles, *(False,) * len(self.angles)])

    def field(self, s: Tensor, chart: str, u: Tensor | None = None) -> Tensor:
        """``vector_field``, passing ``u`` only when there are inputs."""
        return self.vector_field(s, chart) if u is None else self.vector_field(s, chart, u)

    def to_chart(self, s: Tensor, src: str, dst: str) -> Tensor:
        """Map states from chart ``src`` to chart ``dst`` (at least base → every chart)."""
        self.check_chart(src)
        self.check_chart(dst)
        return s if src == dst else self.map_chart(s, src, dst)

    def map_chart(self, s: Tensor, src: str, dst: str) -> Tensor:
        """The chart map between two different charts; systems with several charts implement it."""
        raise ChartError(f"system '{self.name}' cannot map states from '{src}' to '{dst}'")

    def constraints(self, x: Tensor) -> Tensor:
        """Holonomic constraints Φ(x) of the Cartesian chart, shape (..., K), for systems that declare a
        ``layout``."""
        raise self.lacks("holonomic constraints")

    def render(self, s: Tensor, chart: str) -> Tensor:
        """Grey-scale frames (..., H, W) in [0, 1] of states ``s`` (..., 2n) in ``chart``, for systems
        observed by pixels (``frame_shape`` not None)."""
        raise self.lacks("frames")

    # The true physical quantities of the angle chart, for metrics and tests that compare learned ones.
    def mass_matrix(self, q: Tensor) -> Tensor:
        """M(q) of the angle chart, shape (..., n, n)."""
        raise self.lacks("mass matrix in generalised coordinates")

    def potential(self, q: Tensor) -> Tensor:
        """V(q) of the angle chart."""
        raise self.lacks("potential in generalised coordinates")

    def lacks(self, what: str) -> PhysicsError:
        """The error for physics this system does not know."""
        return PhysicsError(f"system '{self.name}' has no known {what}")

    def valid(self, traj: Tensor) -> Tensor:
        """Boolean mask over trajectories (N, T, 2n) in the base chart that are usable."""
        return torch.ones(traj.shape[0], dtype=torch.bool, device=traj.device)


class PointSystem(System):
    """Points (point masses, rigid bodies of points) with generalised coordinates, chart ``angle`` (``n`` of
    them), and the Cartesian chart of ``layout``'s points under ``constraints`` Φ(x) = 0, where the mass
    matrix over points (``point_masses``) is constant. The Cartesian field is Zhong et al. eq. (15)
    (``constrained_acceleration``) and the Cartesian energy ½ ẋᵀ M ẋ + V(x), the same for every subclass;
    a subclass gives M(q), V(q) (``mass_matrix``, ``potential``) and q̈ of the angle chart, the masses,
    V(x) and ∇V(x), and the chart maps.
    """

    charts = ("angle", "cartesian")
    common_chart = "cartesian"
    n: int
    layout: CartesianLayout
    constraints: DistanceConstraints

    def coord_dim(self, chart: str) -> int:
        self.check_chart(chart)
        return self.n if chart == "angle" else self.layout.size

    @abc.abstractmethod
    def acceleration(self, q: Tensor, qd: Tensor) -> Tensor:
        """q̈ of the angle chart at (q, q̇)."""

    @abc.abstractmethod
    def point_masses(self) -> Tensor:
        """The constant (n_points, n_points) Cartesian mass matrix over points (``layout``)."""

    @abc.abstractmethod
    def cartesian_potential(self, x: Tensor) -> Tensor:
        """V(x) of the Cartesian chart."""

    @abc.abstractmethod
    def cartesian_potential_gradient(self, x: Tensor) -> Tensor:
        """∇V(x) of the Cartesian chart, (..., D)."""

    @abc.abstractmethod
    def map_chart(self, s: Tensor, src: str, dst: str) -> Tensor: ...

    def vector_field(self, s: Tensor, chart: str) -> Tensor:  # type: ignore[override]  # no inputs: u omitted (System.field)
        self.check_chart(chart)
        q, qd = split_state(s)
        if chart == "cartesian":
            minv = full_mass_matrix(torch.linalg.inv(self.point_masses().to(q)), self.layout.dim)
            acc = constrained_acceleration(q, qd, minv, self.cartesian_potential_gradient(q), self.constraints)
        else:
            acc = self.acceleration(q, qd)
        return torch.cat([qd, acc], -1)

    def energy(self, s: Tensor, chart: str) -> Tensor:
        self.check_chart(chart)
        q, qd = split_state(s)
        if chart == "cartesian":
            kinetic = 0.5 * (qd * apply_point_matrix(self.point_masses().to(q), qd, self.layout.dim)).sum(-1)
            return kinetic + self.cartesian_potential(q)
        kinetic = 0.5 * (qd[..., None, :] @ self.mass_matrix(q) @ qd[..., :, None])[..., 0, 0]
        return kinetic + self.potential(q)


class DataOnlySystem(System):
    """A system known only through data (a user's file, the latent states an observation model learns):
    one chart of ``n`` coordinates, no true field, energy or initial-state distribution (``known_physics``
    false: the metrics and the oracle that need them are skipped)."""

    known_physics = False
    n: int

    def coord_dim(self, chart: str) -> int:
        self.check_chart(chart)
        return self.n

    def vector_field(self, s: Tensor, chart: str, u: Tensor | None = None) -> Tensor:
        raise self.lacks("vector field: it is known only through its data")

    def energy(self, s: Tensor, chart: str) -> Tensor:
        raise self.lacks("energy: it is known only through its data")

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        raise self.lacks("initial-state distribution: it is known only through its data")


def split_state(s: Tensor) -> tuple[Tensor, Tensor]:
    """Split ``s = (q, q̇)`` into its two halves."""
    n = s.shape[-1] // 2
    return s[..., :n], s[..., n:]
