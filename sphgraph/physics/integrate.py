"""Time integration of one row: DualSPHysics' Verlet and Symplectic steps.

Per-row maths written once: the numba CPU kernels (backends/compute/cpu_kernels.py)
loop over rows and axes and call these; the numba.cuda kernels
(backends/compute/cuda_integrate.py) get device copies of them (cuda_retarget). One
axis of a row at a time: the CPU holds (n, dim) arrays, the GPU one array per axis.

Verlet (DualSPHysics ComputeVerlet), Euler step every `verlet_steps`:

    r += dt v + dt^2/2 a;  v_new = v_m1 + 2 dt a (Euler: v + dt a);
    rho_new = rho_m1 + 2 dt ar (Euler: rho + dt ar); with the DuFort-Frankel diffusion
    step (K_a = dk, sphgraph.physics.interact.diffusion_coef)
    rho_new = (rho_m1 (1 - dt K_a) + 2 dt (ar + K_a rho)) / (1 + dt K_a).

Symplectic (ComputeSymplecticPre / Corr): the predictor advances dt/2,
r* = r0 + dt/2 v0, v* = v0 + dt/2 a, rho* = rho0 + dt/2 ar; the corrector
v = v0 + dt a, r = r0 + dt (v + v0)/2, rho = rho0 (2 - e)/(2 + e) with e = -ar/rho dt
(the Pade form of rho0 exp(ar/rho dt)).

Boundary rows (DBC) keep their position; their density is clamped to >= rho0
(ComputeVerletVarsBound: a wall below rho0 would attract the fluid).
"""
from numba import njit


@njit(inline="always", cache=True)
def verlet_density(rho, rho_m1, ar, dk, dt, euler, df):
    """The Verlet step's new density of a row (`df`: the DuFort-Frankel form with K_a = dk)."""
    if euler:
        return rho + dt * ar
    if df:
        kd = dt * dk
        return (rho_m1 * (1.0 - kd) + 2.0 * dt * (ar + dk * rho)) / (1.0 + kd)
    return rho_m1 + 2.0 * dt * ar


@njit(inline="always", cache=True)
def verlet_axis(p, v, v_m1, a, dt, euler):
    """One axis of a fluid row's Verlet step: (new position, new velocity); the
    caller keeps `v` as the next step's v_m1."""
    p_new = p + (dt * v + 0.5 * dt * dt * a)
    if euler:
        return p_new, v + dt * a
    return p_new, v_m1 + 2.0 * dt * a


@njit(inline="always", cache=True)
def bound_density(r, rho0):
    """A boundary row's density after a step: clamped to >= rho0 (DBC)."""
    return r if r > rho0 else rho0


@njit(inline="always", cache=True)
def predict_axis(p, v, a, dt):
    """One axis of a fluid row's Symplectic predictor (half step): (r*, v*)."""
    h = 0.5 * dt
    return p + h * v, v + h * a


@njit(inline="always", cache=True)
def predict_density(rho, ar, dt):
    return rho + 0.5 * dt * ar


@njit(inline="always", cache=True)
def correct_axis(p0, v0, a, dt):
    """One axis of a fluid row's Symplectic corrector from the stage start (p0, v0):
    (position, velocity)."""
    v = v0 + dt * a
    return p0 + dt * 0.5 * (v + v0), v


@njit(inline="always", cache=True)
def correct_density(rho0, rho, ar, dt):
    e = -ar / rho * dt
    return rho0 * (2.0 - e) / (2.0 + e)
