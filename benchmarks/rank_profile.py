"""Profile every rank of a `sphgraph` command (cProfile), one report per rank.

    mpiexec -n 2 python3 benchmarks/rank_profile.py --out DIR -- bench SCENE --comm mpi ...

Each rank writes DIR/profile.RANK.txt (top functions by own time and by cumulative
time) and DIR/profile.RANK.prof (pstats). Used to find where a rank's step time goes
when one rank waits on another (the waiting rank's time shows up in recv/Probe; the
slow rank's in the work it does first).
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import sys


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", required=True)
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("args", nargs=argparse.REMAINDER)
    a = ap.parse_args()
    args = a.args[1:] if a.args and a.args[0] == "--" else a.args
    rank = next((os.environ[v] for v in ("PMI_RANK", "OMPI_COMM_WORLD_RANK") if v in os.environ), "0")
    os.makedirs(a.out, exist_ok=True)
    sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    from sphgraph.cli import main as cli_main
    prof = cProfile.Profile()
    try:
        code = prof.runcall(cli_main, args) or 0
    except SystemExit as e:
        code = e.code or 0
    prof.dump_stats(os.path.join(a.out, f"profile.{rank}.prof"))
    s = io.StringIO()
    st = pstats.Stats(prof, stream=s)
    st.sort_stats("tottime").print_stats(a.top)
    st.sort_stats("cumulative").print_stats(a.top)
    with open(os.path.join(a.out, f"profile.{rank}.txt"), "w") as f:
        f.write(s.getvalue())
    sys.exit(code)


if __name__ == "__main__":
    main()
