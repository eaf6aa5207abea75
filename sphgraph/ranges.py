"""The physical range of every number a scene or the command line may give.

One table, read by the scene checker (:class:`sphgraph.scene_schema._Checker`) and by
the command line (:func:`check_flag`) before any arithmetic: a value is first a real
number of the right type and finite, then inside its range, and the error names the
range and what it stands for. ``docs/scenes.md`` carries the same table (a test
compares them), and a number the checker is asked about without a row here is a
programming error (exit 3), so a new key cannot slip in without one.

Keys are dotted scene paths with list indices written ``[]`` (``fluid[].max``,
``motion[].velocity[]``); for vectors the range holds for each component. The ranges
are wide -- they admit every case in the literature the project reproduces, from
Poiseuille flow at 1e-4 m/s to a 10 km ocean -- and exist to stop values that no
simulation means (``gravity = 1e30``, ``coefh = 1e-300``) before they overflow or
divide by zero.
"""
from __future__ import annotations

import math
import numbers
import re

from .errors import InputError

COORD = 1e7   # [m]: coordinates within 10,000 km of the origin (Earth's radius is 6,371 km)
_C = (-COORD, COORD, "m", "a coordinate within 10,000 km of the origin")
_LEN = (1e-9, COORD, "m", "a length between 1 nm and 10,000 km")

# key: (lowest, highest, unit, what the range stands for)
RANGES = {
    "dp": (1e-6, 100.0, "m", "a particle spacing between 1 um and 100 m"),
    "end_time": (1e-9, 1e6, "s", "simulated time up to 11.6 days"),
    "output_interval": (1e-12, 1e6, "s", "time between frames up to 11.6 days"),
    "domain.min": _C, "domain.max": _C, "domain.origin": _C,
    "domain.exclude_max_share": (0.0, 1.0, "", "share of the fluid particles excluded before the run stops"),
    "physics.coefh": (0.1, 10.0, "", "h = coefh*sqrt(dim)*dp; DualSPHysics uses 0.75-1.5"),
    "physics.coefsound": (0.1, 1e4, "", "c0 = coefsound*sqrt(g*hswl); 10-40 is usual"),
    "physics.gamma": (1.0, 20.0, "", "Tait exponent: 7 for water, 1.4 for air"),
    "physics.rho0": (1e-3, 1e5, "kg/m^3", "from rarefied gas to beyond osmium (22,590)"),
    "physics.gravity": (-1e3, 1e3, "m/s^2", "each component at most about 100 g"),
    "physics.visc_alpha": (0.0, 10.0, "", "artificial viscosity; DualSPHysics uses 0.01-0.1"),
    "physics.visc_bound_factor": (0.0, 100.0, "", "boundary viscosity as a multiple of visc_alpha"),
    "physics.laminar_nu": (0.0, 1e3, "m^2/s", "water 1e-6, honey 1e-2, molten glass 1e2"),
    "physics.delta": (0.0, 1.0, "", "density diffusion; DualSPHysics uses 0.1"),
    "physics.verlet_euler_every": (1, 10**6, "steps", "an Euler step every 1 to 10^6 steps"),
    "physics.cfl": (1e-6, 10.0, "", "Courant number; 0.1-0.4 is usual"),
    "physics.hswl": (1e-6, 1.2e4, "m", "still-water depth up to the deepest ocean"),
    "physics.rho_min": (0.0, 1e6, "kg/m^3", "the lowest density a particle may reach"),
    "physics.rho_max": (1e-3, 1e7, "kg/m^3", "the highest density a particle may reach"),
    "physics.shifting_coef": (-100.0, 0.0, "", "DualSPHysics ShiftCoef, default -2"),
    "physics.shifting_tfs": (0.0, 3.0, "", "free-surface threshold of div r, below dim"),
    "physics.riemann_eta": (0.0, 100.0, "", "the Riemann limiter's factor; Zhang et al. 2017 use 3"),
    "initial.jitter": (0.0, 0.25, "dp", "random displacement as a fraction of dp"),
    "limits.max_particles": (1, 2 ** 53, "particles", "a count float64 holds exactly"),
    "fluid[].min": _C, "fluid[].max": _C,
    "boundary[].min": _C, "boundary[].max": _C,
    "boundary[].layers": (1, 100, "layers", "1-100 particle layers"),
    # shapes (sphgraph.shapes): cylinders and STL meshes in either group, slopes as boundaries
    "fluid[].center": _C, "boundary[].center": _C,
    "fluid[].radius": _LEN, "boundary[].radius": _LEN,
    "fluid[].length": _LEN, "boundary[].length": _LEN,
    "boundary[].width": _LEN,
    "fluid[].axis": (-1e6, 1e6, "", "a direction vector"), "boundary[].axis": (-1e6, 1e6, "", "a direction vector"),
    "boundary[].start": _C, "boundary[].end": _C,
    "boundary[].angle": (-90.0, 90.0, "degrees", "a slope's angle"),
    "fluid[].scale": (1e-9, 1e9, "", "an STL mesh's scale factor"),
    "boundary[].scale": (1e-9, 1e9, "", "an STL mesh's scale factor"),
    "fluid[].offset": _C, "boundary[].offset": _C,
    # moving bodies (sphgraph.motion) and damping zones (sphgraph.waves)
    "motion[].velocity[]": (-1e4, 1e4, "m/s", "each component below 10 km/s"),
    "motion[].omega[]": (-1e4, 1e4, "rad/s", "below 10^4 rad/s"),
    "motion[].center": _C, "motion[].hinge": _C,
    "motion[].axis": (-1e6, 1e6, "", "a direction vector"),
    "motion[].height": (1e-9, 1e3, "m", "a wave height up to 1 km"),
    "motion[].period": (1e-6, 1e6, "s", "a wave period up to 11.6 days"),
    "motion[].depth": (1e-9, 1.2e4, "m", "a water depth up to the deepest ocean"),
    "motion[].ramp": (0.0, 1e6, "s", "a ramp-up time up to 11.6 days"),
    "motion[].phase": (-1e6, 1e6, "rad", "a phase"),
    "motion[].start": (0.0, 1e6, "s", "a start time up to 11.6 days"),
    "motion[].speed": (1e-9, 1e4, "m/s", "a gate's speed below 10 km/s"),
    "motion[].lift": _LEN,
    "motion[].times": (0.0, 1e6, "s", "times of a motion table up to 11.6 days"),
    "damping[].start": _C, "damping[].end": _C,
    "damping[].overlimit": (0.0, 1e30, "m", "distance beyond end at full damping; 1e30 = no limit"),
    "damping[].redumax": (1e-9, 1e6, "", "the largest velocity reduction"),
    # load balancing (sphgraph.balance): the scene's [balance], the schedule's [rebalance]
    # and the --rebalance-* flags share these rows
    "balance.every": (1, 10**9, "steps", "a balance check every 1 to 10^9 steps"),
    "balance.threshold": (0.0, 1e4, "", "the drop of the imbalance that applies new cuts; 0.03 = 3 points"),
    "balance.max_particles_per_rank": (1, 2 ** 53, "particles", "a rank's capacity; a count float64 holds exactly"),
    "balance.smoothing": (0.0, 1.0, "", "the newest window's weight in the average of the ranks' speeds, above 0"),
    # probes and body forces (sphgraph.probes)
    "probes.interval": (0.0, 1e6, "s", "time between samples up to 11.6 days; 0 = every step"),
    "probes.points[].position": _C,
    "probes.heights[].position": _C,
    "forces.interval": (0.0, 1e6, "s", "time between samples up to 11.6 days; 0 = every step"),
    "forces.bodies[].min": _C, "forces.bodies[].max": _C,
}

# integers that name one of a few options rather than measure anything: checked as exact
# integers in the set (``dim = 2.0`` and ``true`` are refused), listed here so that the
# schema's every key is either a range, one of these, or no number at all
CHOICES = {
    "format": (1,),
    "dim": (2, 3),
    "motion[].order": (1, 2),
}

# command-line flags (sphgraph.cli): flag -> (lowest, highest, unit, what it stands for)
FLAG_RANGES = {
    "--dp": RANGES["dp"],
    "--end-time": RANGES["end_time"],
    "--max-steps": (1, 10**12, "steps", "a step count"),
    "--ranks": (1, 4096, "ranks", "simulated or MPI ranks"),
    "--seed": (0, 2**63 - 1, "", "a seed numpy accepts"),
    "--watchdog": (0.0, 1e6, "s", "seconds a rank may wait; 0 = off"),
    "--walltime": (1e-3, 1e8, "s", "wall-clock seconds before a checkpoint and a clean stop"),
    "--steps": (1, 10**9, "steps", "timed steps"),
    "--warmup": (0, 10**9, "steps", "untimed steps"),
    "--rank-speed": (1e-6, 1e6, "", "relative rank throughput"),
    "--duplicate": (0.0, 1.0, "", "a probability per message"),
    "--loss": (0.0, 1.0, "", "a probability per message"),
    "--rebalance-every": RANGES["balance.every"],
    "--rebalance-threshold": RANGES["balance.threshold"],
    "--max-particles-per-rank": RANGES["balance.max_particles_per_rank"],
}

_INDEX = re.compile(r"\[\d+\]")


def canonical(key: str) -> str:
    """The RANGES key of a scene key: list indices become ``[]`` (``fluid[2].max`` -> ``fluid[].max``)."""
    return _INDEX.sub("[]", key)


def range_of(key: str) -> tuple:
    """(lowest, highest, unit, why) of a scene key or flag.

    Raises
    ------
    LookupError
        No row for it: a programming error (every number has a range).
    """
    k = key if key.startswith("--") else canonical(key)
    table = FLAG_RANGES if key.startswith("--") else RANGES
    if k not in table:
        raise LookupError(f"no physical range for {key!r} in sphgraph.ranges (every number needs one)")
    return table[k]


def is_real(v) -> bool:
    """A number of a scene: int or float (numpy's too), never a bool (``true`` is no number)."""
    # numbers.Real covers numpy's integers and floats without importing numpy (the command
    # line imports this module first, and stays interruptible by a cheap start-up)
    return isinstance(v, numbers.Real) and not isinstance(v, bool) and type(v).__name__ != "bool_"


def finite(v) -> bool:
    """Whether ``v`` is a real number that float64 holds finitely (a 400-digit integer is not)."""
    if not is_real(v):
        return False
    try:
        return math.isfinite(float(v))
    except OverflowError:
        return False


def _fmt(x) -> str:
    return f"{x:g}" if isinstance(x, float) else str(x)


def describe(key: str, gt=None, ge=None, le=None) -> str:
    """The expected form of a number of ``key``: its physical range, and bounds of the caller
    (``gt``, ``ge``, ``le``) that the range does not already imply."""
    lo, hi, unit, why = range_of(key)
    conds = [f"> {_fmt(gt)}"] if gt is not None and not lo > gt else []
    conds += [f">= {_fmt(max(lo, ge if ge is not None else lo))}"]
    conds += [f"<= {_fmt(min(hi, le if le is not None else hi))}"]
    return f"a number {' and '.join(conds)}{f' [{unit}]' if unit else ''} ({why})"


def expected(key: str, v, integer: bool = False, gt=None, ge=None, le=None) -> str | None:
    """None when ``v`` is a number of ``key``'s type (an integer with ``integer``), finite,
    within the caller's bounds and inside the key's range; else the expected form, for the
    one-line error ``FILE: key: expected FORM, got VALUE``. Nothing but comparisons happens
    to ``v`` before it passes (a 400-digit integer is compared exactly, never converted)."""
    form = describe(key, gt, ge, le)
    if integer:
        ok = isinstance(v, numbers.Integral) and not isinstance(v, bool) and type(v).__name__ != "bool_"
        form = form.replace("a number", "an integer", 1)
    else:
        ok = finite(v)
    if ok:
        x = v if integer else float(v)
        ok = ((gt is None or x > gt) and (ge is None or x >= ge) and (le is None or x <= le)
              and in_range(key, x))
    return None if ok else form


def in_range(key: str, v) -> bool:
    lo, hi, _, _ = range_of(key)
    return lo <= v <= hi


def check_flag(flag: str, v, integer: bool = False):
    """A command-line number: right type, finite, inside its range; else InputError naming it."""
    lo, hi, unit, why = range_of(flag)
    ok = isinstance(v, int) and not isinstance(v, bool) if integer else finite(v)
    if not ok or not lo <= v <= hi:
        kind = "an integer" if integer else "a number"
        raise InputError(f"{flag}: expected {kind} >= {_fmt(lo)} and <= {_fmt(hi)}"
                         f"{f' [{unit}]' if unit else ''} ({why}), got {v!r}")
    return v
