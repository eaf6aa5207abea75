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


def visc_terms(pos, vel, kind, c):
    """ViscDt per particle as sphgraph/physics/interact.py defines it: max(0, max over b within
    2h of h (v_ab . r_ab)/(r^2 + eta^2)), over every neighbour of a fluid particle and the
    fluid neighbours of a boundary one."""
    h = c.h
    eta2 = (0.1 * h) ** 2
    out = np.zeros(len(pos))
    for a in range(len(pos)):
        dr = pos[a] - pos
        r2 = (dr * dr).sum(1)
        nb = (r2 <= 4 * h * h) & (r2 > 1e-18)
        if kind[a] != 0:
            nb &= kind == 0
        t = h * ((vel[a] - vel) * dr).sum(1)[nb] / (r2[nb] + eta2)
        out[a] = max(0.0, t.max(initial=0.0))
    return out


def dt(ace, vel, visc, kind, c, cfl):
    """dt = CFL min(sqrt(h / max|a|), h / (max(c0, 10 max|v|) + h max visc)), |a| and |v| over
    fluid particles, `visc` = h ViscDt (visc_terms), as backends/compute/base.py's
    dt_from_terms and sphgraph/physics/interact.py document it. DualSPHysics' DtVariable
    adds h ViscDtMax with ViscDtMax = max (v_ab . r_ab)/(r^2 + eta^2): one factor h fewer."""
    fl = kind == 0
    amax = np.sqrt((ace[fl] ** 2).sum(1).max())
    vmax = np.sqrt((vel[fl] ** 2).sum(1).max())
    return cfl * min(np.sqrt(c.h / amax), c.h / (max(c.c0, 10 * vmax) + c.h * visc.max()))


def steps(p, c, phys, n, integrator):
    """`n` steps of the whole scene (one rank), from the formulas of DualSPHysics' ComputeVerlet
    (an Euler step every `phys.verlet_euler_every`) and ComputeSymplecticPre/Corr; boundary
    particles keep their place and a density of at least rho0. Returns (pos, vel, rho)."""
    pos, vel, rho = p.pos.astype(float), p.vel.astype(float), p.rho.astype(float)
    vel_m1, rho_m1 = p.vel_m1.astype(float), p.rho_m1.astype(float)
    fl = p.kind == 0
    g = np.asarray(c.gravity, float)[: pos.shape[1]]
    rho0 = phys.rho0

    def rates(pos, vel, rho):
        ace, ar = forces(pos, vel, rho, p.kind, c, phys)
        ace = np.where(fl[:, None], ace + g, 0.0)
        return ace, ar

    for k in range(n):
        ace, ar = rates(pos, vel, rho)
        h = dt(ace, vel, visc_terms(pos, vel, p.kind, c), p.kind, c, phys.cfl)
        if integrator == "verlet":
            euler = (k + 1) % phys.verlet_euler_every == 0
            rnew = rho + h * ar if euler else rho_m1 + 2 * h * ar
            vnew = (vel if euler else vel_m1) + (h if euler else 2 * h) * ace
            rho_m1, vel_m1 = rho, vel
            pos = np.where(fl[:, None], pos + h * vel + 0.5 * h * h * ace, pos)
            vel = np.where(fl[:, None], vnew, vel)
            rho = np.where(fl, rnew, np.maximum(rnew, rho0))
        else:
            pos0, vel0, rho0_ = pos, vel, rho
            rp = rho + 0.5 * h * ar
            pos = np.where(fl[:, None], pos + 0.5 * h * vel, pos)
            vel = np.where(fl[:, None], vel + 0.5 * h * ace, vel)
            rho = np.where(fl, rp, np.maximum(rp, rho0))
            ace, ar = rates(pos, vel, rho)
            e = -ar / rho * h
            rc = rho0_ * (2 - e) / (2 + e)
            vnew = vel0 + h * ace
            pos = np.where(fl[:, None], pos0 + h * 0.5 * (vnew + vel0), pos0)
            vel = np.where(fl[:, None], vnew, vel0)
            rho = np.where(fl, rc, np.maximum(rc, rho0))
    return pos, vel, rho
