"""Halo transport bandwidth between two ranks (issue 6 §7): CUDA IPC against host staging.

Run under `mpiexec -n 2` on the GPU machine (one rank per GPU when there are two, both on
GPU 0 otherwise). Rank 0 fills a device buffer and sends its IPC handle once (numba
`get_ipc_handle`, pickled over MPI); rank 1 opens it and copies it device to device into
its own buffer, timed over `--reps` copies after one untimed. The staged path is what
`--halo-transport staged` does with the same bytes: device -> pinned host on rank 0, MPI
Send/Recv of the host bytes, pinned host -> device on rank 1. One JSON line from rank 1,
with the bytes checked after each path.

    mpiexec -n 2 python3 benchmarks/gpu_ipc_bw.py --mib 16 64 256 --json out.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mib", type=float, nargs="+", default=[16, 64, 256])
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--json", default=None)
    a = ap.parse_args(argv)
    from mpi4py import MPI
    from numba import cuda
    comm = MPI.COMM_WORLD
    r = comm.rank
    ngpu = len(cuda.gpus)
    cuda.select_device(r % ngpu)
    rows = []
    for mib in a.mib:
        nb = int(mib * 2 ** 20)
        pattern = (np.arange(nb, dtype=np.uint64) * 2654435761 % 251).astype(np.uint8)
        if r == 0:
            src = cuda.to_device(pattern)
            comm.send(src.get_ipc_handle(), dest=1, tag=1)
            comm.Barrier()                       # rank 1 copies through the mapping
            comm.Barrier()
            pin = cuda.pinned_array(nb, np.uint8)
            comm.Barrier()
            for i in range(a.reps + 1):          # staged: device -> host, MPI
                comm.Barrier()
                src.copy_to_host(pin)
                comm.Send([pin, MPI.BYTE], dest=1, tag=2)
            comm.Barrier()
        else:
            h = comm.recv(source=0, tag=1)
            peer = h.open()
            dst = cuda.device_array(nb, np.uint8)
            comm.Barrier()
            dst.copy_to_device(peer)
            cuda.synchronize()
            t0 = time.perf_counter()
            for _ in range(a.reps):
                dst.copy_to_device(peer)
            cuda.synchronize()
            t_ipc = (time.perf_counter() - t0) / a.reps
            ok_ipc = bool(np.array_equal(dst.copy_to_host(), pattern))
            h.close()
            comm.Barrier()
            pin = cuda.pinned_array(nb, np.uint8)
            dst2 = cuda.device_array(nb, np.uint8)
            comm.Barrier()
            ts = []
            for i in range(a.reps + 1):
                comm.Barrier()
                t0 = time.perf_counter()
                comm.Recv([pin, MPI.BYTE], source=0, tag=2)
                dst2.copy_to_device(pin)
                cuda.synchronize()
                ts.append(time.perf_counter() - t0)
            comm.Barrier()
            t_staged = float(np.mean(ts[1:]))      # includes rank 0's device -> host copy (it sends after it)
            ok_staged = bool(np.array_equal(dst2.copy_to_host(), pattern))
            same_gpu = ngpu == 1
            rows.append({"mib": mib, "ipc_GBps": nb / t_ipc / 1e9, "staged_GBps": nb / t_staged / 1e9,
                         "ipc_ok": ok_ipc, "staged_ok": ok_staged, "gpus": ngpu,
                         "note": "both ranks on one GPU" if same_gpu else "one GPU per rank"})
            print(json.dumps(rows[-1]), flush=True)
    if r == 1:
        out = {"date": time.strftime("%Y-%m-%d %H:%M:%S %Z"), "command": " ".join(sys.argv),
               "device": cuda.get_current_device().name.decode() if isinstance(cuda.get_current_device().name, bytes)
               else cuda.get_current_device().name, "rows": rows}
        if a.json:
            Path(a.json).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
