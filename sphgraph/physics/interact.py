"""Pair interaction of weakly compressible SPH (DualSPHysics formulation).

One call evaluates what particle b contributes to particle a (r_ab = r_a - r_b,
v_ab = v_a - v_b, F the kernel gradient factor, grad_a W = F r_ab), following
DualSPHysics JSphCpu::InteractionForcesFluid / InteractionForcesBound:

continuity   drho_a/dt += m_b (v_ab . grad W) rho_a / rho_b
momentum     dv_a/dt   += -m_b (P_a + P_b)/(rho_a rho_b) grad W
artificial viscosity (Monaghan 1992), only when v_ab . r_ab < 0:
             dv_a/dt   += m_b alpha c0 h (v_ab.r_ab)/(r^2+eta^2) / rho_bar grad W
laminar viscosity (Lo & Shao 2002), when nu > 0:
             dv_a/dt   += m_b 4 nu (r_ab . grad W) / ((rho_a+rho_b)(r^2+eta^2)) v_ab
density diffusion (returned apart, `ddt`, see below):
  Molteni & Colagrossi 2009:  delta 2h c0 (rho_a/rho_b - 1)(r_ab . grad W)/(r^2+eta^2) m_b
  Fourtakas et al. 2019:     -delta 2h c0 ((rho_b - rho_a) - rho^H_ba)(r_ab . grad W)/(r^2+eta^2) m_b/rho_b
     with the hydrostatic part rho^H_ba = rho0 [(1 + (P^H_b - P^H_a)/B)^(1/gamma) - 1],
     P^H_b - P^H_a = rho0 g . (r_b - r_a), so a fluid at rest diffuses nothing.
  With DBC a boundary neighbour cancels the diffusion of particle a ("Molteni",
  "fourtakas"); "fourtakas-full" instead just skips boundary neighbours.
DuFort-Frankel diffusion step (`[physics] diffusion_time = "dufort-frankel"`, Verlet only):
  both diffusion forms are affine in rho_a, ddt_a = D_a - K_a rho_a with
  K_a = sum_b k_ab, k_ab = -delta 2h c0 m_b/rho_b (r_ab . grad W)/(r^2+eta^2) >= 0
  (`diffusion_coef`; Wendland's and the cubic's F < 0). Verlet's leapfrog
  rho^{n+1} = rho^{n-1} + 2 dt ar^n integrates -K_a rho_a with an odd-even mode that grows
  by (1 + dt K_a) a step (unconditionally unstable for a decay term; the Euler step every
  40 steps only resets it); with rho_a in that term taken as (rho^{n+1} + rho^{n-1})/2
  (DuFort & Frankel 1953, Proc. Roy. Soc. A; Durran 2010, Numerical Methods for Fluid
  Dynamics, §3.3) the step is
      rho^{n+1} = (rho^{n-1} (1 - dt K_a) + 2 dt (ar^n + K_a rho^n)) / (1 + dt K_a),
  whose roots have |z|^2 = (1 - dt K_a)/(1 + dt K_a) < 1 for the term alone: stable at
  any dt, second order, and the same limit as the leapfrog when dt K_a -> 0.
Riemann-solver pressure term (`[physics] riemann = "zhang2017"`, `riemann_pair`; Zhang, Hu &
Adams 2017, J. Comput. Phys. 335:605-620, doi:10.1016/j.jcp.2017.01.027): each pair is the
1D Riemann problem along e = r_ab/r with left state a, right state b, U_L = -v_a . e,
U_R = -v_b . e, solved linearised (acoustic impedance rho0 c0):
             U* = (U_L + U_R)/2 + (P_a - P_b)/(2 rho0 c0)
             P* = (P_a + P_b)/2 + rho0 c0 beta (U_L - U_R)/2,
             beta = min(eta max(U_L - U_R, 0)/c0, 1)   (the low-dissipation limiter, eta = 3:
                    dissipation only where the pair is compressed, none in expansion)
continuity   drho_a/dt += 2 rho_a m_b/rho_b (v_a - v*) . grad W
                        = m_b rho_a/rho_b F [v_ab . r_ab + r (P_a - P_b)/(rho0 c0)]
momentum     dv_a/dt   += -m_b 2 P*/(rho_a rho_b) grad W
The P* dissipation replaces the artificial viscosity and the U* pressure jump the density
diffusion (neither is added for these pairs); the laminar term is kept.
Riemann term next to walls (`[physics] riemann_wall`): "skip" (default), a boundary b adds no
pressure jump (SPHinXsys' wall form adds only its hydrostatic part) while a's fluid neighbours
still do; "cancel", a boundary b in reach cancels a's jump, as a DBC wall cancels the Molteni
diffusion. Next to a wall a's fluid neighbours lie on one side only, so during an impact the
jump drains density from the rows at the wall towards the fluid behind them (a first-order
truncation term); an mDBC wall reads that lowered density at its ghost and pushes back less.
In a fast impact on mDBC walls that loop can let fluid through the wall, which "cancel" stops;
but "cancel" leaves the rows at the wall without any density dissipation, and the wall pressure
they give turns to acoustic noise (measured in docs/validation.md, "Riemann term next to walls").
mDBC no-slip walls (`[physics] boundary = "mdbc-noslip"`, prm P_WALL_NOSLIP = 1): a still
wall's row b (kind FIXED, `b_still`) has for velocity the mirrored tangential fluid velocity
its ghost sees (physics.mdbc), which the viscous terms (artificial, laminar, the dt term)
take; the continuity equation and the Riemann term's compression take the wall's own
velocity, zero, as DualSPHysics' mDBC does (the no-slip velocity goes to the viscosity only).
A moving body's rows (kind MOVING) keep the body's velocity, and every term takes it: the
continuity the wall's own velocity, as above, and the viscous terms the body's velocity at
its rows (DualSPHysics' DBC and mDBC "vel=0" modes on a moving body) rather than a mirror
about it, which would need the body's velocity as a second per-row velocity in every pair
loop and halo (DualSPHysics' no-slip keeps one, MotionVel). In the continuity
sum the mirrored velocity's variation along the wall reads as a compression or expansion of
the fluid next to it: behind Yeh & Petroff's surge front over the wet bed it lowered the rows'
density and pulled fluid into the floor (docs/validation.md).
viscous dt term  max over b of h (v_ab . r_ab)/(r^2 + eta^2) (DualSPHysics ViscDt); the pair
             functions return it without the factor h, which the callers apply to the
             maximum (h > 0, so max(h x) = h max(x) to the bit; one multiply a pair less).

The functions are plain @njit so the numba CPU driver and numba.cuda kernels share them.
"""
import math

from numba import njit

from ..config import (P_HYD1, P_HYD2, P_HYD3, P_HYD4, P_RHO0_B, P_C0, P_ETA2, P_GAMMA, P_GX, P_GY, P_GZ, P_H, P_DDT_KH, P_NU,
                      P_RHO0, P_RHO0C0, P_RIEMANN_ETA, P_DDT_KCM, P_VISC, P_VISC_BOUND, P_RIEMANN_CANCEL, P_WALL_NOSLIP, P_YMAX, D_NONE, D_MOLTENI,
                      D_FOURTAKAS_FULL)
from .kernels import grad_factor


@njit(inline="always", cache=True)
def gravity_dot(drx, dry, drz, prm, s):
    """s g . r_ab over gravity's nonzero components only, the factor s taken into each
    component (s gx) drx: on the GPU the parameters are compile-time constants, so the
    tests and the products s gx fold away (one multiply a pair with g along one axis)."""
    if prm[P_GX] != 0.0:
        gr = (s * prm[P_GX]) * drx
        if prm[P_GY] != 0.0:
            gr += (s * prm[P_GY]) * dry
        if prm[P_GZ] != 0.0:
            gr += (s * prm[P_GZ]) * drz
    elif prm[P_GY] != 0.0:
        gr = (s * prm[P_GY]) * dry
        if prm[P_GZ] != 0.0:
            gr += (s * prm[P_GZ]) * drz
    else:
        gr = (s * prm[P_GZ]) * drz
    return gr


@njit(inline="always", cache=True)
def wall_dot(dot, drx, dry, drz, vxb, vyb, vzb, b_still, prm):
    """v_ab . r_ab for the continuity equation: `dot` itself, or with b a still mDBC no-slip
    wall row (`b_still`; velocity vb: its no-slip velocity, for the viscous terms only)
    v_a . r_ab, the wall's own velocity being zero (module docstring). On the GPU prm is
    constant: the test folds away where the scene has no such walls."""
    if prm[P_WALL_NOSLIP] != 0.0 and b_still:
        return dot + (vxb * drx + vyb * dry + vzb * drz)
    return dot


@njit(inline="always", cache=True)
def fluid_pair(drx, dry, drz, r2, dvx, dvy, dvz, vxb, vyb, vzb, rho_a, inv_rho_a, rho_b, p_a, p_b, mass_b,
               b_bound, b_still, prm, kernel, ddt_kind, laminar):
    """Contribution of b to fluid particle a (v_ab = dv, v_b = vb). `b_bound`: b is a
    boundary row; `b_still`: b is a row of a still wall (kind FIXED), whose velocity under
    no-slip mDBC is the mirror the viscous terms take (wall_dot).

    Returns (ax, ay, az, ar, ddt, cancel, visc) where `cancel` is 1 when b
    switches a's density diffusion off (DBC neighbour), `visc` the ViscDt term / h.
    """
    fac = grad_factor(r2, prm, kernel)
    inv_rho_b = 1.0 / rho_b          # shared reciprocals: divisions dominate the pair cost
    inv_r2e = 1.0 / (r2 + prm[P_ETA2])
    dot = dvx * drx + dvy * dry + dvz * drz
    # grad W = F r_ab, so v_ab . grad W = F (v_ab . r_ab) and r_ab . grad W = F r^2: two
    # scalar products a pair instead of four, and the momentum sum takes (coef F) r_ab.
    # Factors of a alone (m_b rho_a, -m_b / rho_a) first: the kernels hoist them out of the
    # loop over b, and with fastmath a product is not reassociated for them
    ar = (mass_b * rho_a) * (fac * dot) * inv_rho_b
    # a still no-slip wall's continuity, v_a . r_ab (wall_dot), added as a term of its own:
    # folding it into `dot` let the CPU's fastmath regroup the default path (the example
    # digests moved); added, the path without such walls compiles as before
    if prm[P_WALL_NOSLIP] != 0.0 and b_still:
        ar += (mass_b * rho_a) * (fac * (vxb * drx + vyb * dry + vzb * drz)) * inv_rho_b
    dot_rr2 = dot * inv_r2e
    coef = (p_a + p_b) * (-mass_b * inv_rho_a) * inv_rho_b
    if dot < 0.0:
        alpha = prm[P_VISC_BOUND] if b_bound else prm[P_VISC]
        # 1 / rho_bar = 2 / (rho_a + rho_b) as a reciprocal (fastmath: one approximate
        # reciprocal, where a division keeps a range check), the constants in one factor
        coef += (2.0 * alpha * prm[P_C0] * prm[P_H] * mass_b) * dot_rr2 * (1.0 / (rho_a + rho_b))
    cf = coef * fac
    ax = cf * drx
    ay = cf * dry
    az = cf * drz
    rfr = fac * r2
    if laminar:
        lam = mass_b * 4.0 * prm[P_NU] * rfr * inv_r2e / (rho_a + rho_b)
        ax += lam * dvx
        ay += lam * dvy
        az += lam * dvz
    ddt = 0.0 * ar
    cancel = 0
    if ddt_kind != D_NONE:
        if b_bound:
            cancel = 0 if ddt_kind == D_FOURTAKAS_FULL else 1
        elif ddt_kind == D_MOLTENI:
            ddt = prm[P_DDT_KH] * prm[P_C0] * (rho_a * inv_rho_b - 1.0) * inv_r2e * rfr * mass_b
        else:
            # hydrostatic density difference rho^H_b - rho^H_a from P^H_b - P^H_a = -rho0 g . r_ab
            y = gravity_dot(drx, dry, drz, prm, -prm[P_RHO0_B])
            # binomial series, exact to round-off for |y| < 1e-3 (float32 kernels: 2e-2,
            # F32_REMAP): pow() per pair is slow, and where no pair of the scene can reach
            # past the series' range (P_YMAX, a constant on the GPU) the branch folds away
            if prm[P_YMAX] < 1e-3 or abs(y) < 1e-3:
                drho_h = (prm[P_RHO0] * y) * (prm[P_HYD1] + y * (prm[P_HYD2] + y * (prm[P_HYD3] + y * prm[P_HYD4])))
            else:
                drho_h = prm[P_RHO0] * ((1.0 + y) ** prm[P_HYD1] - 1.0)
            # -delta 2h c0 m_b with m_b = m_f: a boundary b never reaches here (it cancels the term)
            ddt = -prm[P_DDT_KCM] * ((rho_b - rho_a) - drho_h) * inv_r2e * rfr * inv_rho_b
    return ax, ay, az, ar, ddt, cancel, dot_rr2


@njit(inline="always", cache=True)
def riemann_pair(drx, dry, drz, r2, dvx, dvy, dvz, vxb, vyb, vzb, rho_a, inv_rho_a, rho_b, p_a, p_b, mass_b,
                 b_bound, b_still, prm, kernel, laminar):
    """Contribution of b to fluid particle a with the Riemann-solver pressure term (module
    docstring), in `fluid_pair`'s shape: (ax, ay, az, ar, ddt, cancel, visc), visc the ViscDt
    term / h. The continuity's U* pressure jump is the pair's `ddt` (summed apart and added
    unless a neighbour cancels it): it is a density diffusion. A boundary b adds none: its
    pressure is the wall's reaction, not a fluid state (with DBC walls diffusing towards it
    pumps the density up along every wall). With `riemann_wall = "cancel"` (prm
    P_RIEMANN_CANCEL) a boundary b cancels a's jump altogether, as a DBC wall cancels the
    Molteni diffusion (module docstring, "Riemann term next to walls")."""
    fac = grad_factor(r2, prm, kernel)
    inv_rho_b = 1.0 / rho_b
    inv_r2e = 1.0 / (r2 + prm[P_ETA2])
    r = math.sqrt(r2)
    dot = dvx * drx + dvy * dry + dvz * drz          # v_ab . r_ab = -r (U_L - U_R)
    dot_c = wall_dot(dot, drx, dry, drz, vxb, vyb, vzb, b_still, prm)
    du = -dot_c / r                                  # U_L - U_R (> 0: the pair is compressed)
    rc = prm[P_RHO0C0]
    mf = (mass_b * rho_a) * fac * inv_rho_b
    ar = mf * dot_c
    jump = 0.0 * ar if b_bound else mf * (r * (p_a - p_b) / rc)
    cancel = 1 if (b_bound and prm[P_RIEMANN_CANCEL] != 0.0) else 0
    beta = min(prm[P_RIEMANN_ETA] * max(du, 0.0) / prm[P_C0], 1.0)
    p2 = p_a + p_b + rc * beta * du                  # 2 P*
    cf = p2 * (-mass_b * inv_rho_a) * inv_rho_b * fac
    ax = cf * drx
    ay = cf * dry
    az = cf * drz
    if laminar:
        lam = mass_b * 4.0 * prm[P_NU] * (fac * r2) * inv_r2e / (rho_a + rho_b)
        ax += lam * dvx
        ay += lam * dvy
        az += lam * dvz
    return ax, ay, az, ar, jump, cancel, dot * inv_r2e


@njit(inline="always", cache=True)
def diffusion_coef(r2, fac, rho_b, mass_b, prm):
    """k_ab >= 0, the coefficient of -rho_a in the pair's density-diffusion term (Molteni and
    Fourtakas alike: d ddt / d rho_a): -delta 2h c0 m_b (F r^2)/(r^2 + eta^2) / rho_b."""
    return (-prm[P_DDT_KH] * prm[P_C0] * mass_b) * (fac * r2) / ((r2 + prm[P_ETA2]) * rho_b)


@njit(inline="always", cache=True)
def fluid_pair_df(drx, dry, drz, r2, dvx, dvy, dvz, vxb, vyb, vzb, rho_a, inv_rho_a, rho_b, p_a, p_b, mass_b,
                  b_bound, b_still, prm, kernel, ddt_kind, laminar):
    """`fluid_pair` and the pair's k_ab (`diffusion_coef`) for the DuFort-Frankel step: a fluid
    b adds k_ab to K_a, a boundary b nothing (where it cancels a's diffusion, K_a is zeroed
    with the term when the parts are summed). Returns fluid_pair's tuple, then k_ab."""
    ax, ay, az, ar, ddt, cancel, visc = fluid_pair(drx, dry, drz, r2, dvx, dvy, dvz, vxb, vyb, vzb, rho_a,
                                                   inv_rho_a, rho_b,
                                                   p_a, p_b, mass_b, b_bound, b_still, prm, kernel, ddt_kind,
                                                   laminar)
    k = 0.0 * ar if b_bound else diffusion_coef(r2, grad_factor(r2, prm, kernel), rho_b, mass_b, prm)
    return ax, ay, az, ar, ddt, cancel, visc, k


@njit(inline="always", cache=True)
def bound_pair(drx, dry, drz, r2, dvx, dvy, dvz, rho_a, rho_b, mass_b, prm, kernel):
    """Contribution of fluid particle b to boundary particle a (DBC): continuity only.

    Returns (ar, visc), visc the ViscDt term / h.
    """
    fac = grad_factor(r2, prm, kernel)
    dot = dvx * drx + dvy * dry + dvz * drz
    # reciprocals, not divisions (fastmath: one approximate reciprocal each), m_b rho_a first
    # (hoisted out of the loop over b), as in fluid_pair
    ar = (mass_b * rho_a) * (fac * dot) * (1.0 / rho_b)
    return ar, dot * (1.0 / (r2 + prm[P_ETA2]))
