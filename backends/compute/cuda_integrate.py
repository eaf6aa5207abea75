"""numba.cuda kernels of the time integration (one thread per row): Verlet and the
Symplectic predictor and corrector. The per-row maths is sphgraph.physics.integrate's,
as the CPU kernels' (backends/compute/cpu_kernels.py); here the axes are arrays of
their own (float64 positions, run-type velocities).
"""
from numba import cuda

from sphgraph.physics.damping import damping_factor
from sphgraph.physics.integrate import (bound_density, correct_axis, correct_density, predict_axis,
                                        predict_density, verlet_axis, verlet_density)
from sphgraph.physics.wrap import wrap_axis

KERNELS = ("k_verlet", "k_sym_predict", "k_sym_correct", "k_wrap", "k_damp")


def k_verlet(px, py, pz, vx, vy, vz, rho, vxm, vym, vzm, rhom, kind, ax, ay, az, ar, dk,
             n, dim, dt, euler, rho0, df):
    """Verlet step, Euler step when `euler`; `df`: the DuFort-Frankel density form with
    K_a in `dk`."""
    i = cuda.grid(1)
    if i >= n:
        return
    zero = ar[i] - ar[i]
    rnew = verlet_density(rho[i], rhom[i], ar[i], dk[i] if df else zero, dt, euler, df)
    rhom[i] = rho[i]
    if kind[i] == 0:
        v = vx[i]
        px[i], vx[i] = verlet_axis(px[i], v, vxm[i], ax[i], dt, euler)
        vxm[i] = v
        v = vy[i]
        py[i], vy[i] = verlet_axis(py[i], v, vym[i], ay[i], dt, euler)
        vym[i] = v
        if dim == 3:
            v = vz[i]
            pz[i], vz[i] = verlet_axis(pz[i], v, vzm[i], az[i], dt, euler)
            vzm[i] = v
        rho[i] = rnew
    else:
        rho[i] = bound_density(rnew, rho0)


def k_sym_predict(px, py, pz, vx, vy, vz, rho, px0, py0, pz0, vx0, vy0, vz0, rho0_, kind, ax, ay, az, ar,
                  n, dim, dt, rho_ref):
    """Symplectic predictor (half step dt/2); the stage start kept in px0.., vx0.., rho0_."""
    i = cuda.grid(1)
    if i >= n:
        return
    rho0_[i] = rho[i]
    r = predict_density(rho[i], ar[i], dt)
    if kind[i] == 0:
        px0[i] = px[i]
        vx0[i] = vx[i]
        px[i], vx[i] = predict_axis(px[i], vx[i], ax[i], dt)
        py0[i] = py[i]
        vy0[i] = vy[i]
        py[i], vy[i] = predict_axis(py[i], vy[i], ay[i], dt)
        if dim == 3:
            pz0[i] = pz[i]
            vz0[i] = vz[i]
            pz[i], vz[i] = predict_axis(pz[i], vz[i], az[i], dt)
        rho[i] = r
    else:
        rho[i] = bound_density(r, rho_ref)


def k_sym_correct(px, py, pz, vx, vy, vz, rho, px0, py0, pz0, vx0, vy0, vz0, rho0_, kind, ax, ay, az, ar,
                  n, dim, dt, rho_ref):
    """Symplectic corrector from the stage start (px0.., vx0.., rho0_)."""
    i = cuda.grid(1)
    if i >= n:
        return
    r = correct_density(rho0_[i], rho[i], ar[i], dt)
    if kind[i] == 0:
        px[i], vx[i] = correct_axis(px0[i], vx0[i], ax[i], dt)
        py[i], vy[i] = correct_axis(py0[i], vy0[i], ay[i], dt)
        if dim == 3:
            pz[i], vz[i] = correct_axis(pz0[i], vz0[i], az[i], dt)
        rho[i] = r
    else:
        rho[i] = bound_density(r, rho_ref)


def k_wrap(px, py, pz, n, lo0, lo1, lo2, hi0, hi1, hi2, p0, p1, p2, w0, w1, w2):
    """Positions on the wrapped axes (w0..w2 nonzero) brought back into [lo, hi)
    (sphgraph.physics.wrap.wrap_axis, as on the host)."""
    i = cuda.grid(1)
    if i >= n:
        return
    if w0:
        px[i] = wrap_axis(px[i], lo0, hi0, p0)
    if w1:
        py[i] = wrap_axis(py[i], lo1, hi1, p1)
    if w2:
        pz[i] = wrap_axis(pz[i], lo2, hi2, p2)


def k_damp(px, py, pz, vx, vy, vz, kind, n, dim, zones, nz, dt):
    """Fluid rows' velocities times their relaxation zones' factor (sphgraph.physics.damping)."""
    i = cuda.grid(1)
    if i >= n or kind[i] != 0:
        return
    f = damping_factor(px[i], py[i], pz[i] if dim == 3 else 0.0, zones, nz, dt)
    if f < 1.0:
        vx[i] = vx[i] * f
        vy[i] = vy[i] * f
        if dim == 3:
            vz[i] = vz[i] * f
