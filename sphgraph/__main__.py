import sphgraph

# sphgraph/__init__.py installed the start-up SIGINT handler when it saw python -m sphgraph;
# runpy.run_module("sphgraph") from code reaches here without it
sphgraph.COMMAND = True
import signal  # noqa: E402

signal.signal(signal.SIGINT, sphgraph._sigint_at_start)   # the command's start-up handler

from . import cli  # noqa: E402 - after the start-up SIGINT handler

cli.COMMAND = True
raise SystemExit(cli.main())
