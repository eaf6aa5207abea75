#!/usr/bin/env bash
# One batched device call (issue 6): GPU tests, SPHERIC 2 and Yeh & Petroff benchmarks,
# float32 GPU toe against float64 CPU, and a 2-rank mpiexec run on this one GPU.
# Every stage has its own time limit and writes under $OUT, so a stage that runs long
# costs only itself. Run from the repository root on the GPU machine, after the
# install line of shared/device/README.md:
#     bash benchmarks/gpu_session.sh STAGE [STAGE ...]
# Stages: tests spheric2 toe yeh large multi lanes multi-nolanes forceab ncu spheric2-4m
#         forceab-trim forceab-cap hostprof slow-launch tests-quick final check-4m ipc ipc-tests ipc-overlap mem forceab-rt largest
set -u
OUT=${OUT:-/tmp/gpu_out}
mkdir -p "$OUT"
export NUMBA_CACHE_DIR=/tmp/numba_cache
nvidia-smi --query-gpu=name,memory.total,clocks.sm,clocks.max.sm,power.limit --format=csv >"$OUT/gpu.txt" 2>&1
cat "$OUT/gpu.txt"
stage() {  # name, limit seconds, command...
  local name=$1 limit=$2; shift 2
  local t0=$(date +%s)
  timeout "$limit" "$@" >"$OUT/$name.log" 2>&1
  local rc=$?
  echo "== $name rc=$rc $(( $(date +%s) - t0 )) s"
  tail -n 4 "$OUT/$name.log"
}
mps_on() {   # the CUDA MPS daemon: several processes share the GPU without time-slicing
  export CUDA_MPS_PIPE_DIRECTORY=/tmp/mps_pipe CUDA_MPS_LOG_DIRECTORY=/tmp/mps_log
  mkdir -p "$CUDA_MPS_PIPE_DIRECTORY" "$CUDA_MPS_LOG_DIRECTORY"
  nvidia-cuda-mps-control -d; echo "== mps daemon rc=$?"
}
mps_off() {
  echo quit | nvidia-cuda-mps-control; echo "== mps quit rc=$?"
}
for s in "$@"; do
  case $s in
    tests)    stage tests 500 python3 -m pytest -q -m gpu -p no:cacheprovider tests/test_cuda_backend.py \
                tests/test_shifting_cuda.py tests/test_compute_conformance.py ;;
    spheric2) stage spheric2 330 python3 benchmarks/gpu_bench.py --dp 0.01 0.006 0.004 --steps 20 --warmup 3 \
                --profile-steps 3 --bare --json "$OUT/spheric2.json" ;;
    toe)      stage toe 200 python3 benchmarks/gpu_toe.py --dp 0.02 --json "$OUT/toe.json" ;;
    yeh)      stage yeh 300 bash -c "for dp in 0.0045 0.0028 0.0017; do python3 -m sphgraph bench \
                examples/yeh_petroff.toml --dp \$dp --steps 20 --warmup 3 --backend numba-cuda --json; done | tee $OUT/yeh.jsonl" ;;
    large)    stage large 400 python3 benchmarks/gpu_bench.py --dp 0.002 --steps 10 --warmup 2 \
                --profile-steps 1 --json "$OUT/large.json" ;;
    multi)    stage multi 300 python3 benchmarks/gpu_multi.py --dp 0.01 --ranks 2 --steps 20 --warmup 3 \
                --json "$OUT/multi.json" ;;
    # lanes as CUDA streams (issue 6 §3): production against bulk-synchronous on 2 mock ranks
    # sharing the GPU, a stream per lane (1) and the default stream only (0), device trace
    lanes)    stage lanes 500 python3 benchmarks/gpu_lanes.py --dp 0.01 0.006 --ranks 2 --steps 10 --warmup 3 \
                --trace-steps 2 --streams 1 0 --json "$OUT/lanes.json" ;;
    # the multi stage again with every rank on its default stream (before lanes), to compare
    multi-nolanes) stage multi_nolanes 300 env SPHGRAPH_CUDA_STREAMS=0 python3 benchmarks/gpu_multi.py --dp 0.01 \
                --ranks 2 --steps 20 --warmup 3 --json "$OUT/multi_nolanes.json" ;;
    # fluid force kernel variants KERNEL:MAXREG:BLOCK timed on one 4.4 M state (issue 6 §6)
    forceab)  stage forceab 240 python3 benchmarks/force_ab.py --dp 0.006 --warmup 4 --reps 10 --rounds 3 \
                --variants f:64:128 fv:64:128 fv:56:128 --json "$OUT/force_ab.json" ;;
    # trimmed rows (cells sorted along the rows) against whole cells, and register caps
    forceab-trim) stage forceab_trim 300 python3 benchmarks/force_ab.py --dp 0.006 --warmup 4 --reps 10 --rounds 3 \
                --variants f:64:128 fv:64:128:notrim fv:64:128 fv:80:128 fv:0:128 fv:48:128 \
                --json "$OUT/force_ab_trim.json" ;;
    # the final tree: the three force variants and SPHERIC 2 at 4.4 M
    final)    stage final_ab 200 python3 benchmarks/force_ab.py --dp 0.006 --warmup 4 --reps 10 --rounds 3 \
                --variants f:64:128 fv:64:128:notrim fv:64:128 --json "$OUT/force_ab_final.json"
              stage final_4m 200 python3 benchmarks/gpu_bench.py --dp 0.006 --steps 50 --warmup 3 --profile-steps 3 \
                --json "$OUT/spheric2_final.json" ;;
    # SPHERIC 2 at 4.4 and 13 M, 30 timed steps (a short check of a tree)
    check-4m) stage check_4m 120 python3 benchmarks/gpu_bench.py --dp 0.006 0.004 --steps 30 --warmup 3 \
                --profile-steps 2 --json "$OUT/spheric2_check.json" ;;
    # register caps and block sizes of the trimmed kernels
    forceab-cap) stage forceab_cap 300 python3 benchmarks/force_ab.py --dp 0.006 --warmup 4 --reps 10 --rounds 3 \
                --variants fv:64:128 fv:56:128 fv:48:128 fv:40:128 fv:64:64 fv:64:256 fv:48:256 \
                --json "$OUT/force_ab_cap.json" ;;
    # where the host's time goes at 1.1 M (cProfile over 20 timed steps)
    hostprof) stage hostprof 200 python3 benchmarks/gpu_bench.py --dp 0.01 --steps 20 --warmup 3 --profile-steps 3 \
                --host-profile --json "$OUT/hostprof.json" ;;
    # numba-cuda's own launch path (SPHGRAPH_CUDA_FAST_LAUNCH=0), to compare with spheric2
    slow-launch) stage slow_launch 300 env SPHGRAPH_CUDA_FAST_LAUNCH=0 python3 benchmarks/gpu_bench.py \
                --dp 0.01 0.006 --steps 20 --warmup 3 --profile-steps 3 --json "$OUT/slow_launch.json" ;;
    # the GPU tests of this change only
    tests-quick) stage tests_quick 300 python3 -m pytest -q -m gpu -p no:cacheprovider tests/test_cuda_backend.py \
                -k "fast_launch or float64_matches or float32_close" ;;
    # Nsight Compute on one launch of each fluid kernel (k_forces_f, k_forces_fv) at 1.1 M
    ncu)      NCU=$(command -v ncu || ls /opt/nvidia/nsight-compute/*/ncu 2>/dev/null | head -1)
              stage ncu 240 "$NCU" --clock-control none --target-processes all -k regex:k_forces_f \
                --launch-skip 2 --launch-count 2 --section SpeedOfLight --section Occupancy \
                --section WarpStateStats --section SchedulerStats --section LaunchStats \
                --metrics smsp__thread_inst_executed_per_inst_executed.ratio,smsp__inst_executed.sum \
                python3 benchmarks/force_ab.py --dp 0.01 --warmup 1 --reps 1 --rounds 1 \
                --variants f:64:128 fv:64:128 ;;
    # SPHERIC 2 at 1.1, 4.4 and 13 M with the default kernels, 50 timed steps
    spheric2-4m) stage spheric2_4m 300 python3 benchmarks/gpu_bench.py --dp 0.01 0.006 0.004 --steps 50 --warmup 3 \
                --profile-steps 3 --bare --json "$OUT/spheric2_4m.json" ;;
    # --halo-transport ipc (issue 6 §7): the GPU tests (mpiexec -n 2, CUDA IPC handles), the copy
    # bandwidth of both transports, and SPHERIC 2 at 1.1 M on 2 ranks with each transport
    ipc)      stage ipc_tests 400 python3 -m pytest -q -s -m gpu -p no:cacheprovider tests/test_cuda_halo.py
              stage ipc_bw 120 mpiexec -n 2 python3 benchmarks/gpu_ipc_bw.py --mib 4 16 64 256 --json "$OUT/ipc_bw.json"
              stage ipc_bench 400 python3 benchmarks/gpu_multi.py --dp 0.01 --ranks 2 --steps 20 --warmup 3 \
                --schedules production --transports staged ipc --json "$OUT/multi_ipc.json" ;;
    # what overlap buys with each transport: production against bulk-synchronous, 2 ranks on the GPU
    ipc-overlap) stage ipc_overlap 400 python3 benchmarks/gpu_multi.py --dp 0.01 --ranks 2 --steps 20 --warmup 3 \
                --schedules production bulk-synchronous --transports staged ipc --json "$OUT/multi_ipc_overlap.json" ;;
    # the row set-up in the run's type (float32 slab gaps): caps and whole cells against k_forces_f
    forceab-rt) stage forceab_rt 200 python3 benchmarks/force_ab.py --dp 0.006 --warmup 4 --reps 10 --rounds 3 \
                --variants f:64:128 fv:64:128:notrim fv:64:128 fv:56:128 fv:48:128 --json "$OUT/force_ab_rt.json" ;;
    ipc-tests) stage ipc_tests 400 python3 -m pytest -q -s -m gpu -p no:cacheprovider tests/test_cuda_halo.py ;;
    # device memory beyond the arrays (modules, work buffers) at 4.4 M
    mem)      stage mem 150 python3 benchmarks/gpu_memory.py --dp 0.006 --json "$OUT/memory.json" ;;
    # the 32-bit loop indices, unwrapped loads and the folded gravity terms: fv against f, caps
    # (a run of 2026-12-02 07:01 also had fv with each record loaded one ahead: 0.95x, dropped)
    forceab-i32) stage forceab_i32 200 python3 benchmarks/force_ab.py --dp 0.006 --warmup 4 --reps 10 --rounds 3 \
                --variants f:64:128 fv:64:128 fv:56:128 \
                --json "$OUT/force_ab_i32.json" ;;
    # SPHERIC 2 at 4.4 and 13 M with the force kernels capped at 56 registers, 30 timed steps
    check-cap56) stage check_cap56 120 env SPHGRAPH_CUDA_MAXREG=56 python3 benchmarks/gpu_bench.py --dp 0.006 0.004 \
                --steps 30 --warmup 3 --profile-steps 2 --json "$OUT/spheric2_cap56.json" ;;
    # Nsight Compute source counters (warp instructions executed per SASS line) of the interior
    # force kernels at 4.4 M: where the instructions go (row set-up, candidate tests, pair bodies)
    ncu-src)  NCU=$(command -v ncu || ls /opt/nvidia/nsight-compute/*/ncu 2>/dev/null | head -1)
              stage ncu_src 240 "$NCU" --clock-control none -o "$OUT/src" --section SourceCounters \
                --metrics smsp__inst_executed.sum,smsp__thread_inst_executed_per_inst_executed.ratio,gpu__time_duration.sum \
                -k regex:k_forces_ --launch-skip 2 --launch-count 2 python3 benchmarks/force_ab.py --dp 0.006 \
                --warmup 1 --reps 1 --rounds 1 --variants fv:64:128
              "$NCU" -i "$OUT/src.ncu-rep" --page source --csv --print-source sass >"$OUT/ncu_src.csv" 2>&1
              "$NCU" -i "$OUT/src.ncu-rep" --page details --csv >"$OUT/ncu_details.csv" 2>&1
              rm -f "$OUT/src.ncu-rep" ;;
    # the final tree: two candidates a turn (u2) against one (u1), caps 56 / 64; then the
    # faster of the cap-56 pair is exported (SPHGRAPH_CUDA_UNROLL) for the stages after it
    forceab-u2) stage forceab_u2 200 python3 benchmarks/force_ab.py --dp 0.006 --warmup 4 --reps 10 --rounds 3 \
                --variants f:64:128 fv:56:128:u1 fv:56:128:u2 fv:64:128:u2 --json "$OUT/force_ab_u2.json"
              export SPHGRAPH_CUDA_UNROLL=$(python3 -c "import json; v = json.load(open('$OUT/force_ab_u2.json'))['variants']; \
print(1 if v['fv:56:128:u1']['median_ms'] < v['fv:56:128:u2']['median_ms'] else 2)" 2>/dev/null || echo 2)
              echo "SPHGRAPH_CUDA_UNROLL=$SPHGRAPH_CUDA_UNROLL" | tee "$OUT/unroll.txt" ;;
    # the largest SPHERIC 2 that fits an H100 80 GB (issue 6 §6): dp 0.00095, 835,827,729 particles
    # (785,608,352 fluid), planned by `gpu_bench.py --plan` at 97.1 B per particle, 96 % of the
    # H100's 81,559 MiB with 1 GiB for the context; 2 warm-up and 10 timed steps, set-up phases and
    # host / device peaks in the JSON (--lean: no pair count, profile pass or bare loop)
    largest)  stage largest 540 python3 benchmarks/gpu_bench.py --dp 0.00095 --steps 10 --warmup 2 --lean \
                --json "$OUT/largest.json" ;;
    # every GPU test but the fine runs (the multi-rank path, ipc under mpiexec -n 2 and -n 4,
    # shifting, DuFort-Frankel, Riemann, mDBC and the backend against numba-cpu)
    tests-all) stage tests_all 420 python3 -m pytest -q -m gpu -p no:cacheprovider -rs tests/test_cuda_backend.py \
                tests/test_cuda_multirank.py tests/test_cuda_halo.py tests/test_shifting_cuda.py \
                tests/test_cuda_dufort.py tests/test_cuda_riemann.py tests/test_cuda_mdbc.py ;;
    # cProfile of 1, 2 and 4 mock ranks at 4.4 M (where the host time of a rank-step goes)
    hostprof-ranks) stage hostprof_ranks 200 python3 benchmarks/gpu_host_profile.py --dp 0.006 --ranks 1 2 4 \
                --steps 20 --top 45 ;;
    # mock ranks against single at 4.4 M, ROUNDS rounds (default 1), 52 timed steps
    mock-4m)  stage mock_4m 240 python3 benchmarks/gpu_mock_ranks.py --dp 0.006 --ranks 2 4 --steps 52 --warmup 2 \
                --rounds "${ROUNDS:-1}" --transport "${TRANSPORT:-auto}" --json "$OUT/mock_4m.json" ;;
    # the mock's virtual clock from the device's task times (predicted) against the wall clock,
    # 1, 2 and 4 mock ranks at 4.4 M, and --comm single
    predict)  stage predict 200 bash -c "for r in 1 2 4; do python3 -m sphgraph bench examples/spheric2.toml \
                --dp 0.006 --steps 30 --warmup 3 --backend numba-cuda --comm mock --ranks \$r; done; \
                python3 -m sphgraph bench examples/spheric2.toml --dp 0.006 --steps 30 --warmup 3 \
                --backend numba-cuda" ;;
    # the GPU tests of this session's kernels: shifting, DuFort-Frankel, Riemann, mDBC, ipc under
    # mpiexec -n 2 and -n 4
    tests-new) stage tests_new 420 python3 -m pytest -q -m gpu -p no:cacheprovider -rs tests/test_shifting_cuda.py \
                tests/test_cuda_dufort.py tests/test_cuda_riemann.py tests/test_cuda_mdbc.py tests/test_cuda_halo.py ;;
    tests-fine) stage tests_fine 420 python3 -m pytest -q -s -m gpu -p no:cacheprovider -rs tests/test_fine_runs_gpu.py ;;
    # two and four processes on the one GPU under CUDA MPS (issue 21 §3), ipc halos
    mps)      mps_on
              stage mps2 300 python3 benchmarks/gpu_multi.py --dp 0.006 --ranks 2 --steps 30 --warmup 3 \
                --schedules production bulk-synchronous --transports ipc --json "$OUT/mps2.json"
              stage mps4 200 python3 benchmarks/gpu_multi.py --dp 0.006 --ranks 4 --steps 30 --warmup 3 \
                --schedules production --transports ipc --json "$OUT/mps4.json"
              mps_off ;;
    # the device timeline of 2 mock ranks at 4.4 M, production and bulk-synchronous (Perfetto JSON)
    lanes-trace) stage lanes_trace 200 python3 benchmarks/gpu_lanes.py --dp 0.006 --ranks 2 --steps 10 --warmup 3 \
                --trace-steps 2 --schedules production bulk-synchronous --chrome "$OUT" --json "$OUT/lanes_trace.json" ;;
    # CPU under real MPI on the 16 cores (issue 21 §6): Yeh & Petroff at dp 0.0045 (1.0 M particles),
    # 1 x 16 threads, mpiexec -n 2 x 8, -n 4 x 4
    cpu-mpi)  stage cpu_mpi 300 bash -c "NUMBA_NUM_THREADS=16 python3 -m sphgraph bench examples/yeh_petroff.toml \
                --dp 0.0045 --steps 8 --warmup 2; for n in 2 4; do mpiexec -n \$n env NUMBA_NUM_THREADS=\$((16 / n)) \
                python3 -m sphgraph bench examples/yeh_petroff.toml --dp 0.0045 --steps 8 --warmup 2 --comm mpi; done" ;;
    # the fine runs of issue 22 §1 on the GPU, float32 (benchmarks/fine_runs.py), one log each
    fine)     stage fine_yeh 400 python3 benchmarks/fine_runs.py yeh_petroff --dp 0.0085 --backend numba-cuda \
                --precision float32
              stage fine_yeh_df 400 python3 benchmarks/fine_runs.py yeh_petroff --dp 0.0085 --backend numba-cuda \
                --precision float32 --diffusion-time dufort-frankel --no-exclude
              stage fine_wall2d 400 python3 benchmarks/fine_runs.py wall2d --diffusion-time leapfrog \
                --backend numba-cuda --precision float32
              stage fine_wall2d_df 400 python3 benchmarks/fine_runs.py wall2d --backend numba-cuda --precision float32 \
                --no-exclude ;;
    # mock ranks against single at 4.4 and 13.3 M, 3 alternated rounds, both engine orders, the
    # float64 match against one rank at 2 and 4 ranks; the GPU path's multi-rank test (1.3 M, 4 and 5 ranks)
    mock-21)  stage mock_21 420 python3 benchmarks/gpu_mock_ranks.py --dp 0.006 0.004 --ranks 2 4 --steps 52 \
                --warmup 3 --rounds 3 --transport auto --orders eager clock --match --json "$OUT/mock_21.json"
              stage multirank_gpu 200 python3 -m pytest -q -s -m gpu -p no:cacheprovider -rs tests/test_cuda_multirank.py ;;
    # two and four processes on the GPU under CUDA MPS at 4.4 and 13.3 M, both schedules; the float64
    # mpiexec -n 2 / -n 4 test under MPS; the paper's timers of 40-step MPS runs (sphgraph plot breakdown)
    mps-21)   mps_on
              stage mps2_21 240 python3 benchmarks/gpu_multi.py --dp 0.006 0.004 --ranks 2 --steps 30 --warmup 3 \
                --schedules production bulk-synchronous --transports ipc --json "$OUT/mps2_21.json"
              stage mps4_21 100 python3 benchmarks/gpu_multi.py --dp 0.006 --ranks 4 --steps 30 --warmup 3 \
                --schedules production --transports ipc --json "$OUT/mps4_21.json"
              stage mps_match 150 python3 -m pytest -q -s -m gpu -p no:cacheprovider -rs tests/test_cuda_halo.py \
                -k mpiexec_ipc
              stage mps_breakdown 100 python3 benchmarks/breakdown_mpi.py --scene examples/spheric2.toml --dp 0.006 \
                --ranks 2 --steps 40 --backend numba-cuda --precision float32 \
                --schedules production bulk-synchronous --png "$OUT/breakdown_mps2.png"
              mps_off ;;
    # CPU under real MPI at 1.0 M on the 16 cores, 2 alternated rounds: 1 x 16 threads, -n 2 x 8 and
    # -n 4 x 4, each rank bound to its own cores (Hydra's -bind-to core:K)
    cpu-mpi-21) stage cpu_mpi_21 150 bash -c "B='python3 -m sphgraph bench examples/yeh_petroff.toml --dp 0.0045 \
                --steps 8 --warmup 2 --json'; for r in 1 2; do NUMBA_NUM_THREADS=16 \$B; \
                mpiexec -n 2 -bind-to core:8 env NUMBA_NUM_THREADS=8 \$B --comm mpi || \
                mpiexec -n 2 env NUMBA_NUM_THREADS=8 \$B --comm mpi; \
                mpiexec -n 4 -bind-to core:4 env NUMBA_NUM_THREADS=4 \$B --comm mpi || \
                mpiexec -n 4 env NUMBA_NUM_THREADS=4 \$B --comm mpi; done | tee $OUT/cpu_mpi_21.jsonl" ;;
    # one-rank speed of the tree before the house refactors (39916ab, in .before/tree: see
    # benchmarks/house_ab.sh) against this tree: SPHERIC 2 at 4.4 M, 50 timed steps, alternated, 3 rounds
    house-ab) stage house_ab 200 bash benchmarks/house_ab.sh .before/tree 3 "$OUT/house_ab.jsonl" \
                examples/spheric2.toml --dp 0.006 --steps 50 --warmup 3 --backend numba-cuda ;;
    # the final tree at 4.4 M: mock 2 and 4 against single, 3 alternated rounds of 52 steps (the step-50
    # balance check inside), the float64 match at 2 and 4 ranks
    mock-21-4m) stage mock_21_4m 140 python3 benchmarks/gpu_mock_ranks.py --dp 0.006 --ranks 2 4 --steps 52 \
                --warmup 3 --rounds 3 --transport auto --match --json "$OUT/mock_21_4m.json" ;;
    # the breakdown of 2 MPS processes by the paper's timers, production and bulk-synchronous
    mps-breakdown) mps_on
              stage mps_breakdown 70 python3 benchmarks/breakdown_mpi.py --scene examples/spheric2.toml --dp 0.006 \
                --ranks 2 --steps 40 --backend numba-cuda --precision float32 \
                --schedules production bulk-synchronous --png "$OUT/breakdown_mps2.png"
              mps_off ;;
    # a [forces] sample and a probe sample against a step at 1.0 M (Yeh & Petroff), float32, on the device
    probes-gpu) stage probes_gpu 60 python3 benchmarks/force_sample_cost.py --backend numba-cuda --dp 0.0045 \
                --steps 10 --repeat 10 --probes ;;
    # the GPU tests of the force variants made from the default kernels (DuFort-Frankel, Riemann, mDBC)
    # and of the probe sums on the device
    tests-variants) stage tests_variants 110 python3 -m pytest -q -m gpu -p no:cacheprovider -rs \
                tests/test_cuda_dufort.py tests/test_cuda_riemann.py tests/test_cuda_mdbc.py
              stage tests_probes 45 python3 -m pytest -q -m gpu -p no:cacheprovider -rs tests/test_probe_sums.py ;;
    # the device timeline of 1, 2 and 4 mock ranks at 4.4 M, production (where the GPU idles between
    # the ranks' work), 3 traced steps each
    timeline-21) for r in 1 2 4; do stage timeline_r$r 150 python3 benchmarks/gpu_lanes.py --dp 0.006 --ranks $r \
                --steps 10 --warmup 3 --trace-steps 3 --schedules production --json "$OUT/timeline_r$r.json"; done ;;
    # the GPU tests not yet run on the device: mDBC one rank and mock ranks, probe sums
    tests-pending) stage tests_pending 330 python3 -m pytest -q -m gpu -p no:cacheprovider -rs \
                tests/test_cuda_mdbc.py tests/test_cuda_mdbc_ranks.py tests/test_probe_sums.py ;;
    # mDBC's cost on the GPU (issue 22 §2): SPHERIC 2 at ~1 M particles, float32, dbc / mdbc / mdbc-noslip
    mdbc-cost) stage mdbc_cost 200 python3 benchmarks/mdbc_cost.py --scene examples/spheric2.toml --dp 0.01 \
                --backend numba-cuda --precision float32 --steps 50 --warmup 10 ;;
    # where the device's probe sums leave numba-cpu's (tests/test_probe_sums.py gpu test)
    probe-diag) stage probe_diag 120 python3 .diag/probe_diag.py ;;
    # 13.3 M: mock 2 and 4 against single, 3 alternated rounds of 52 steps (the final tree)
    mock-21-13m) stage mock_21_13m 330 python3 benchmarks/gpu_mock_ranks.py --dp 0.004 --ranks 2 4 --steps 52 \
                --warmup 3 --rounds 3 --transport auto --json "$OUT/mock_21_13m.json" ;;
    # what overlap buys on 2 mock ranks at 4.4 M: production against bulk-synchronous, with each
    # run's device timeline (Perfetto JSON)
    lanes-ab) stage lanes_ab 150 python3 benchmarks/gpu_lanes.py --dp 0.006 --ranks 2 --steps 30 --warmup 3 \
                --trace-steps 2 --schedules production bulk-synchronous --chrome "$OUT" ;;
    # Buchner's wall pressure (issue 22 §3): the formulations of benchmarks/buchner_sweep.py at H/80
    # (all) and H/120 (the Riemann ones), float64 on the device, one JSON line a run
    buchner-80) stage buchner_80 330 python3 benchmarks/buchner_sweep.py --backend numba-cuda --precision float64 \
                --dp-fractions 80 --variants all --timeout-per-run 90 --json "$OUT/buchner_80.json" ;;
    buchner-120) stage buchner_120 200 python3 benchmarks/buchner_sweep.py --backend numba-cuda --precision float64 \
                --dp-fractions 120 --variants zhang-eta0.3 --timeout-per-run 190 --json "$OUT/buchner_120.json" ;;
    buchner-120-mdbc) stage buchner_120_mdbc 420 python3 benchmarks/buchner_sweep.py --backend numba-cuda \
                --precision float64 --dp-fractions 80 120 --variants zhang-eta0.3-mdbc --timeout-per-run 200 \
                --json "$OUT/buchner_120_mdbc.json" ;;
    # the probe-sum GPU test (one and two mock ranks, 2D and 3D, float64 and float32)
    tests-probes) stage tests_probes 120 python3 -m pytest -q -m gpu -p no:cacheprovider -rs tests/test_probe_sums.py ;;
    # Yeh & Petroff's column force, dry floor against the experiment's wet bed (issue 22 §4), dp 0.005
    wetbed)   stage wetbed 470 python3 benchmarks/yeh_wetbed.py --backend numba-cuda --dp 0.005 \
                --json "$OUT/yeh_wetbed.json" --out "$OUT/wetbed_plots" ;;
    wetbed-variants) stage wetbed_variants 520 python3 benchmarks/yeh_wetbed.py --backend numba-cuda --dp 0.005 \
                --runs wet-noslip,wet-zhang --json "$OUT/yeh_wetbed_variants.json" --out "$OUT/wetbed_plots" ;;
    wetbed-noslip) stage wetbed_noslip 560 python3 benchmarks/yeh_wetbed.py --backend numba-cuda --dp 0.005 \
                --runs wet-noslip --json "$OUT/yeh_wetbed_noslip.json" --out "$OUT/wetbed_plots" ;;
    wetbed-noslip-laminar) stage wetbed_noslip_laminar 560 python3 benchmarks/yeh_wetbed.py --backend numba-cuda \
                --dp 0.005 --runs wet-noslip-laminar --json "$OUT/yeh_wetbed_noslip_laminar.json" --out "$OUT/wetbed_plots" ;;
    # the wet bed released by a lifted gate at c = V/sqrt(g h0) = 1 (issue 22 §4; not the experiment's speed)
    wetbed-gate) stage wetbed_gate 260 python3 benchmarks/yeh_wetbed.py --backend numba-cuda --dp 0.005 \
                --runs wet-gate-c1 --json "$OUT/yeh_wetbed_gate.json" --out "$OUT/wetbed_gate_plots" ;;
    # [[motion]] bodies on the device against numba-cpu, float64, one rank and 2 mock ranks
    tests-motion) stage tests_motion 200 python3 -m pytest -q -m gpu -p no:cacheprovider -rs tests/test_cuda_motion.py ;;
    # 2D surge front at dp = a/100 (issue 22 §4), the formulations of benchmarks/front_sweep.py
    front-100) stage front_100 300 python3 benchmarks/front_sweep.py --backend numba-cuda --precision float64 \
                --dp 0.01 --variants all --json "$OUT/front_sweep_100.json" ;;
    # mDBC on numba-cuda across processes (mpiexec -n 2 / 3, staged halos) and on mock ranks
    tests-mdbc-ranks) stage tests_mdbc_ranks 200 python3 -m pytest -q -m gpu -p no:cacheprovider -rs \
                tests/test_cuda_mdbc_ranks.py ;;
    # 4 and 5 mock ranks at 1.3 M against one GPU rank (the halo kernel k_forces included)
    tests-many-ranks) stage tests_many_ranks 200 python3 -m pytest -q -m gpu -p no:cacheprovider -rs \
                tests/test_cuda_multirank.py ;;
    # the renormalised Riemann jump (riemann_jump = "renormalised"): SPHERIC 2 over its 6 s at dp 0.02,
    # its cost against "cancel" over the first 0.5 s (one call, one card), Buchner H/80
    rjump-s2) stage rjump_s2 420 python3 benchmarks/spheric2_heights.py --backend numba-cuda --dp 0.02 \
                --runs zhang-mdbc4-renorm --json "$OUT/rjump_s2.json" --plot "$OUT/rjump_s2.png" ;;
    rjump-cost) stage rjump_cost 200 python3 benchmarks/spheric2_heights.py --backend numba-cuda --dp 0.02 \
                --t-end 0.5 --runs zhang-mdbc4-cancel,zhang-mdbc4-renorm,zhang-mdbc4-cancel,zhang-mdbc4-renorm \
                --json "$OUT/rjump_cost.json" ;;
    rjump-buchner) stage rjump_buchner 180 python3 benchmarks/buchner_sweep.py --backend numba-cuda \
                --precision float64 --dp-fractions 80 --variants zhang-eta0.3-mdbc-renorm --timeout-per-run 150 \
                --json "$OUT/rjump_buchner.json" ;;
    # with riemann_wall = "cancel": the walls cancel the jump of only the rows it cannot renormalise
    rjump-s2-cancel) stage rjump_s2_cancel 360 python3 benchmarks/spheric2_heights.py --backend numba-cuda \
                --dp 0.02 --runs zhang-mdbc4-renorm-cancel --json "$OUT/rjump_s2_cancel.json" \
                --plot "$OUT/rjump_s2_cancel.png" ;;
    rjump-buchner-80|rjump-buchner-120) n=${s##*-}; stage rjump_buchner_$n 330 python3 benchmarks/buchner_sweep.py \
                --backend numba-cuda --precision float64 --dp-fractions $n \
                --variants zhang-eta0.3-mdbc-renorm zhang-eta0.3-mdbc-renorm-cancel --timeout-per-run 160 \
                --json "$OUT/rjump_buchner_$n.json" ;;
    sites-s2-renorm-cancel) stage sites_s2_renorm_cancel 330 python3 benchmarks/exclusion_sites.py \
                --backend numba-cuda --dp 0.02 --t-end 3.6 --run zhang-mdbc4-renorm-cancel \
                --json "$OUT/sites_s2_renorm_cancel.json" --plot "$OUT/sites_s2_renorm_cancel.png" ;;
    # SPHERIC 2's box pressures (the eight sensors, sphgraph.validation.sensors) beside its heights:
    # DualSPHysics' formulation and the runs closest to the heights (docs/validation.md)
    s2p-a) stage s2p_a 420 python3 benchmarks/spheric2_heights.py --backend numba-cuda --precision float32 \
                --dp 0.02 --runs dsph,zhang-noslip4-cancel --json "$OUT/s2p_a.json" --plot "$OUT/s2p_a.png" ;;
    s2p-b) stage s2p_b 560 python3 benchmarks/spheric2_heights.py --backend numba-cuda --precision float32 \
                --dp 0.02 --runs mdbc4,zhang-mdbc4-cancel,noslip4 --json "$OUT/s2p_b.json" --plot "$OUT/s2p_b.png" ;;
    tests-rjump) stage tests_rjump 240 python3 -m pytest -q -m gpu -p no:cacheprovider -rs \
                tests/test_cuda_riemann_jump.py tests/test_cuda_riemann.py ;;
    *) echo "unknown stage $s"; exit 2 ;;
  esac
done
