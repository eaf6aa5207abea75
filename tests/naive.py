"""O(N^2) reference of the force computation, plain numpy, for checking fast paths.

Written from the formulas in sphgraph/physics/interact.py's docstring, not from
its code: all pairs within 2h, no cells.
"""
import numpy as np


def wendland_grad_factor(r, h, dim):
    aw = 7.0 / (4 * np.pi * h * h) if dim == 2 else 21.0 / (16 * np.pi * h ** 3)
    q = r / h
    return -5.0 * aw / h * q * (1 - q / 2) ** 3 / r


def forces(pos, vel, rho, kind, c, phys):
    """(ace without gravity, drho/dt) of every particle, all pairs within 2h."""
    n, dim = pos.shape
    h, c0, B, m = c.h, c.c0, c.B, c.mass_fluid
    gamma, rho0 = phys.gamma, phys.rho0
    eta2 = (0.1 * h) ** 2
    p = B * ((rho / rho0) ** gamma - 1)
    ace = np.zeros((n, dim))
    ar = np.zeros(n)
    ddt = np.zeros(n)
    cancel = np.zeros(n, bool)
    kh = phys.delta * 2 * h
    g = np.asarray(c.gravity, float)
    for a in range(n):
        dr = pos[a] - pos
        r2 = (dr * dr).sum(1)
        nb = np.nonzero((r2 <= 4 * h * h) & (r2 > 1e-18))[0]
        for b in nb:
            r = np.sqrt(r2[b])
            fr = wendland_grad_factor(r, h, dim) * dr[b]
            dv = vel[a] - vel[b]
            bound_b = kind[b] != 0
            if kind[a] != 0:
                if not bound_b:
                    ar[a] += m * dv @ fr * rho[a] / rho[b]
                continue
            ar[a] += m * dv @ fr * rho[a] / rho[b]
            acc = -m * (p[a] + p[b]) / (rho[a] * rho[b]) * fr
            if dv @ dr[b] < 0:
                alpha = phys.visc_alpha * (phys.visc_bound_factor if bound_b else 1.0)
                mu = h * (dv @ dr[b]) / (r2[b] + eta2)
                acc += m * alpha * c0 * mu / ((rho[a] + rho[b]) / 2) * fr
            ace[a] += acc
            if phys.diffusion == "fourtakas":
                if bound_b:
                    cancel[a] = True
                else:
                    dph = rho0 * g @ (pos[b] - pos[a])
                    drho_h = rho0 * ((1 + dph / B) ** (1 / gamma) - 1)
                    # dr.fr < 0: a denser neighbour (beyond hydrostatics) raises rho_a
                    ddt[a] -= kh * c0 * ((rho[b] - rho[a]) - drho_h) * (dr[b] @ fr) / (r2[b] + eta2) * m / rho[b]
    ar = ar + np.where(cancel, 0.0, ddt)
    return ace, ar
