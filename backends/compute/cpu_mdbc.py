"""numba CPU kernel of mDBC (sphgraph.physics.mdbc): corrected fluid density and velocity at
each boundary particle's ghost node, extrapolated back to the particle."""
import numpy as np
from numba import njit, prange

from sphgraph.physics import drop_stale_cache

drop_stale_cache(__file__)  # the kernel inlines sphgraph.physics: recompile when it changes

from sphgraph.cells import cell_window  # noqa: E402
from sphgraph.config import O_DIM, O_KERNEL, P_MASS_F, P_SUPPORT2  # noqa: E402
from sphgraph.physics.mdbc import ghost_add, ghost_value  # noqa: E402


@njit(parallel=True, cache=True)
def mdbc_boundary(rows, ghost, pos, vel, rho, kind, start, origin, inv_size, dims, axes, reach,
                  prm, opt, det_min, noslip, rho_out, vel_out):
    """For boundary rows `rows` with ghost nodes `ghost`: rho_out[i], vel_out[i] (mDBC; the
    per-row maths of sphgraph.physics.mdbc, ghost_add / ghost_value)."""
    dim = opt[O_DIM]
    kernel = opt[O_KERNEL]
    support2 = prm[P_SUPPORT2]
    m = prm[P_MASS_F]
    nf = dims[0]
    nm = dims[1]
    for t in prange(rows.shape[0]):
        i = rows[t]
        A = np.zeros((4, 4))
        b = np.zeros(4)
        A2 = np.zeros((4, 4))
        b2 = np.zeros(4)
        vs = np.zeros(3)
        sw = 0.0
        gz = ghost[t, 2] if dim == 3 else 0.0
        lo0, hi0, lo1, hi1, lo2, hi2, empty = cell_window(ghost[t, 0], ghost[t, 1], gz, origin[0], origin[1],
                                                          origin[2], inv_size, dims[0], dims[1], dims[2],
                                                          axes[0], axes[1], axes[2], reach)
        if not empty:
            for c2 in range(lo2, hi2 + 1):
                for c1 in range(lo1, hi1 + 1):
                    row = (c2 * nm + c1) * nf
                    for j in range(start[row + lo0], start[row + hi0 + 1]):
                        if kind[j] != 0:
                            continue
                        dx0 = pos[j, 0] - ghost[t, 0]       # x_j - x_g
                        dx1 = pos[j, 1] - ghost[t, 1]
                        dx2 = (pos[j, 2] - gz) if dim == 3 else 0.0
                        r2 = dx0 * dx0 + dx1 * dx1 + dx2 * dx2
                        if r2 >= support2:
                            continue
                        sw += ghost_add(A, b, vs, dx0, dx1, dx2, r2, rho[j], vel[j, 0], vel[j, 1],
                                        vel[j, 2] if dim == 3 else 0.0, m, dim, prm, kernel)
        r, u0, u1, u2 = ghost_value(A, b, A2, b2, vs, sw, pos[i, 0] - ghost[t, 0], pos[i, 1] - ghost[t, 1],
                                    (pos[i, 2] - gz) if dim == 3 else 0.0, dim, prm, det_min, noslip)
        rho_out[t] = r
        vel_out[t, 0] = u0
        vel_out[t, 1] = u1
        if dim == 3:
            vel_out[t, 2] = u2


def mdbc_tasks(scene, noslip: bool = False, det_min: float = 1e-3):
    """[UserTask] that applies mDBC before each force stage (numba-cpu, one rank), and the
    schedule order that places it (`mdbc_schedule(base_order)`)."""
    from sphgraph.graph.task import UserTask
    from sphgraph.physics.mdbc import ghost_positions, interface_boxes

    from . import cpu_kernels as K
    boxes = interface_boxes(scene)

    def body(ctx, task):
        st = ctx.state
        p = st.particles
        rows = np.nonzero(p.kind != 0)[0]
        if len(rows) == 0:
            return
        ghost = ghost_positions(np.asarray(p.pos[rows], np.float64), boxes)
        rho_out = np.empty(len(rows))
        vel_out = np.zeros((len(rows), p.dim))
        mdbc_boundary(rows, ghost, p.pos, p.vel, p.rho, p.kind, *st.cells.kernel_args(), st.prm, st.opt,
                      det_min, noslip, rho_out, vel_out)
        p.rho[rows] = rho_out
        p.vel[rows] = vel_out
        K.pressure_into(p.rho, st.prm, st.press)

    return [UserTask("mdbc", body, reads=("particles", "cells"), writes=("particles",), per_stage=True)]


SUPPORTED = "--backend numba-cpu or numba-cuda, one rank, no [[motion]] bodies"


def attach(scene, compute_name: str, nranks: int, schedule, user_tasks=()):
    """The schedule and user tasks of a run whose scene asks for `[physics] boundary =
    "mdbc" | "mdbc-noslip"` (`Simulation` calls this before validating the schedule).

    Parameters
    ----------
    scene : Scene
    compute_name : str
        The compute backend's registered name.
    nranks : int
    schedule : Schedule
        The run's schedule; ``mdbc`` is inserted before the first force stage task
        (``send_edges`` or ``forces_interior``) unless its order names it already.
    user_tasks : sequence of UserTask
        Kept; the ``mdbc`` task is appended unless one of that name is given.

    Returns
    -------
    (Schedule, tuple of UserTask)

    Raises
    ------
    InputError
        Where the task cannot run (one line naming the key and what is supported):
        another backend, several ranks (the task reads one rank's rows, so
        ghosts near a slab edge would miss the halo's fluid), moving bodies (ghosts
        mirror across the scene's fixed geometry).
    """
    import dataclasses

    from sphgraph.errors import InputError
    mode = scene.physics.boundary
    why = None
    if compute_name not in ("numba-cpu", "numba-cuda"):
        why = f"--backend {compute_name}"
    elif nranks != 1:
        why = f"{nranks} ranks"
    elif scene.extra.get("motion"):
        why = "[[motion]] bodies"
    if why is not None:
        raise InputError(f"{scene.source}: physics.boundary: \"{mode}\" runs with {SUPPORTED} "
                         f"(or use boundary = \"dbc\"), got {why}")
    tasks = tuple(user_tasks)
    if not any(u.name == "mdbc" for u in tasks):
        if compute_name == "numba-cuda":
            from .cuda_mdbc import mdbc_tasks as device_tasks
            tasks += tuple(device_tasks(scene, noslip=mode == "mdbc-noslip"))
        else:
            tasks += tuple(mdbc_tasks(scene, noslip=mode == "mdbc-noslip"))
    if "mdbc" not in schedule.order:
        order = mdbc_schedule(schedule.order)["order"]
        schedule = dataclasses.replace(schedule, order=order,
                                       description=f"{schedule.description}; mDBC before each force stage")
    return schedule, tasks


def mdbc_schedule(order=None):
    order = list(order or ["build_cells", "forces_interior", "dt_local", "dt_allreduce", "integrate"])
    i = order.index("forces_interior")
    if "send_edges" in order:
        i = min(i, order.index("send_edges"))
    order.insert(i, "mdbc")
    return {"format": 1, "description": "one rank, mDBC before each force stage", "order": order}
