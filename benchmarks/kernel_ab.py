"""A/B of two versions of the CPU force kernel in one process (interleaved, same state).

    mkdir -p /tmp/ab && git show REV:backends/compute/cpu_kernels.py | sed 's/drop_stale_cache(__file__)/pass/' > /tmp/ab/kern_old.py
    sed 's/drop_stale_cache(__file__)/pass/' backends/compute/cpu_kernels.py > /tmp/ab/kern_new.py
    python benchmarks/kernel_ab.py examples/dambreak2d.toml 0.01 600

Runs the scene NSTEPS steps, then calls both `forces` on the same arrays 15 x 5 times,
alternating, and prints the median time of each and whether their outputs are identical
(the largest difference of each output otherwise; exit status 1 then).
"""
import sys, time, numpy as np
sys.path.insert(0, "/tmp/ab")
import kern_old, kern_new
from sphgraph.solver import Simulation
from sphgraph.scene import Scene
scene_file, dp, nsteps = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
sim = Simulation(Scene.from_toml(scene_file).with_overrides(dp=dp))
for _ in range(nsteps):
    sim.step()
st = sim.contexts[0].state; p = st.particles; buf = st.parts["interior"]
args = (p.pos, p.vel, p.rho, st.press, p.kind, p.pos, p.vel, p.rho, st.press, p.kind, *st.cells.kernel_args(),
        st.prm, st.opt, buf.ace, buf.ar, buf.ddt, buf.cancel, buf.visc)
outs = {}
for K in (kern_old, kern_new):
    K.forces(*args); outs[K.__name__] = [a.copy() for a in (buf.ace, buf.ar, buf.ddt, buf.visc)]
diffs = {}
for name, a, b in zip(("ace", "ar", "ddt", "visc"), *outs.values()):
    if not np.array_equal(a, b):
        diffs[name] = float(np.abs(a.astype(float) - b.astype(float)).max())
        print(f"{name}: largest difference {diffs[name]:.3e} (largest value {np.abs(a).max():.3e})")
t = {"kern_old": [], "kern_new": []}
for rep in range(15):
    for K in (kern_old, kern_new):
        t0 = time.perf_counter()
        for _ in range(5):
            K.forces(*args)
        t[K.__name__].append((time.perf_counter() - t0) / 5)
o, n = np.median(t["kern_old"]), np.median(t["kern_new"])
same = "identical outputs" if not diffs else "outputs differ: " + ", ".join(diffs)
print(f"{scene_file.split('/')[-1]} dp {dp} N {p.n}: old {o*1e3:.3f} ms new {n*1e3:.3f} ms new/old {n/o:.3f} ({same})")
sys.exit(1 if diffs else 0)
