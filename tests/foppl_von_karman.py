"""The clamped circular plate of issue 57 and its axisymmetric Föppl–von Kármán deflection,
computed independently of the package (shared by the tests of the nonlinear kinematics)."""

from __future__ import annotations

import numpy as np

#: half-thickness ε, Lamé constants λ, μ (ν = 0.3), radius and the pressure of issue 57's plate
PLATE_EPS, PLATE_LAM, PLATE_MU, PLATE_R, PLATE_P = 0.005, 1.5, 1.0, 0.5, 3.628e-6


def plate_constants() -> tuple[float, float, float, float]:
    """Young's modulus, Poisson's ratio, bending stiffness ``D`` and membrane stiffness ``C``
    of the plate (thickness ``2ε``)."""
    E = PLATE_MU * (3 * PLATE_LAM + 2 * PLATE_MU) / (PLATE_LAM + PLATE_MU)
    nu = PLATE_LAM / (2 * (PLATE_LAM + PLATE_MU))
    t = 2 * PLATE_EPS
    return E, nu, E * t**3 / (12 * (1 - nu**2)), E * t / (1 - nu**2)


def linear_deflection(q: float) -> float:
    """The linear clamped plate's centre deflection ``q R⁴ / (64 D)``."""
    return q * PLATE_R**4 / (64 * plate_constants()[2])


def foppl_von_karman_deflection(q: float, steps: int = 1000) -> float:
    """Centre deflection of the clamped, immovable circular plate under the uniform pressure
    ``q`` by the axisymmetric Föppl–von Kármán equations (slope ``φ = w'``, radial displacement
    ``u``, ``N_r = C (u' + φ²/2 + ν u/r)``)::

        D ((rφ)'/r)' = q r/2 + N_r φ,   u'' + u'/r − u/r² = −φφ' − (1 − ν) φ²/(2r),

    ``φ = u = 0`` at ``r = 0`` and ``r = R``, shot from ``r = 0`` (``φ ≈ A r``, ``u ≈ B r``)
    with RK4, Newton on ``(A, B)``; ``w(0) = −∫_0^R φ dr``."""
    _, nu, D, C = plate_constants()

    def rhs(r: float, y: np.ndarray) -> np.ndarray:
        phi, dphi, u, du, _ = y
        N = C * (du + phi**2 / 2 + nu * u / r)
        ddphi = (q * r / 2 + N * phi) / D - dphi / r + phi / r**2
        ddu = u / r**2 - du / r - (1 - nu) * phi**2 / (2 * r) - phi * dphi
        return np.array([dphi, ddphi, du, ddu, phi])

    def shoot(AB: np.ndarray) -> np.ndarray:
        r0 = 1e-7 * PLATE_R
        y = np.array([AB[0] * r0, AB[0], AB[1] * r0, AB[1], 0.0])
        dr = (PLATE_R - r0) / steps
        for r in r0 + dr * np.arange(steps):
            k1 = rhs(r, y)
            k2 = rhs(r + dr / 2, y + dr / 2 * k1)
            k3 = rhs(r + dr / 2, y + dr / 2 * k2)
            k4 = rhs(r + dr, y + dr * k3)
            y = y + dr / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return y

    AB = np.array([-q * PLATE_R**2 / (16 * D), 0.0])  # the linear plate's slope
    for _ in range(20):
        y = shoot(AB)
        F = y[[0, 2]]
        J = np.empty((2, 2))
        for k in range(2):
            d = np.zeros(2)
            d[k] = 1e-7 * max(abs(AB[k]), 1e-3)
            J[:, k] = (shoot(AB + d)[[0, 2]] - F) / d[k]
        step = np.linalg.solve(J, -F)
        AB = AB + step
        if np.abs(step).max() < 1e-12 * np.abs(AB).max():
            return -shoot(AB)[4]
    raise RuntimeError("the Föppl–von Kármán shooting did not converge")
