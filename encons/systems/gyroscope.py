"""Heavy symmetric top about a fixed pivot (Finzi et al. 2020, "Gyroscope"; Zhong et al. §4.1).

Angle chart: ZXZ Euler angles q = (φ, θ, ψ), rotation R = Rz(φ) Rx(θ) Rz(ψ), and their rates;
the symmetry axis e_3 = R[:, 2] and θ is its tilt from the upward vertical.
L = ½ J⊥' (θ̇² + φ̇² sin²θ) + ½ J_3 (ψ̇ + φ̇ cos θ)² − m g ℓ cos θ, with J⊥' = J⊥ + m ℓ².
Cartesian chart (Finzi et al.'s rigid body, D = 12): the centre of mass x_c followed by the three
unit body-axis points x_i = x_c + e_i (e_i = R[:, i]), kinetic energy ½ m |ẋ_c|² + ½ Σ_i I_i |ė_i|²,
9 holonomic constraints |e_i|² = 1, |x_i − x_j|² = 2 (i < j) and x_c − ℓ e_3 = 0 (pivot at the
origin). Gravity g along −z. The body-axis "inertias" I give the principal moments about the
centre of mass J⊥ = I_1 + I_3 (= I_2 + I_3), J_3 = I_1 + I_2.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated

import torch
from torch import Tensor
from torch.func import jvp

from encons.infra.bounds import Finite, NonNegative, Positive, Range
from encons.infra.errors import ConfigError
from encons.systems.base import CartesianLayout, PointSystem, point_mass_matrix, split_state
from encons.systems.constrained import DistanceConstraints


def _rotation(q: Tensor) -> Tensor:
    """R = Rz(φ) Rx(θ) Rz(ψ) for Euler angles (..., 3); shape (..., 3, 3)."""
    c, s = torch.cos(q), torch.sin(q)
    (c1, c2, c3), (s1, s2, s3) = c.unbind(-1), s.unbind(-1)
    rows = [
        [c1 * c3 - s1 * c2 * s3, -c1 * s3 - s1 * c2 * c3, s1 * s2],
        [s1 * c3 + c1 * c2 * s3, -s1 * s3 + c1 * c2 * c3, -c1 * s2],
        [s2 * s3, s2 * c3, c2],
    ]
    return torch.stack([torch.stack(row, -1) for row in rows], -2)


class Gyroscope(PointSystem):
    """Heavy symmetric top, spinning fast about its axis and precessing about a fixed pivot.

    Gimbal lock: the angle chart is singular where sin θ = 0 (det M(q) = J⊥'² J_3 sin²θ), i.e.
    with the axis vertical, which the initial tilts θ ~ U(−1.5, 1.5) reach. ``valid`` rejects a
    simulated trajectory whose |sin θ| drops below ``min_sin_theta`` at any stored step, so the
    data module redraws it and logs ``rejection_reason``; ``min_sin_theta=0`` keeps every finite trajectory
    (Zhong et al.'s protocol, ``profile=zhong``). The Cartesian chart has no singularity.
    """

    name = "gyroscope"
    n = 3

    def __init__(
        self,
        mass: Positive = 0.1,
        ell: Positive = 0.2217,
        inertias: Sequence[Positive] = (0.024138, 0.024138, 0.003694),
        g: Positive = 9.81,
        angle_range: Positive = 1.5,
        phi_rate_range: NonNegative = 4.5,
        theta_rate_range: NonNegative = 0.3,
        spin_mean: Finite = 7.0,
        spin_scale: Positive = 1.5,
        min_sin_theta: Annotated[float, Range(ge=0, lt=1)] = 0.1,
    ):
        inertias = [float(i) for i in inertias]
        if len(inertias) != 3 or inertias[0] != inertias[1]:
            raise ConfigError(
                f"system.inertias={inertias}; allowed: 3 positive numbers with I_1 = I_2 (a symmetric top)"
            )
        self.m, self.ell, self.g = float(mass), float(ell), float(g)
        self.inertias = torch.tensor(inertias, dtype=torch.float64)
        self.j_perp = inertias[0] + inertias[2] + self.m * self.ell**2  # about the pivot
        self.j_3 = inertias[0] + inertias[1]
        self.init = dict(
            angle=float(angle_range),
            phi_rate=float(phi_rate_range),
            theta_rate=float(theta_rate_range),
            spin_mean=float(spin_mean),
            spin_scale=float(spin_scale),
        )
        self.min_sin_theta = float(min_sin_theta)
        # Φ: unit body axes |x_k − x_c|² = 1, orthogonal |x_i − x_j|² = 2, pivot x_c − ℓ (x_3 − x_c) = 0.
        pivot = torch.zeros(3, 4, 3, dtype=torch.float64)
        eye = torch.eye(3, dtype=torch.float64)
        pivot[:, 0], pivot[:, 3] = (1 + self.ell) * eye, -self.ell * eye
        self.constraints = DistanceConstraints(
            4, 3, [(1, 0), (2, 0), (3, 0), (1, 2), (1, 3), (2, 3)], [1.0] * 3 + [2.0**0.5] * 3, pivot.flatten(1)
        )
        self.rejection_reason = f"|sin θ| < min_sin_theta={self.min_sin_theta}: gimbal lock of the angle chart"
        self.layout = CartesianLayout(4, 3, ((0, 1, 2, 3),))

    def mass_matrix(self, q: Tensor) -> Tensor:
        """M(q) over (φ, θ, ψ): [[J⊥' sin²θ + J_3 cos²θ, 0, J_3 cos θ], [0, J⊥', 0], [J_3 cos θ, 0, J_3]]."""
        c, s = torch.cos(q[..., 1]), torch.sin(q[..., 1])
        zero, j_perp, j_3 = torch.zeros_like(c), torch.full_like(c, self.j_perp), torch.full_like(c, self.j_3)
        rows = [
            [self.j_perp * s**2 + self.j_3 * c**2, zero, self.j_3 * c],
            [zero, j_perp, zero],
            [self.j_3 * c, zero, j_3],
        ]
        return torch.stack([torch.stack(row, -1) for row in rows], -2)

    def potential(self, q: Tensor) -> Tensor:
        return self.m * self.g * self.ell * torch.cos(q[..., 1])

    def point_masses(self) -> Tensor:
        """Finzi et al.'s (4, 4) mass matrix over (x_c, x_1, x_2, x_3), from (m, I_1, I_2, I_3)."""
        params = torch.cat([torch.tensor([self.m], dtype=torch.float64), self.inertias])
        return point_mass_matrix(self.layout, [params])

    def cartesian_potential(self, x: Tensor) -> Tensor:
        return self.m * self.g * x[..., 2]

    def cartesian_potential_gradient(self, x: Tensor) -> Tensor:
        grad_v = torch.zeros_like(x)
        grad_v[..., 2] = self.m * self.g
        return grad_v

    def acceleration(self, q: Tensor, qd: Tensor) -> Tensor:
        """The Euler–Lagrange equations; p_φ and p_ψ = J_3 ω_3 are conserved, ω_3 = ψ̇ + φ̇ cos θ."""
        c, s = torch.cos(q[..., 1]), torch.sin(q[..., 1])
        phid, thetad, psid = qd.unbind(-1)
        a, b = self.j_3 / self.j_perp, self.m * self.g * self.ell / self.j_perp
        omega_3 = psid + phid * c
        thetadd = s * (phid**2 * c - a * omega_3 * phid + b)
        phidd = thetad * (a * omega_3 - 2 * phid * c) / s
        psidd = phid * thetad * s - phidd * c
        return torch.stack([phidd, thetadd, psidd], -1)

    def sample_initial(self, n: int, generator: torch.Generator) -> Tensor:
        """Finzi et al.: angles U(−a, a), φ̇ U(−4.5, 4.5), θ̇ U(−0.3, 0.3), ψ̇ = ±1.5 (7 + N(0, 1))."""
        init = self.init

        def uniform(half_width: float, *shape: int) -> Tensor:
            return (2 * torch.rand(n, *shape, generator=generator, dtype=torch.float64) - 1) * half_width

        sign = 2.0 * torch.randint(2, (n,), generator=generator, dtype=torch.float64) - 1
        spin = (
            sign * init["spin_scale"] * (init["spin_mean"] + torch.randn(n, generator=generator, dtype=torch.float64))
        )
        rates = torch.stack([uniform(init["phi_rate"]), uniform(init["theta_rate"]), spin], -1)
        return torch.cat([uniform(init["angle"], 3), rates], -1)

    def valid(self, traj: Tensor) -> Tensor:
        """Trajectories (N, T, 6) whose |sin θ| stays ≥ ``min_sin_theta`` (no gimbal lock)."""
        return (torch.sin(traj[..., 1]).abs() >= self.min_sin_theta).all(-1)

    def _points(self, q: Tensor) -> Tensor:
        """Euler angles (..., 3) -> (x_c, x_1, x_2, x_3) flattened, (..., 12)."""
        axes = _rotation(q).transpose(-1, -2)  # rows e_i
        com = self.ell * axes[..., 2, :]
        return torch.cat([com[..., None, :], com[..., None, :] + axes], -2).flatten(-2)

    def map_chart(self, s: Tensor, src: str, dst: str) -> Tensor:
        q, qd = split_state(s)
        if src == "angle":
            return torch.cat(jvp(self._points, (q,), (qd,)), -1)
        pts, vel = q.unflatten(-1, (4, 3)), qd.unflatten(-1, (4, 3))
        rot = (pts[..., 1:, :] - pts[..., :1, :]).transpose(-1, -2)  # columns e_i
        rot_dot = (vel[..., 1:, :] - vel[..., :1, :]).transpose(-1, -2)
        skew = rot.transpose(-1, -2) @ rot_dot  # [ω]× in the body frame
        w1, w2, w3 = (
            (skew[..., 2, 1] - skew[..., 1, 2]) / 2,
            (skew[..., 0, 2] - skew[..., 2, 0]) / 2,
            (skew[..., 1, 0] - skew[..., 0, 1]) / 2,
        )
        phi = torch.atan2(rot[..., 0, 2], -rot[..., 1, 2])
        theta = torch.atan2(torch.hypot(rot[..., 0, 2], rot[..., 1, 2]), rot[..., 2, 2])
        psi = torch.atan2(rot[..., 2, 0], rot[..., 2, 1])
        c3, s3 = torch.cos(psi), torch.sin(psi)
        phid = (w1 * s3 + w2 * c3) / torch.sin(theta)
        rates = torch.stack([phid, w1 * c3 - w2 * s3, w3 - phid * torch.cos(theta)], -1)
        return torch.cat([torch.stack([phi, theta, psi], -1), rates], -1)
