"""The clamped circular plate of docs/model.md §11 and its axisymmetric Föppl–von Kármán
deflection, computed independently of the package (shared by the tests of the nonlinear
kinematics and benchmarks/nonlinear_plate.py)."""

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


def foppl_von_karman_deflection(q: float, steps: int = 1000, loads: int = 1) -> float:
    """Centre deflection of the clamped, immovable circular plate under the uniform pressure
    ``q`` by the axisymmetric Föppl–von Kármán equations (slope ``φ = w'``, radial displacement
    ``u``, ``N_r = C (u' + φ²/2 + ν u/r)``)::

        D ((rφ)'/r)' = q r/2 + N_r φ,   u'' + u'/r − u/r² = −φφ' − (1 − ν) φ²/(2r),

    ``φ = u = 0`` at ``r = 0`` and ``r = R``, shot from ``r = 0`` (``φ ≈ A r``, ``u ≈ B r``)
    with RK4 in ``steps`` steps, Newton on ``(A, B)`` from the linear plate's slope through
    ``loads`` equal load steps; ``w(0) = −∫_0^R φ dr``. Thickness ``2ε``, Young's modulus and
    Poisson's ratio from the Lamé constants."""
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

    def solve(q_k: float, AB: np.ndarray) -> np.ndarray:
        nonlocal q
        q = q_k
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
                return AB
        raise RuntimeError("the Föppl–von Kármán shooting did not converge")

    total = q
    AB = np.array([-total / loads * PLATE_R**2 / (16 * D), 0.0])  # the linear plate's slope
    for q_k in total * np.arange(1, loads + 1) / loads:  # continuation in the load
        AB = solve(q_k, AB)
    return -shoot(AB)[4]


def foppl_von_karman_collocation(loads: list[float], nodes: int = 100) -> list[float]:
    """Centre deflections of the plate of :func:`foppl_von_karman_deflection` under the
    pressures ``loads`` (increasing), by central differences on ``nodes`` intervals of
    ``[0, R]`` (unknowns ``φ``, ``u`` at the interior nodes, exact Jacobian, Newton from the
    previous load's solution), Richardson-extrapolated from ``nodes`` and ``2 nodes``: an
    independent solution, robust where shooting from ``r = 0`` is not."""
    _, nu, D, C = plate_constants()

    def centres(n: int) -> np.ndarray:
        dr = PLATE_R / n
        r = dr * np.arange(1, n)
        ones = np.ones(n - 2)
        G = (np.diag(ones, 1) - np.diag(ones, -1)) / (2 * dr)  # d/dr, zero at both ends
        L = (np.diag(ones, 1) - 2 * np.eye(n - 1) + np.diag(ones, -1)) / dr**2
        L += G / r[:, None] - np.diag(1 / r**2)  # (1/r)(r v')' − v/r²
        phi, u, w = np.zeros(n - 1), np.zeros(n - 1), []
        for q in loads:
            for _ in range(30):
                N = C * (G @ u + phi**2 / 2 + nu * u / r)
                F = np.concatenate(
                    [
                        D * (L @ phi) - q * r / 2 - N * phi,
                        L @ u + phi * (G @ phi) + (1 - nu) * phi**2 / (2 * r),
                    ]
                )
                J = np.block(
                    [
                        [
                            D * L - np.diag(N + C * phi**2),
                            -C * phi[:, None] * (G + np.diag(nu / r)),
                        ],
                        [np.diag(G @ phi + (1 - nu) * phi / r) + phi[:, None] * G, L],
                    ]
                )
                step = np.linalg.solve(J, -F)
                phi, u = phi + step[: n - 1], u + step[n - 1 :]
                if np.abs(step[: n - 1]).max() < 1e-10 * np.abs(phi).max():
                    break
            else:
                raise RuntimeError("the Föppl–von Kármán collocation did not converge")
            w.append(-dr * phi.sum())  # −∫ φ dr, trapezoidal (φ = 0 at both ends)
        return np.array(w)

    return list((4 * centres(2 * nodes) - centres(nodes)) / 3)
