import os
import signal


def _sigint_at_start(signum, frame):
    # start-up of `python -m sphgraph` (imports, before main's handlers): nothing is written yet
    os.write(2, b"sphgraph: interrupted (SIGINT) during start-up\n")
    os._exit(130)


signal.signal(signal.SIGINT, _sigint_at_start)

from . import cli  # noqa: E402 - after the start-up SIGINT handler

cli.COMMAND = True
raise SystemExit(cli.main())
