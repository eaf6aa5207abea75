#!/usr/bin/env bash
# One-rank speed of an earlier tree against this one, alternated, in one call:
#     bash benchmarks/house_ab.sh BEFORE_DIR ROUNDS OUT.jsonl [sphgraph bench arguments]
# BEFORE_DIR holds the earlier tree (e.g. `mkdir -p .before/tree && git archive 39916ab |
# tar -x -C .before/tree`, the tree before the house refactors); its backends/ and schedules/
# are linked into its package as on the GPU machine. Each line of OUT is `sphgraph bench
# --json` with the tree ("before" / "after") and the round added.
set -u
before=$(cd "$1" && pwd); rounds=$2; out=$3; shift 3
after=$(pwd)
rest=${PYTHONPATH#*:}          # the site packages after the checkout on PYTHONPATH
[ "$rest" = "$PYTHONPATH" ] && rest=""
(cd "$before" && ln -sfn ../backends sphgraph/backends && ln -sfn ../schedules sphgraph/schedules)
: >"$out"
for r in $(seq 1 "$rounds"); do
  for t in before after; do
    dir=$before; [ $t = after ] && dir=$after
    line=$(cd "$dir" && PYTHONPATH="$dir${rest:+:$rest}" python3 -m sphgraph bench "$@" --json | grep '^{')
    echo "{\"tree\": \"$t\", \"round\": $r, ${line#\{}" | tee -a "$out"
  done
done
python3 - "$out" <<'PY'
import json, statistics, sys
rows = [json.loads(x) for x in open(sys.argv[1])]
med = {t: statistics.median(r["steps_per_s"] for r in rows if r["tree"] == t) for t in ("before", "after")}
print(json.dumps({"median_steps_per_s": med, "after_over_before": med["after"] / med["before"]}))
PY
