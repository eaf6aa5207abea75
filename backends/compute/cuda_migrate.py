"""numba.cuda kernels of the rows that move between ranks.

Rows leaving a slab are found and removed on the device (only they cross the bus):
k_mig_keep flags the rows that stay and counts the leaving ones; an exclusive scan of
the flags gives each kept row its new place (k_compact_perm, then the usual gather)
and each leaving row its place in the message (k_pack_leaving: increasing row order;
the host tells the sides apart by position).

Packed transfers: every field a message needs is gathered into (or scattered from) one
device buffer by one launch and crosses the bus in one copy. Row records of the run's
type, `w = dim + 5` values per row: (vm_x, vm_y[, vm_z], vx, vy, vz, rho, rho_m1),
i.e. the history, the vel4 record, the density history; positions are float64 records
of `dim` values.
"""
from numba import cuda

KERNELS = ("k_mig_keep", "k_near_faces", "k_compact_perm", "k_pack_leaving", "k_unpack_rows")


def k_mig_keep(pa, n, lo, hi, keep, count):
    """keep[i] = 1 for rows in [lo, hi) along the split axis, else 0 (counted)."""
    i = cuda.grid(1)
    if i >= n:
        return
    x = pa[i]
    if x < lo or x >= hi:
        keep[i] = 0
        cuda.atomic.add(count, 0, 1)
    else:
        keep[i] = 1


def k_near_faces(px, py, pz, n, t0, t1, t2, u0, u1, u2, w0, w1, w2, keep, count):
    """keep[i] = 0 (counted) for rows within reach of a face along a flagged axis (w0..w2):
    x < t or x >= u (t = lo + reach, u = hi - reach, as sphgraph.periodic), else 1."""
    i = cuda.grid(1)
    if i >= n:
        return
    near = False
    if w0 and (px[i] < t0 or px[i] >= u0):
        near = True
    if w1 and (py[i] < t1 or py[i] >= u1):
        near = True
    if w2 and (pz[i] < t2 or pz[i] >= u2):
        near = True
    if near:
        keep[i] = 0
        cuda.atomic.add(count, 0, 1)
    else:
        keep[i] = 1


def k_compact_perm(keep, pos, n, perm):
    i = cuda.grid(1)
    if i < n and keep[i] != 0:
        perm[pos[i]] = i


def k_pack_leaving(keep, pos, n, dim, px, py, pz, vmx, vmy, vmz, vel4, rhom, kind, ids,
                   o64, of, okind, oid):
    """Rows with keep == 0 into slot i - pos[i] (pos: exclusive scan of keep), so the
    leaving rows come out in increasing row order."""
    i = cuda.grid(1)
    if i >= n or keep[i] != 0:
        return
    j = i - pos[i]
    b = j * dim
    o64[b] = px[i]
    o64[b + 1] = py[i]
    w = dim + 5
    f = j * w
    of[f] = vmx[i]
    of[f + 1] = vmy[i]
    if dim == 3:
        o64[b + 2] = pz[i]
        of[f + 2] = vmz[i]
    s = 4 * i
    of[f + dim] = vel4[s]
    of[f + dim + 1] = vel4[s + 1]
    of[f + dim + 2] = vel4[s + 2]
    of[f + dim + 3] = vel4[s + 3]
    of[f + dim + 4] = rhom[i]
    okind[j] = kind[i]
    oid[j] = ids[i]


def k_unpack_rows(n0, m, dim, i64, if_, ikind, iid, px, py, pz, vmx, vmy, vmz, vel4, rhom, kind, ids):
    """Records packed as k_pack_leaving packs them, written to rows n0 .. n0+m-1."""
    j = cuda.grid(1)
    if j >= m:
        return
    i = n0 + j
    b = j * dim
    px[i] = i64[b]
    py[i] = i64[b + 1]
    w = dim + 5
    f = j * w
    vmx[i] = if_[f]
    vmy[i] = if_[f + 1]
    if dim == 3:
        pz[i] = i64[b + 2]
        vmz[i] = if_[f + 2]
    s = 4 * i
    vel4[s] = if_[f + dim]
    vel4[s + 1] = if_[f + dim + 1]
    vel4[s + 2] = if_[f + dim + 2]
    vel4[s + 3] = if_[f + dim + 3]
    rhom[i] = if_[f + dim + 4]
    kind[i] = ikind[j]
    ids[i] = iid[j]
