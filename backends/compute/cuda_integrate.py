"""numba.cuda kernels of the time integration (one thread per row): Verlet and the
Symplectic predictor and corrector, as backends/compute/cpu_kernels.py.
"""
from numba import cuda

KERNELS = ("k_verlet", "k_sym_predict", "k_sym_correct")


def k_verlet(px, py, pz, vx, vy, vz, rho, vxm, vym, vzm, rhom, kind, ax, ay, az, ar,
             n, dim, dt, euler, rho0):
    """As cpu_kernels.verlet (DualSPHysics ComputeVerlet), Euler step when `euler`."""
    i = cuda.grid(1)
    if i >= n:
        return
    dt2 = 2.0 * dt
    dt205 = 0.5 * dt * dt
    if euler:
        rnew = rho[i] + dt * ar[i]
    else:
        rnew = rhom[i] + dt2 * ar[i]
    rhom[i] = rho[i]
    if kind[i] == 0:
        v = vx[i]
        px[i] += dt * v + dt205 * ax[i]
        vx[i] = (v if euler else vxm[i]) + (dt if euler else dt2) * ax[i]
        vxm[i] = v
        v = vy[i]
        py[i] += dt * v + dt205 * ay[i]
        vy[i] = (v if euler else vym[i]) + (dt if euler else dt2) * ay[i]
        vym[i] = v
        if dim == 3:
            v = vz[i]
            pz[i] += dt * v + dt205 * az[i]
            vz[i] = (v if euler else vzm[i]) + (dt if euler else dt2) * az[i]
            vzm[i] = v
        rho[i] = rnew
    else:
        rho[i] = rnew if rnew > rho0 else rho0


def k_sym_predict(px, py, pz, vx, vy, vz, rho, vx0, vy0, vz0, rho0_, kind, ax, ay, az, ar,
                  n, dim, dt, rho_ref):
    """As cpu_kernels.symplectic_predict (half step dt/2). The stage-start position is
    not kept: the corrector advances the predicted one (see k_sym_correct)."""
    i = cuda.grid(1)
    if i >= n:
        return
    h = 0.5 * dt
    rho0_[i] = rho[i]
    r = rho[i] + h * ar[i]
    if kind[i] == 0:
        vx0[i] = vx[i]
        vy0[i] = vy[i]
        px[i] += h * vx[i]
        py[i] += h * vy[i]
        vx[i] += h * ax[i]
        vy[i] += h * ay[i]
        if dim == 3:
            vz0[i] = vz[i]
            pz[i] += h * vz[i]
            vz[i] += h * az[i]
        rho[i] = r
    else:
        rho[i] = r if r > rho_ref else rho_ref


def k_sym_correct(px, py, pz, vx, vy, vz, rho, vx0, vy0, vz0, rho0_, kind, ax, ay, az, ar,
                  n, dim, dt, rho_ref):
    """As cpu_kernels.symplectic_correct: rho = rho0 (2 - e)/(2 + e), e = -ar/rho dt (Pade
    form of rho0 exp(ar/rho dt)); v = v0 + dt a, r = r0 + dt (v + v0)/2, written
    as r = r_pred + dt v / 2 (r_pred = r0 + dt v0 / 2): equal up to round-off, and no
    stage-start copy of the float64 positions (24 B per particle) is needed."""
    i = cuda.grid(1)
    if i >= n:
        return
    e = -ar[i] / rho[i] * dt
    r = rho0_[i] * (2.0 - e) / (2.0 + e)
    if kind[i] == 0:
        hd = 0.5 * dt
        v = vx0[i] + dt * ax[i]
        px[i] += hd * v
        vx[i] = v
        v = vy0[i] + dt * ay[i]
        py[i] += hd * v
        vy[i] = v
        if dim == 3:
            v = vz0[i] + dt * az[i]
            pz[i] += hd * v
            vz[i] = v
        rho[i] = r
    else:
        rho[i] = r if r > rho_ref else rho_ref
