"""Physics options and the constants derived from them.

Defaults follow DualSPHysics (v5 XML defaults and the formulas in JSph.cpp /
JSphCpu.cpp): h = coefh*sqrt(dim)*dp, Tait EOS with gamma 7,
c0 = coefsound*sqrt(g*Hswl), B = c0^2*rho0/gamma, eta^2 = (0.1 h)^2,
artificial viscosity alpha 0.01, density diffusion delta 0.1, CFL 0.2,
Verlet with an Euler step every 40 steps, density bounds 700-1300 kg/m^3
(DualSPHysics RhopOutMin/RhopOutMax).

Kernels receive the constants as one flat float array `prm` and the switches as
one int array `opt`; the index names below are shared by every compute backend.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, asdict

import numpy as np

KERNELS = ("wendland", "cubic")
DIFFUSIONS = ("none", "molteni", "fourtakas", "fourtakas-full")
INTEGRATORS = ("verlet", "symplectic")
CELL_SIZES = ("2h", "h")
# particle shifting modes, in DualSPHysics' order (JSphShifting::ReadXml, <shifting mode>:
# 0 None, 1 NoBound "ignore bound", 2 NoFixed "ignore fixed", 3 Full); see sphgraph.shifting
SHIFTINGS = ("none", "nobound", "nofixed", "full")
# wall treatment: dynamic boundaries (DualSPHysics DBC) or modified DBC (English et al. 2019,
# sphgraph.physics.mdbc; "mdbc-noslip" also mirrors the fluid velocity), DualSPHysics SlipMode
BOUNDARIES = ("dbc", "mdbc", "mdbc-noslip")
# how the Verlet step advances the density-diffusion term (sphgraph.physics.interact,
# diffusion_coef): "leapfrog" as DualSPHysics (rho_m1 + 2 dt ar: unstable for a diffusion
# term, its odd-even mode grows between the Euler steps), "dufort-frankel" (DuFort &
# Frankel 1953: the particle's own density in the term is the mean of the new and the
# previous one, unconditionally stable for diffusion)
DIFFUSION_TIMES = ("leapfrog", "dufort-frankel")
# the pressure term of fluid pairs (sphgraph.physics.interact): "none" = DualSPHysics' centred
# (P_a + P_b) with artificial viscosity and density diffusion; "zhang2017" = the linearised
# (acoustic) Riemann solution with the low-dissipation limiter of Zhang, Hu & Adams 2017
RIEMANNS = ("none", "zhang2017")
RIEMANN_WALLS = ("skip", "cancel")     # what a wall neighbour does to the U* jump (riemann_pair)
# the U* jump of fluid pairs: as Zhang, Hu & Adams 2017, or with its linear part removed
# (sphgraph.physics.riemann_jump)
RIEMANN_JUMPS = ("plain", "renormalised")

# prm indices
P_H, P_H2, P_SUPPORT2, P_AW, P_BW, P_C0, P_B, P_GAMMA, P_RHO0, P_ETA2 = range(10)
P_VISC, P_VISC_BOUND, P_NU, P_DDT_KH, P_GX, P_GY, P_GZ, P_MASS_F, P_MASS_B = range(10, 19)
P_CUBIC_A24 = 19
P_HYD1, P_HYD2, P_HYD3, P_HYD4, P_RHO0_B = 20, 21, 22, 23, 24  # series of (1+y)^(1/gamma) - 1; rho0/B
P_INV_H, P_BWH, P_YMAX = 25, 26, 27
P_RHO0C0, P_RIEMANN_ETA = 28, 29   # rho0 c0 and the limiter's factor (riemann_pair)  # P_YMAX: the largest |y| of the series (fluid_pair)
P_DDT_KCM = 30                   # delta 2h m_f c0: the Fourtakas term's constant (fluid_pair)
P_WALL_NOSLIP = 31                # 1: boundary rows carry mDBC's no-slip velocity, for the viscous terms only (fluid_pair)
P_RIEMANN_CANCEL, P_COUNT = 32, 33  # 1: a boundary neighbour cancels the row's U* jump (riemann_pair)
# opt indices
O_DIM, O_KERNEL, O_DDT, O_LAMINAR, O_DDT_DF, O_RIEMANN, O_RIEMANN_JUMP, O_COUNT = range(8)
# opt values
K_WENDLAND, K_CUBIC = 0, 1
D_NONE, D_MOLTENI, D_FOURTAKAS, D_FOURTAKAS_FULL = 0, 1, 2, 3


@dataclass
class PhysicsConfig:
    """Every physics option a scene may set (the `[physics]` table)."""

    kernel: str = "wendland"
    coefh: float = 1.0
    coefsound: float = 20.0
    gamma: float = 7.0
    rho0: float = 1000.0
    gravity: tuple | None = None        # None: (0, -9.81) in 2D, (0, 0, -9.81) in 3D
    visc_alpha: float = 0.01
    visc_bound_factor: float = 1.0
    laminar_nu: float = 0.0             # kinematic viscosity [m^2/s]; 0 = off (Lo & Shao 2002 form)
    diffusion: str = "fourtakas"
    delta: float = 0.1
    integrator: str = "verlet"
    verlet_euler_every: int = 40
    cfl: float = 0.2
    hswl: float | None = None           # still-water depth for c0; None = fluid height
    rho_min: float = 700.0
    rho_max: float = 1300.0
    cell_size: str = "2h"
    shifting: str = "none"              # particle shifting mode (SHIFTINGS), sphgraph.shifting
    shifting_coef: float = -2.0         # DualSPHysics ShiftCoef (default -2): A = -coef in Lind et al.
    shifting_tfs: float = 0.0           # DualSPHysics ShiftTFS: free-surface threshold of div r; 0 = off
    boundary: str = "dbc"               # wall treatment (BOUNDARIES); mDBC: sphgraph.physics.mdbc
    diffusion_time: str = "leapfrog"    # Verlet's density-diffusion step (DIFFUSION_TIMES)
    riemann: str = "none"               # Riemann-solver pressure term of fluid pairs (RIEMANNS)
    riemann_eta: float = 3.0            # the limiter's factor (Zhang, Hu & Adams 2017: 3)
    riemann_wall: str = "skip"          # a wall neighbour adds no U* jump, or cancels the row's (RIEMANN_WALLS)
    riemann_jump: str = "plain"         # the U* jump as it is, or with its linear part removed (RIEMANN_JUMPS)

    @classmethod
    def field_names(cls):
        return [f.name for f in fields(cls)]

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Constants:
    """Derived constants for a scene at a given dp."""

    dim: int
    dp: float
    h: float
    c0: float
    B: float
    mass_fluid: float
    mass_bound: float
    gravity: np.ndarray
    cell_size: float
    prm: np.ndarray   # float64; cast by the backend to its precision
    opt: np.ndarray   # int64


def derive(cfg: PhysicsConfig, dim: int, dp: float, hswl: float) -> Constants:
    """Constants of DualSPHysics' formulation for `dim`, `dp` and still-water depth `hswl`."""
    g = np.array(cfg.gravity if cfg.gravity is not None else ([0.0] * (dim - 1) + [-9.81]), float)
    gmag = float(np.linalg.norm(g)) or 9.81
    h = cfg.coefh * math.sqrt(dim) * dp                  # JSph: H = CoefH*sqrt(dim*Dp^2)
    c0 = cfg.coefsound * math.sqrt(gmag * max(hswl, dp))  # JSph: Cs0 = CoefSound*sqrt(g*HSwl)
    B = c0 * c0 * cfg.rho0 / cfg.gamma                   # JSph: CteB = Cs0^2*RhopZero/Gamma
    mass = cfg.rho0 * dp ** dim                          # JSph: MassFluid = MassBound = RhopZero*Dp^dim
    if cfg.kernel == "wendland":
        # Wendland C2 (Wendland 1995): W = aw (1-q/2)^4 (2q+1), q = r/h in [0, 2]
        aw = 7.0 / (4.0 * math.pi * h * h) if dim == 2 else 21.0 / (16.0 * math.pi * h ** 3)
        bw = -5.0 * aw / h                               # dW/dr = bw * q (1-q/2)^3
    else:
        # cubic spline (Monaghan & Lattanzio 1985)
        aw = 10.0 / (7.0 * math.pi * h * h) if dim == 2 else 1.0 / (math.pi * h ** 3)
        bw = aw / h
    prm = np.zeros(P_COUNT)
    prm[P_H] = h
    prm[P_H2] = h * h
    prm[P_SUPPORT2] = 4.0 * h * h
    prm[P_AW] = aw
    prm[P_BW] = bw
    prm[P_C0] = c0
    prm[P_B] = B
    prm[P_GAMMA] = cfg.gamma
    prm[P_RHO0] = cfg.rho0
    prm[P_ETA2] = (0.1 * h) ** 2                         # JSph: Eta2 = (h*0.1)^2
    prm[P_VISC] = cfg.visc_alpha
    prm[P_VISC_BOUND] = cfg.visc_alpha * cfg.visc_bound_factor
    prm[P_NU] = cfg.laminar_nu
    prm[P_DDT_KH] = cfg.delta * 2.0 * h                  # JSph: DDTkh = DDTValue*KernelSize (2h)
    prm[P_GX:P_GX + dim] = g
    prm[P_MASS_F] = mass
    prm[P_MASS_B] = mass
    prm[P_CUBIC_A24] = 0.25 * aw                         # cubic: W = a24 (2-q)^3 for 1<q<2
    # binomial series of (1+y)^k - 1, k = 1/gamma: exact to round-off for |y| < 1e-3
    k = 1.0 / cfg.gamma
    prm[P_HYD1] = k
    prm[P_HYD2] = prm[P_HYD1] * (k - 1.0) / 2.0
    prm[P_HYD3] = prm[P_HYD2] * (k - 2.0) / 3.0
    prm[P_HYD4] = prm[P_HYD3] * (k - 3.0) / 4.0
    prm[P_RHO0_B] = cfg.rho0 / B
    # the largest |y| = |g . r_ab| rho0/B a pair within 2h can have: below the series' range
    # the Fourtakas term needs no pow() branch (fluid_pair; a compile-time fold on the GPU)
    prm[P_YMAX] = float(np.linalg.norm(g)) * 2.0 * h * prm[P_RHO0_B]
    prm[P_INV_H] = 1.0 / h
    prm[P_BWH] = bw / h
    prm[P_RHO0C0] = cfg.rho0 * c0
    prm[P_RIEMANN_ETA] = cfg.riemann_eta
    # one constant, formed here in this order: a product of prm loads inside a fastmath kernel
    # is regrouped by LLVM in the order the loads are emitted, which any change of the
    # kernel's code around it (a call, an inlined helper) moves, and with it the last bits
    prm[P_DDT_KCM] = (prm[P_DDT_KH] * mass) * c0
    prm[P_WALL_NOSLIP] = 1.0 if cfg.boundary == "mdbc-noslip" else 0.0
    prm[P_RIEMANN_CANCEL] = float(RIEMANN_WALLS.index(cfg.riemann_wall))
    opt = np.zeros(O_COUNT, np.int64)
    opt[O_DIM] = dim
    opt[O_KERNEL] = KERNELS.index(cfg.kernel)
    # the Riemann term carries its own density dissipation: no diffusion term with it
    opt[O_DDT] = DIFFUSIONS.index(cfg.diffusion) if cfg.delta > 0 and cfg.riemann == "none" else D_NONE
    opt[O_LAMINAR] = 1 if cfg.laminar_nu > 0 else 0
    opt[O_RIEMANN] = RIEMANNS.index(cfg.riemann)
    opt[O_RIEMANN_JUMP] = RIEMANN_JUMPS.index(cfg.riemann_jump) if cfg.riemann != "none" else 0
    opt[O_DDT_DF] = 1 if (cfg.diffusion_time == "dufort-frankel" and opt[O_DDT] != D_NONE) else 0
    cell = 2.0 * h if cfg.cell_size == "2h" else h
    return Constants(dim=dim, dp=dp, h=h, c0=c0, B=B, mass_fluid=mass, mass_bound=mass,
                     gravity=g, cell_size=cell, prm=prm, opt=opt)
