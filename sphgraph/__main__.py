import sphgraph

sphgraph.COMMAND = True
import signal  # noqa: E402

signal.signal(signal.SIGINT, sphgraph._sigint_at_start)   # the command's start-up handler

from . import cli  # noqa: E402 - after the start-up SIGINT handler

cli.COMMAND = True
raise SystemExit(cli.main())
