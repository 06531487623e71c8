"""The options the commands share: argument types, option groups, the parser and its help texts.

Each option is defined once here (its type, metavar and help); a command module adds the groups
it takes. Nothing here reads a file or starts JAX.
"""

from __future__ import annotations

import argparse
import functools
import math
import textwrap
from pathlib import Path

PROG = "grasp-jax"
DEFAULT_MU = 0.364  # tan(20 deg), the paper's friction

DESCRIPTION = """\
Force-closure and the quality Q of multi-finger grasps via central axes (Bounab, Sidobre and
Zaatri), batched in JAX. Sample random grasps of an object and score them by the million with
flat memory, score grasps stored in a file, or draw the best ones.

Optimize grasps by gradient, moving their contacts over the object's surface (from random starts,
or from the best grasps of a sampled file).

With no arguments, runs the demo: 100,000 random 4-finger grasps of the built-in glass."""

_EXAMPLES = """\
examples:
  grasp-jax                                   # the demo (same as: grasp-jax demo)
  grasp-jax sample glass --num 1000000 --out glass.parquet
  grasp-jax sample star --fingers 3 --num 20000 --epsilon --out star.npz --plot star.png
  grasp-jax sample ../shared/data/meshes/ycb_025_mug.obj --fingers 4 --scheme paper
  grasp-jax sample wrench.csv --hole wrench_hole.csv --fingers 3 --out wrench.npz
  grasp-jax score glass.parquet --mu 0.2 --out glass_mu02.npz
  grasp-jax show glass.parquet --top 6
  grasp-jax show glass.parquet --top 10 --html glass.html
  grasp-jax optimize glass --fingers 4 --starts 1024 --steps 200 --out opt.npz --plot opt.png
  grasp-jax sample glass --num 100000 --out s.npz && grasp-jax optimize --from s.npz --starts 256
  grasp-jax sample glass --num 10000 --robust 100 --sigma-pos 0.02 --mu-range 0.8,1.2 --out robust.parquet
  grasp-jax dataset meshes/ --out data/ --num 10000 --robust 100 --sigma-pos 0.02 --shard 0/4
  grasp-jax hand mug.obj --hand allegro_hand_right.urdf --starts 256 --out mug_hand.parquet --html mug.html
  grasp-jax sample mug.obj --gripper parallel-jaw --max-width 0.1 --num 2000 --out jaws.npz && grasp-jax simulate jaws.npz
"""

_NOTES = (
    ("OBJECT is a built-in name ({builtins}) or a path to a mesh (.obj, .stl, .ply, ...) or a polygon "
     "(.csv of x,y vertices; --hole FILE.csv cuts a hole in it, once per hole)."),
    ("Result files (.npz or .parquet) hold points, normals, force_closure, quality, converged (and "
     "epsilon, volume) per grasp plus the run's metadata ('optimize' adds initial_points, objective, reason "
     "and the per-step history and quality_history of every start); read them with "
     "grasp_jax.storage.read_results(path), numpy.load or pyarrow."),
    ("Compiled programs are cached in ~/.cache/grasp_jax/xla (GRASP_JAX_CACHE=DIR moves it, "
     "GRASP_JAX_CACHE=off disables it)."),
)

_BUILTINS = "glass, part, quad, star, sphere, box, cylinder, ellipsoid"
_DEVICES_HELP = "CPU devices to split the cores into (default: one per core; ignored if XLA_FLAGS already sets it)"


@functools.cache
def builtin_names() -> str:
    """The built-in objects' names, for the help (a fixed list if the objects cannot be imported)."""
    try:
        from ..objects import BUILTIN_NAMES
    except Exception:  # noqa: BLE001 - help must work even if objects cannot be imported
        return _BUILTINS
    return ", ".join(BUILTIN_NAMES)


def epilog() -> str:
    """The examples and notes printed below the help of ``grasp-jax`` and of the main commands."""
    notes = "\n\n".join(textwrap.fill(n.format(builtins=builtin_names()), width=96) for n in _NOTES)
    return _EXAMPLES + "\n" + notes


class UsageError(Exception):
    """A mistake on the command line (printed as one line, status 2)."""


class Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Shows defaults (except None / False, whose help says what happens) and keeps the examples'
    line breaks."""

    def __init__(self, prog):
        super().__init__(prog, max_help_position=32, width=100)

    def _get_help_string(self, action):
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)


class Parser(argparse.ArgumentParser):
    """argparse that reports a mistake as one line (``grasp-jax: error: ...``) and status 2."""

    def error(self, message):
        raise UsageError(f"{message} (see '{self.prog} --help')")


# ---------------------------------------------------------------------------------------------
# Argument types


def integer(minimum: int, what: str):
    """An integer >= ``minimum``; ``what`` names it in the message of a bad value."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}")
        return value

    parse.__name__ = what
    return parse


def count(text: str) -> int:
    """A positive integer that may be written 1e6 or 1_000_000."""
    try:
        value = float(text.replace("_", "")) if any(c in text for c in "eE.") else int(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer; got {text!r}") from None
    if not (isinstance(value, int) or (math.isfinite(value) and value == int(value))) or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer; got {text!r}")
    return int(value)


def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0; got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0; got {text!r}")
    return value


def nonnegative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0; got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0; got {text!r}")
    return value


def fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1]; got {text!r}") from None
    if not (0 <= value <= 1):
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1]; got {text!r}")
    return value


def point(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated coordinates like 0,0,0.1; got {text!r}") from None
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected 2 or 3 comma-separated coordinates; got {text!r}")
    return values


def multipliers(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two comma-separated multipliers like 0.8,1.2; got {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise argparse.ArgumentTypeError(f"expected multipliers 0 < LO <= HI; got {text!r}")
    return lo, hi


def pose(text: str) -> tuple[float, float]:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ROT or ROT,TRANS (numbers >= 0); got {text!r}") from None
    if len(values) not in (1, 2) or not all(math.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected ROT or ROT,TRANS (numbers >= 0); got {text!r}")
    return values[0], values[-1]


def lengths(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three comma-separated lengths like 0.01,0.02,0.05; got {text!r}") from None
    if len(values) != 3 or not all(math.isfinite(v) and v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected three comma-separated lengths > 0; got {text!r}")
    return values


# ---------------------------------------------------------------------------------------------
# Single options, whose default and help differ between commands


def add_fingers(g, default: int | None, help: str) -> None:
    g.add_argument("--fingers", type=integer(2, "an integer >= 2"), default=default, help=help)


def add_seed(g, help: str) -> None:
    g.add_argument("--seed", type=integer(0, "an integer >= 0"), default=0, help=help)


def add_mu(g, default: float | None, help: str) -> None:
    g.add_argument("--mu", type=positive_float, default=default, help=help)


def add_edges(g, default: int | None, help: str) -> None:
    g.add_argument("--edges", type=integer(3, "an integer >= 3"), default=default, help=help)


def add_devices(g, help: str = _DEVICES_HELP) -> None:
    g.add_argument("--devices", type=integer(1, "an integer >= 1"), default=None, metavar="N", help=help)


def add_chunk(g, help: str) -> None:
    g.add_argument("--chunk", type=count, default=None, metavar="N", help=help)


def add_reporting(g) -> None:
    """--json and --quiet: how the summary is printed."""
    g.add_argument("--json", action="store_true", help="print the summary as one JSON line")
    g.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")


def add_hole(p: argparse.ArgumentParser, *, from_file: bool = False) -> None:
    p.add_argument("--hole", type=Path, action="append", default=None, metavar="FILE.csv",
                   help="a hole of a polygon OBJECT (.csv): a CSV of x,y rows; repeat for several holes"
                        + (" (default: the file's metadata)" if from_file else ""))


# ---------------------------------------------------------------------------------------------
# Option groups


def add_sampling(p: argparse.ArgumentParser, *, num: int) -> None:
    g = p.add_argument_group("sampling")
    add_fingers(g, 4, "contacts per grasp")
    g.add_argument("--num", type=count, default=num, help="grasps to sample and score (1e6 is fine)")
    add_seed(g, "random seed")
    g.add_argument("--scheme", choices=("uniform", "paper"), default="uniform",
                   help="'uniform': all contacts uniform on the surface; 'paper': a fixed first contact "
                        "and random others, as in the paper's experiments")
    g.add_argument("--first-contact", type=integer(0, "a facet index >= 0"), default=None, metavar="F",
                   help="with --scheme paper: the facet of the first contact (default: drawn from --seed)")


def add_scoring(p: argparse.ArgumentParser, *, from_file: bool) -> None:
    """The scoring, robust-label and output options of ``sample``, ``score`` and ``demo``
    (``from_file``: defaults from the file's metadata)."""
    g = p.add_argument_group("scoring")

    def dflt(value) -> str:
        return f" (default: the file's metadata, else {value})" if from_file else ""

    add_mu(g, None if from_file else DEFAULT_MU,
           "friction coefficient tan(alpha); 0.364 is the paper's 20 degrees" + dflt(DEFAULT_MU))
    add_edges(g, None if from_file else 8,
              "edges of each linearized 3D friction cone (the paper uses 25)" + dflt(8))
    g.add_argument("--torque-test", choices=("exact", "paper"), default=None if from_file else "exact",
                   help="'exact' positive-spanning test (correct), or the paper's eq. (15) (only "
                        "necessary in 3D)" + dflt("exact"))
    add_contact(g, dflt("hard"))
    add_critical(g)
    g.add_argument("--epsilon", action="store_true",
                   help="also compute the Ferrari-Canny epsilon and hull volume with qhull (slow: "
                        "5-30 ms per grasp)")
    g.add_argument("--origin", type=point, default=None, metavar="X,Y[,Z]",
                   help="point epsilon's torques are taken about (default: the object's centre of mass)")
    g.add_argument("--torque-scale", type=positive_float, default=None, metavar="L",
                   help="length epsilon's torques are divided by (default: the object's radius, as GraspIt)")
    add_robust(p)
    o = p.add_argument_group("output and performance")
    o.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="write every grasp and its scores to FILE (.npz or .parquet), atomically")
    add_chunk(o, "grasps per chunk (sampled, scored, written together; default 65536 on a CPU)")
    add_devices(o)
    o.add_argument("--distributed", action="store_true",
                   help="join a multi-process JAX job (jax.distributed.initialize; automatic when "
                        "JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID are set): each "
                        "process scores its slice and writes FILE.<i>-of-<P>.<suffix>")
    add_reporting(o)


def add_contact(g, default_note: str = "") -> None:
    g.add_argument("--contact", choices=("hard", "soft", "dexnet-soft"), default=None,
                   help="contact model: 'hard' point contacts with friction (the paper's), 'soft' fingers "
                        "(a moment about the normal up to TORSION x the normal force; two soft contacts can "
                        "hold a grasp), or 'dexnet-soft' (Dex-Net's soft-finger columns, to reproduce its "
                        "labels); 3D only" + (default_note or " (default: hard)"))
    g.add_argument("--torsion", type=nonnegative_float, default=None, metavar="L",
                   help="torsional coefficient of soft contacts, a length in the object's units ('soft': "
                        "the largest moment per unit normal force; 'dexnet-soft': Dex-Net's pi r^2 mu)")
    g.add_argument("--patch-radius", type=positive_float, default=None, metavar="R",
                   help="instead of --torsion: the contact patch radius, torsion = (2/3) mu R ('soft', a "
                        "uniformly pressed disc) or pi R^2 mu ('dexnet-soft', R its finger_radius)")


def add_critical(g) -> None:
    g.add_argument("--critical-friction", action=argparse.BooleanOptionalAction, default=None,
                   help="also the smallest friction coefficient at which each grasp is force-closure "
                        "(columns critical_mu, critical_status, friction_label: GraspNet-1Billion's "
                        "0.2..1.2 label; about 1/10 of the throughput for two soft contacts, 1/16 for four "
                        "hard ones) (default: on with --gripper, else off)")


def add_robust(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("robust labels (grasp_jax.robust)")
    g.add_argument("--robust", type=integer(2, "an integer >= 2"), default=None, metavar="N",
                   help="also label every grasp under N perturbations (the same N for every grasp): columns "
                        "p_fc (P(force-closure)), q_mean, q_low, margin_mean, margin_low and their standard "
                        "errors, beside the nominal ones")
    g.add_argument("--sigma-pos", type=nonnegative_float, default=0.0, metavar="S",
                   help="contact position noise along the surface, per tangent axis, in object radii")
    g.add_argument("--sigma-normal", type=nonnegative_float, default=0.0, metavar="RAD",
                   help="normal tilt per tangent axis, radians")
    g.add_argument("--mu-range", type=multipliers, default=None, metavar="LO,HI",
                   help="friction per contact: mu x U[LO, HI]")
    g.add_argument("--mu-sigma", type=nonnegative_float, default=0.0, metavar="S",
                   help="instead of --mu-range: friction per contact mu x exp(N(0, S^2)) (lognormal)")
    g.add_argument("--sigma-pose", type=pose, default=None, metavar="ROT[,TRANS]",
                   help="object pose noise under fixed fingers: rotation per axis (radians) and translation "
                        "per axis (object radii; default: ROT); contacts go to the nearest surface point")
    g.add_argument("--quantile", type=fraction, default=0.1, metavar="Q",
                   help="the low quantile of q_low and margin_low")
    g.add_argument("--robust-seed", type=integer(0, "an integer >= 0"), default=None, metavar="SEED",
                   help="seed of the perturbations (default: --seed, or 0)")
    g.add_argument("--no-margin", action="store_true",
                   help="leave out the min-weight margin columns (margin_*)")


def add_gripper(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("gripper (grasp_jax.grippers)")
    g.add_argument("--gripper", choices=("parallel-jaw",), default=None,
                   help="sample antipodal parallel-jaw grasps (2 contacts where the jaws' closing line meets a "
                        "mesh) and write their poses: center, axis, approach, width, jaw_status; scored as soft "
                        "contacts (default --patch-radius: max width / 20)")
    g.add_argument("--max-width", type=positive_float, default=None, metavar="W",
                   help="the gripper's largest opening, in the object's units (required with --gripper)")
    g.add_argument("--min-width", type=nonnegative_float, default=None, metavar="W",
                   help="the gripper's smallest opening (default 0)")
    g.add_argument("--collision", action="store_true",
                   help="reject grasps whose gripper body (two finger boxes and a palm) intersects the object "
                        "(jaw_status COLLISION; needs python-fcl)")
    g.add_argument("--finger-size", type=lengths, default=None, metavar="T,B,L",
                   help="finger box thickness, breadth and length for --collision (default W/8, W/4, 0.6 W)")
    g.add_argument("--palm-size", type=lengths, default=None, metavar="S,B,D",
                   help="palm box span, breadth and depth for --collision (default 1.25 W, W/4, W/4)")


def add_plot(p: argparse.ArgumentParser, default_help: str | None = None,
             help_text: str = "draw the best force-closure grasps on the object") -> None:
    g = p.add_argument_group("figure")
    g.add_argument("--plot", type=Path, default=None, metavar="FILE.png",
                   help=help_text + (f" ({default_help})" if default_help else ""))
    g.add_argument("--top", type=integer(1, "an integer >= 1"), default=4, metavar="K",
                   help="how many of the best grasps to draw and list")
