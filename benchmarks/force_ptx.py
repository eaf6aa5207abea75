"""Registers, spills and the load instructions of the float32 force kernels, without a GPU.

Compiles the force kernels (k_forces_fv / k_forces_bv, as k_forces_f / k_forces_b) for SPHERIC 2 to PTX with numba-cuda (NVVM only, no
device), assembles it for sm_90 with ptxas at the register cap the backend uses, and
prints ptxas' resource report and the global-load widths of the PTX; with `cuobjdump` on
the PATH also the SASS (`--dump DIR`: NAME.sass) and its instruction count. Needs
numba-cuda, NVRTC and a CUDA toolkit's ptxas on the PATH (not part of the default
install). On the development VM: a separate virtual environment with
`numba==0.68.1 "numpy<2.5" numba-cuda==0.30.4 nvidia-cuda-nvrtc==13.0.*`, this project
installed into it, `CUDA_HOME=/usr/local/cuda-13.0` with its `bin` (ptxas) on the PATH, and
the `bin` folders of the wheels `nvidia-cuda-cuobjdump` and `nvidia-cuda-nvdisasm`
(unpacked) on the PATH for the SASS:

    python benchmarks/force_ptx.py [--maxreg 64] [--dump DIR]

Comparing the SASS of two trees this way checked that refactorings kept the kernels'
instructions (sm_90), and counted the instructions of the candidate loop and pair body.
"""
import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--maxreg", type=int, default=None, help="register cap (default: the backend's)")
    ap.add_argument("--dp", type=float, default=0.03)
    ap.add_argument("--dump", default=None, help="write the PTX and SASS here")
    ap.add_argument("--forces", default="fv", choices=("f", "fv"),
                    help="fv: the backend's; f: benchmarks/cuda_force_variants.py's whole-cell kernels")
    a = ap.parse_args(argv)
    from numba import cuda, types as T
    from sphgraph.backends.compute import cuda_kernels as CK
    from sphgraph.config import O_DDT, O_KERNEL, O_LAMINAR
    from sphgraph.solver import Simulation
    from benchmarks.gpu_bench import spheric2
    sim = Simulation(spheric2(a.dp))
    st = sim.contexts[0].state
    opt = st.opt
    f32, f64, i64 = T.float32, T.float64, T.int64
    a32, a64, ai32, ai8 = T.float32[::1], T.float64[::1], T.int32[::1], T.int8[::1]
    geo = (ai32, i64, f64, f64, f64, f64, i64, i64, i64, i64, i64, i64, i64, a32, i64, i64)
    sig_f = (a64, a64, a64, a32, a32, i64, i64) + geo + (i64, i64, i64, f32, f32, f32,
                                                          a32, a32, a32, a32, a32, ai8, a32)
    sig_b = (a64, a64, a64, a32, a32, i64, i64) + geo + (i64, a32, a32, a32, a32, a32, ai8, a32)
    if a.forces == "f":    # benchmarks/cuda_force_variants.py: whole cells, scalar loads
        from benchmarks import cuda_force_variants as V
        V.select(forces="f")
    else:                  # production: k_forces_fv / k_forces_bv
        sig_f = (a32, a32, i64, i64, ai32, i64) + (f32,) * 6 + (i64,) * 7 + (f32,) * 3 + (a32,) * 5 + (ai8, a32)
        sig_b = sig_f                       # k_forces_bv: the same arguments
    mr = CK.MAXREG if a.maxreg is None else a.maxreg
    import numba.cuda.dispatcher as D   # device functions ask the (absent) device for its cc
    D.get_current_device = lambda: type("Dev", (), {"compute_capability": (9, 0)})()
    kf = CK.force_kernels(np.float32, st.prm, int(opt[O_KERNEL]), int(opt[O_DDT]), int(opt[O_LAMINAR]))
    out = Path(a.dump) if a.dump else Path(tempfile.mkdtemp())
    out.mkdir(parents=True, exist_ok=True)
    for name, sig in (("k_forces_f", sig_f), ("k_forces_b", sig_b)):
        fn = getattr(kf, name).py_func
        ptx, _ = cuda.compile_ptx(fn, sig, cc=(9, 0), fastmath=True)
        p = out / f"{name}.ptx"
        p.write_text(ptx)
        cmd = ["ptxas", "-arch=sm_90", "-v", "-o", str(out / f"{name}.cubin"), str(p)]
        if mr:
            cmd.insert(1, f"--maxrregcount={mr}")
        r = subprocess.run(cmd, capture_output=True, text=True)
        rep = " ".join(l.strip() for l in r.stderr.splitlines() if "Used" in l or "spill" in l)
        loads = {}
        for m in re.finditer(r"ld\.global(?:\.nc)?(\.v[24])?\.(\w+)", ptx):
            k = (m.group(1) or ".v1") + "." + m.group(2)
            loads[k] = loads.get(k, 0) + 1
        print(f"{name}: maxreg {mr}: {rep or r.stderr.strip()[:300]}")
        print(f"  global loads in the PTX: {loads}")
        if shutil.which("cuobjdump") and r.returncode == 0:
            sass = subprocess.run(["cuobjdump", "-sass", str(out / f"{name}.cubin")], capture_output=True,
                                  text=True).stdout
            ins = [ln.strip() for ln in sass.splitlines() if re.match(r"\s+/\*[0-9a-f]{4}\*/", ln)]
            (out / f"{name}.sass").write_text("\n".join(ins) + "\n")
            print(f"  SASS: {len(ins)} instructions ({name}.sass)")
    print(f"PTX and cubin in {out}")


if __name__ == "__main__":
    main()
