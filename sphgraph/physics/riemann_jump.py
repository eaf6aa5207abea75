"""The Riemann term's pressure jump with its linear part removed (`[physics] riemann_jump =
"renormalised"`; docs/validation.md, "A jump with its linear part removed").

The continuity equation of `interact.riemann_pair` carries, for every fluid pair, the jump

    J_ab = m_b rho_a/rho_b F r (P_a - P_b) / (rho0 c0)

(F the kernel gradient factor, r = |r_ab|, r_ab = r_a - r_b). In a smooth pressure field
P_a - P_b = grad P_a . r_ab + O(r^2): where a's neighbours sit on one side only (a wall, a
free surface) the linear part does not cancel over the pairs and the jump moves density
along the pressure gradient -- next to an mDBC wall during an impact it drains the rows at the
wall, the ghost reads the lowered density and the wall pushes back less. The renormalised
jump takes that part out:

    J_ab = m_b rho_a/rho_b F r [(P_a - P_b) - grad P_a . r_ab] / (rho0 c0),

which leaves the jump's dissipation of pressure noise (the part of P_a - P_b beyond linear)
and drops its first-order truncation term. grad P_a is the renormalised gradient over a's
fluid neighbours (boundary rows carry a wall's reaction, not a fluid pressure):

    grad P_a = M_a^-1 g_a,  M_a = sum_b V_b (r_b - r_a) (x) grad W_ab = -sum_b V_b F r_ab r_ab^T,
                            g_a = sum_b V_b (P_b - P_a) grad W_ab = sum_b V_b (P_b - P_a) F r_ab,

exact for a linear field whatever the neighbour set (Randles & Libersky 1996; Bonet & Lok
1999). Where a's fluid neighbours fill too little of its support for M_a to be invertible
with confidence -- det M_a below RJ_DET_MIN (1 for a full support; about 1/4 in 2D and 1/8 in
3D for a half one, a row on a flat wall or surface; less in a corner or a spray) -- the row
keeps the plain jump.

Every term is a sum over the pairs of row a, so it splits over the parts of a row's
neighbours (interior, halo 1, halo 2) like the rest of the force: each part sums, for its
fluid pairs, the twelve moments

    M (6: m00 m01 m02 m11 m12 m22), g (3), S = sum_b m_b rho_a/rho_b F r r_ab / (rho0 c0) (3),

(`jump_moments`), and the correction -grad P_a . S_a is added once per row where the parts
are summed (`jump_correction`). With riemann_wall = "cancel" a wall neighbour cancels the jump
of only the rows it cannot renormalise (`jump_kept`): those keep the plain jump's first-order
drain, which in SPHERIC 2's 3D impacts let the fluid through mDBC walls (the rows at a wall and
roof corner, a thin sheet running up a wall), while a row whose gradient is formed keeps its
corrected jump and with it the dissipation that "cancel" alone takes away next to every wall.
numba-cpu and numba-cuda call these same functions.
"""
from numba import njit

from ..config import O_RIEMANN_JUMP, P_RHO0C0
from .kernels import grad_factor

RJ_SUMS = 12                      # the moments a row carries per part (m 6, g 3, s 3)
RJ_DET_MIN_2D = 0.2               # det M_a below which a row keeps the plain jump (module doc)
RJ_DET_MIN_3D = 0.08


def renormalised(opt) -> bool:
    """Whether a run's options (config.derive's `opt`) ask for the renormalised jump: derive sets
    O_RIEMANN_JUMP only with the Riemann term on, so this one entry decides."""
    return bool(opt[O_RIEMANN_JUMP])


@njit(inline="always", cache=True)
def jump_moments(drx, dry, drz, r2, r, rho_a, rho_b, p_a, p_b, mass_b, prm, kernel):
    """What fluid neighbour b adds to row a's twelve sums (module docstring): M (m00 m01 m02 m11
    m12 m22), g (g0 g1 g2), S (s0 s1 s2)."""
    fac = grad_factor(r2, prm, kernel)
    vf = (mass_b / rho_b) * fac
    w = -vf
    q = vf * (p_b - p_a)
    s = (mass_b * rho_a) * fac / rho_b * r / prm[P_RHO0C0]
    return (w * drx * drx, w * drx * dry, w * drx * drz, w * dry * dry, w * dry * drz, w * drz * drz,
            q * drx, q * dry, q * drz, s * drx, s * dry, s * drz)


@njit(inline="always", cache=True)
def _det(m00, m01, m02, m11, m12, m22, dim):
    """det M_a (the 2x2 block in 2D), expanded along the first row as jump_correction's cofactors."""
    if dim == 2:
        return m00 * m11 - m01 * m01
    return m00 * (m11 * m22 - m12 * m12) + m01 * (m02 * m12 - m01 * m22) + m02 * (m01 * m12 - m02 * m11)


@njit(inline="always", cache=True)
def _det_min(dim):
    return RJ_DET_MIN_2D if dim == 2 else RJ_DET_MIN_3D


@njit(inline="always", cache=True)
def renormalisable(m00, m01, m02, m11, m12, m22, dim):
    """Whether row a's M_a is invertible with confidence (det M_a above RJ_DET_MIN)."""
    return _det(m00, m01, m02, m11, m12, m22, dim) > _det_min(dim)


@njit(inline="always", cache=True)
def jump_kept(cc, m00, m01, m02, m11, m12, m22, dim):
    """Whether row a keeps its (corrected) jump: no neighbour cancelled it (cc == 0), or one did
    (riemann_wall = "cancel") but the row's gradient is renormalised (module docstring)."""
    return cc == 0 or renormalisable(m00, m01, m02, m11, m12, m22, dim)


@njit(inline="always", cache=True)
def jump_correction(m00, m01, m02, m11, m12, m22, g0, g1, g2, s0, s1, s2, dim):
    """-grad P_a . S_a: what the row's summed jumps lose with their linear part (0 where det M_a
    is below RJ_DET_MIN: the row keeps the plain jump)."""
    det = _det(m00, m01, m02, m11, m12, m22, dim)
    if not det > _det_min(dim):
        return 0.0 * det
    inv = 1.0 / det
    if dim == 2:
        gx = (m11 * g0 - m01 * g1) * inv
        gy = (m00 * g1 - m01 * g0) * inv
        return -(gx * s0 + gy * s1)
    c00 = m11 * m22 - m12 * m12
    c01 = m02 * m12 - m01 * m22
    c02 = m01 * m12 - m02 * m11
    c11 = m00 * m22 - m02 * m02
    c12 = m01 * m02 - m00 * m12
    c22 = m00 * m11 - m01 * m01
    gx = (c00 * g0 + c01 * g1 + c02 * g2) * inv
    gy = (c01 * g0 + c11 * g1 + c12 * g2) * inv
    gz = (c02 * g0 + c12 * g1 + c22 * g2) * inv
    return -(gx * s0 + gy * s1 + gz * s2)
