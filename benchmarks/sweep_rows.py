"""The bookkeeping every validation sweep of benchmarks/ shares: run one variant, keep the
row whatever happens to it, print it and rewrite the JSON file as each run finishes (so a
sweep cut by a time limit keeps what it measured)."""
from __future__ import annotations

import json
import time
import traceback


def attempt(row: dict, run) -> dict:
    """`row` updated with `run()`'s fields and ok=True, or -- the sweep goes on -- ok=False
    and the failure: a NumericalError's own line (step and cause), else the traceback; the
    wall seconds either way unless `run` gave them."""
    from sphgraph.errors import NumericalError
    t0 = time.perf_counter()
    try:
        row.update(ok=True, **run())
    except NumericalError as e:
        row.update(ok=False, failure=str(e))
    except Exception:   # noqa: BLE001 - recorded, the next run goes on
        row.update(ok=False, failure=traceback.format_exc(limit=3))
    row.setdefault("wall_s", time.perf_counter() - t0)
    return row


def record(rows: list, row: dict, path: str | None, quiet=("series",)) -> None:
    """Append `row`, print it as one JSON line (less the bulky `quiet` fields) and rewrite `path`."""
    rows.append(row)
    print(json.dumps({k: v for k, v in row.items() if k not in quiet}), flush=True)
    if path:
        with open(path, "w") as f:
            json.dump(rows, f)
