"""The ``grasp-jax`` command: sample and score grasps of an object, score a file, draw the best.

Run ``grasp-jax --help`` (or ``python -m grasp_jax --help``) for the subcommands. Heavy modules
(JAX, trimesh, matplotlib, pyarrow) are imported inside :func:`main`, after the command line has
been read and the CPU device count chosen.

Exit status: 0 on success, 2 for a user mistake (one ``grasp-jax: error: ...`` line on stderr),
130 after ``Ctrl-C`` (and 143 after ``SIGTERM``), with no partial output file in either case.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

PROG = "grasp-jax"
DEFAULT_MU = 0.364  # tan(20 deg), the paper's friction
DEMO_OBJECT = "glass"
DEMO_NUM = 100_000
PLOT_SUFFIXES = (".png", ".pdf", ".svg")

_DESCRIPTION = """\
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
"""

_NOTES = (
    "OBJECT is a built-in name ({builtins}) or a path to a mesh (.obj, .stl, .ply, ...) or a polygon "
    "(.csv of x,y vertices; --hole FILE.csv cuts a hole in it, once per hole).",
    "Result files (.npz or .parquet) hold points, normals, force_closure, quality, converged (and "
    "epsilon, volume) per grasp plus the run's metadata ('optimize' adds initial_points, objective, reason "
    "and the per-step history and quality_history of every start); read them with "
    "grasp_jax.storage.read_results(path), numpy.load or pyarrow.",
    "Compiled programs are cached in ~/.cache/grasp_jax/xla (GRASP_JAX_CACHE=DIR moves it, "
    "GRASP_JAX_CACHE=off disables it).",
)


def _epilog(builtins: str) -> str:
    import textwrap

    notes = "\n\n".join(textwrap.fill(n.format(builtins=builtins), width=96) for n in _NOTES)
    return _EXAMPLES + "\n" + notes


class _UsageError(Exception):
    """A mistake on the command line (printed as one line, status 2)."""


class _Formatter(argparse.ArgumentDefaultsHelpFormatter, argparse.RawDescriptionHelpFormatter):
    """Shows defaults (except None / False, whose help says what happens) and keeps the examples'
    line breaks."""

    def __init__(self, prog):
        super().__init__(prog, max_help_position=32, width=100)

    def _get_help_string(self, action):
        if action.default is None or action.default is False:
            return action.help
        return super()._get_help_string(action)


class _Parser(argparse.ArgumentParser):
    """argparse that reports a mistake as one line (``grasp-jax: error: ...``) and status 2."""

    def error(self, message):
        raise _UsageError(f"{message} (see '{self.prog} --help')")


# ---------------------------------------------------------------------------------------------
# Argument types


def _int(minimum: int, what: str):
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


def _count(text: str) -> int:
    """A positive integer that may be written 1e6 or 1_000_000."""
    try:
        value = float(text.replace("_", "")) if any(c in text for c in "eE.") else int(text.replace("_", ""))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer; got {text!r}") from None
    if not (isinstance(value, int) or (math.isfinite(value) and value == int(value))) or value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer; got {text!r}")
    return int(value)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0; got {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0; got {text!r}")
    return value


def _point(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated coordinates like 0,0,0.1; got {text!r}") from None
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected 2 or 3 comma-separated coordinates; got {text!r}")
    return values


# ---------------------------------------------------------------------------------------------
# Parser


def _add_scoring(p: argparse.ArgumentParser, *, from_file: bool) -> None:
    g = p.add_argument_group("scoring")

    def dflt(value) -> str:
        return f" (default: the file's metadata, else {value})" if from_file else ""

    g.add_argument("--mu", type=_positive_float, default=None if from_file else DEFAULT_MU,
                   help="friction coefficient tan(alpha); 0.364 is the paper's 20 degrees" + dflt(DEFAULT_MU))
    g.add_argument("--edges", type=_int(3, "an integer >= 3"), default=None if from_file else 8,
                   help="edges of each linearized 3D friction cone (the paper uses 25)" + dflt(8))
    g.add_argument("--torque-test", choices=("exact", "paper"), default=None if from_file else "exact",
                   help="'exact' positive-spanning test (correct), or the paper's eq. (15) (only "
                        "necessary in 3D)" + dflt("exact"))
    _add_contact(g, dflt("hard"))
    _add_critical(g)
    g.add_argument("--epsilon", action="store_true",
                   help="also compute the Ferrari-Canny epsilon and hull volume with qhull (slow: "
                        "5-30 ms per grasp)")
    g.add_argument("--origin", type=_point, default=None, metavar="X,Y[,Z]",
                   help="point epsilon's torques are taken about (default: the object's centre of mass)")
    g.add_argument("--torque-scale", type=_positive_float, default=None, metavar="L",
                   help="length epsilon's torques are divided by (default: the object's radius, as GraspIt)")
    _add_robust(p)
    o = p.add_argument_group("output and performance")
    o.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="write every grasp and its scores to FILE (.npz or .parquet), atomically")
    o.add_argument("--chunk", type=_count, default=None, metavar="N",
                   help="grasps per chunk (sampled, scored, written together; default 65536 on a CPU)")
    o.add_argument("--devices", type=_int(1, "an integer >= 1"), default=None, metavar="N",
                   help="CPU devices to split the cores into (default: one per core; ignored if XLA_FLAGS "
                        "already sets it)")
    o.add_argument("--distributed", action="store_true",
                   help="join a multi-process JAX job (jax.distributed.initialize; automatic when "
                        "JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES, JAX_PROCESS_ID are set): each "
                        "process scores its slice and writes FILE.<i>-of-<P>.<suffix>")
    o.add_argument("--json", action="store_true", help="print the summary as one JSON line")
    o.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")


def _add_robust(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("robust labels (grasp_jax.robust)")
    g.add_argument("--robust", type=_int(2, "an integer >= 2"), default=None, metavar="N",
                   help="also label every grasp under N perturbations (the same N for every grasp): columns "
                        "p_fc (P(force-closure)), q_mean, q_low, margin_mean, margin_low and their standard "
                        "errors, beside the nominal ones")
    g.add_argument("--sigma-pos", type=_nonnegative_float, default=0.0, metavar="S",
                   help="contact position noise along the surface, per tangent axis, in object radii")
    g.add_argument("--sigma-normal", type=_nonnegative_float, default=0.0, metavar="RAD",
                   help="normal tilt per tangent axis, radians")
    g.add_argument("--mu-range", type=_range, default=None, metavar="LO,HI",
                   help="friction per contact: mu x U[LO, HI]")
    g.add_argument("--mu-sigma", type=_nonnegative_float, default=0.0, metavar="S",
                   help="instead of --mu-range: friction per contact mu x exp(N(0, S^2)) (lognormal)")
    g.add_argument("--sigma-pose", type=_pose, default=None, metavar="ROT[,TRANS]",
                   help="object pose noise under fixed fingers: rotation per axis (radians) and translation "
                        "per axis (object radii; default: ROT); contacts go to the nearest surface point")
    g.add_argument("--quantile", type=_fraction, default=0.1, metavar="Q",
                   help="the low quantile of q_low and margin_low")
    g.add_argument("--robust-seed", type=_int(0, "an integer >= 0"), default=None, metavar="SEED",
                   help="seed of the perturbations (default: --seed, or 0)")
    g.add_argument("--no-margin", action="store_true",
                   help="leave out the min-weight margin columns (margin_*)")


def _range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two comma-separated multipliers like 0.8,1.2; got {text!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise argparse.ArgumentTypeError(f"expected multipliers 0 < LO <= HI; got {text!r}")
    return lo, hi


def _pose(text: str) -> tuple[float, float]:
    try:
        values = [float(v) for v in text.replace(" ", "").split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected ROT or ROT,TRANS (numbers >= 0); got {text!r}") from None
    if len(values) not in (1, 2) or not all(math.isfinite(v) and v >= 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected ROT or ROT,TRANS (numbers >= 0); got {text!r}")
    return values[0], values[-1]


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1]; got {text!r}") from None
    if not (0 <= value <= 1):
        raise argparse.ArgumentTypeError(f"expected a number in [0, 1]; got {text!r}")
    return value


def _noise_given(args) -> list[str]:
    """The noise flags set on the command line."""
    return [flag for flag, value in (("--sigma-pos", args.sigma_pos), ("--sigma-normal", args.sigma_normal),
                                     ("--mu-range", args.mu_range), ("--mu-sigma", args.mu_sigma),
                                     ("--sigma-pose", args.sigma_pose)) if value]


def _robust_settings(args, obj=None):
    """The :class:`grasp_jax.pipeline.RobustLabels` of --robust and the noise flags (``None``
    without --robust). Checked before any work: call it once without ``obj`` first."""
    given = _noise_given(args)
    if args.robust is None:
        extra = given + [f for f, v in (("--no-margin", args.no_margin), ("--robust-seed", args.robust_seed),
                                        ("--quantile", args.quantile != 0.1)) if v]
        if extra:
            raise ValueError(f"{extra[0]} sets the robust labels: add --robust N (perturbations per grasp)")
        return None
    if not given:
        raise ValueError("--robust N needs noise: --sigma-pos, --sigma-normal, --mu-range, --mu-sigma or --sigma-pose")
    from ._robust import Noise
    from .pipeline import RobustLabels

    rot, trans = args.sigma_pose or (0.0, 0.0)
    noise = Noise(position=args.sigma_pos, normal=args.sigma_normal, friction=args.mu_range or (1.0, 1.0),
                  friction_sigma=args.mu_sigma, rotation=rot, translation=trans)
    seed = args.robust_seed if args.robust_seed is not None else getattr(args, "seed", 0)
    return RobustLabels(noise, samples=args.robust, seed=seed, quantile=args.quantile, margin=not args.no_margin,
                        obj=obj)


def _add_contact(g, default_note: str = "") -> None:
    g.add_argument("--contact", choices=("hard", "soft", "dexnet-soft"), default=None,
                   help="contact model: 'hard' point contacts with friction (the paper's), 'soft' fingers "
                        "(a moment about the normal up to TORSION x the normal force; two soft contacts can "
                        "hold a grasp), or 'dexnet-soft' (Dex-Net's soft-finger columns, to reproduce its "
                        "labels); 3D only" + (default_note or " (default: hard)"))
    g.add_argument("--torsion", type=_nonnegative_float, default=None, metavar="L",
                   help="torsional coefficient of soft contacts, a length in the object's units ('soft': "
                        "the largest moment per unit normal force; 'dexnet-soft': Dex-Net's pi r^2 mu)")
    g.add_argument("--patch-radius", type=_positive_float, default=None, metavar="R",
                   help="instead of --torsion: the contact patch radius, torsion = (2/3) mu R ('soft', a "
                        "uniformly pressed disc) or pi R^2 mu ('dexnet-soft', R its finger_radius)")


def _contact_settings(args, mu, meta: dict | None = None) -> tuple[str | None, float | None]:
    """``(contact, torsion)`` from --contact, --torsion and --patch-radius (``None``: the file's
    metadata, else hard contacts, where ``meta`` is given)."""
    from ._contact import dexnet_torsion, patch_torsion

    contact = args.contact
    if args.torsion is not None and args.patch_radius is not None:
        raise ValueError("give --torsion or --patch-radius, not both")
    if contact is None and (args.torsion is not None or args.patch_radius is not None):
        raise ValueError("--torsion and --patch-radius set the torsion of soft contacts: add --contact soft "
                         "(or dexnet-soft)")
    if contact is None:
        if meta is None or "contact" not in meta:
            return (None if meta is not None else "hard"), None
        return meta["contact"], meta.get("torsion")
    if contact == "hard":
        return contact, None
    if args.patch_radius is not None:
        helper = patch_torsion if contact == "soft" else dexnet_torsion
        return contact, float(helper(args.patch_radius, mu))
    if args.torsion is None:
        raise ValueError(f"--contact {contact} needs --torsion L or --patch-radius R")
    return contact, args.torsion


def _nonnegative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0; got {text!r}") from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected a finite number >= 0; got {text!r}")
    return value


def _add_sampling(p: argparse.ArgumentParser, *, num: int) -> None:
    g = p.add_argument_group("sampling")
    g.add_argument("--fingers", type=_int(2, "an integer >= 2"), default=4, help="contacts per grasp")
    g.add_argument("--num", type=_count, default=num, help="grasps to sample and score (1e6 is fine)")
    g.add_argument("--seed", type=_int(0, "an integer >= 0"), default=0, help="random seed")
    g.add_argument("--scheme", choices=("uniform", "paper"), default="uniform",
                   help="'uniform': all contacts uniform on the surface; 'paper': a fixed first contact "
                        "and random others, as in the paper's experiments")
    g.add_argument("--first-contact", type=_int(0, "a facet index >= 0"), default=None, metavar="F",
                   help="with --scheme paper: the facet of the first contact (default: drawn from --seed)")


def _add_critical(g) -> None:
    g.add_argument("--critical-friction", action=argparse.BooleanOptionalAction, default=None,
                   help="also the smallest friction coefficient at which each grasp is force-closure "
                        "(columns critical_mu, critical_status, friction_label: GraspNet-1Billion's "
                        "0.2..1.2 label; about 1/10 of the throughput for two soft contacts, 1/16 for four "
                        "hard ones) (default: on with --gripper, else off)")


def _add_gripper(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("gripper (grasp_jax.grippers)")
    g.add_argument("--gripper", choices=("parallel-jaw",), default=None,
                   help="sample antipodal parallel-jaw grasps (2 contacts where the jaws' closing line meets a "
                        "mesh) and write their poses: center, axis, approach, width, jaw_status; scored as soft "
                        "contacts (default --patch-radius: max width / 20)")
    g.add_argument("--max-width", type=_positive_float, default=None, metavar="W",
                   help="the gripper's largest opening, in the object's units (required with --gripper)")
    g.add_argument("--min-width", type=_nonnegative_float, default=None, metavar="W",
                   help="the gripper's smallest opening (default 0)")
    g.add_argument("--collision", action="store_true",
                   help="reject grasps whose gripper body (two finger boxes and a palm) intersects the object "
                        "(jaw_status COLLISION; needs python-fcl)")
    g.add_argument("--finger-size", type=_lengths, default=None, metavar="T,B,L",
                   help="finger box thickness, breadth and length for --collision (default W/8, W/4, 0.6 W)")
    g.add_argument("--palm-size", type=_lengths, default=None, metavar="S,B,D",
                   help="palm box span, breadth and depth for --collision (default 1.25 W, W/4, W/4)")


def _lengths(text: str) -> tuple[float, float, float]:
    try:
        values = tuple(float(v) for v in text.replace(" ", "").split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected three comma-separated lengths like 0.01,0.02,0.05; got {text!r}") from None
    if len(values) != 3 or not all(math.isfinite(v) and v > 0 for v in values):
        raise argparse.ArgumentTypeError(f"expected three comma-separated lengths > 0; got {text!r}")
    return values


def _jaw_settings(args) -> tuple[dict, str | None, float | None]:
    """``(run keywords, contact, torsion)`` of ``sample --gripper`` (``({}, ...)`` without it)."""
    given = [f for f, v in (("--max-width", args.max_width), ("--min-width", args.min_width),
                            ("--collision", args.collision), ("--finger-size", args.finger_size),
                            ("--palm-size", args.palm_size)) if v not in (None, False)]
    if args.gripper is None:
        if given:
            raise ValueError(f"{given[0]} describes a gripper: add --gripper parallel-jaw")
        return {}, *_contact_settings(args, args.mu)
    from .grippers import ParallelJaw

    if args.max_width is None:
        raise ValueError("--gripper parallel-jaw needs --max-width W (the largest opening, in the object's units)")
    if args.fingers not in (2, 4) or args.scheme != "uniform" or args.first_contact is not None:
        raise ValueError("--gripper parallel-jaw grasps have 2 contacts, sampled antipodally: leave out --fingers, "
                         "--scheme and --first-contact")
    args.fingers = 2
    min_width = 0.0 if args.min_width is None else args.min_width
    if min_width >= args.max_width:
        raise ValueError(f"--min-width {min_width} must be smaller than --max-width {args.max_width}")
    body = ParallelJaw.scaled(args.max_width, min_width)
    finger = args.finger_size or (body.finger_size if args.collision else None)
    palm = args.palm_size or (body.palm_size if args.collision else None)
    if palm is not None and finger is None:
        raise ValueError("--palm-size needs --collision or --finger-size")
    gripper = ParallelJaw(args.max_width, min_width, finger_size=finger, palm_size=palm)
    if args.collision:
        from .grippers._contacts import require_collision_support

        try:
            require_collision_support()
        except ImportError as e:
            raise ValueError(str(e)) from None
    if args.contact is None:
        args.contact = "soft"
        if args.torsion is None and args.patch_radius is None:
            args.patch_radius = args.max_width / 20
    contact, torsion = _contact_settings(args, args.mu)
    return {"gripper": gripper, "collision": bool(args.collision)}, contact, torsion


def _add_hole(p: argparse.ArgumentParser, *, from_file: bool = False) -> None:
    p.add_argument("--hole", type=Path, action="append", default=None, metavar="FILE.csv",
                   help="a hole of a polygon OBJECT (.csv): a CSV of x,y rows; repeat for several holes"
                        + (" (default: the file's metadata)" if from_file else ""))


def _add_plot(p: argparse.ArgumentParser, default_help: str | None = None,
              help_text: str = "draw the best force-closure grasps on the object") -> None:
    g = p.add_argument_group("figure")
    g.add_argument("--plot", type=Path, default=None, metavar="FILE.png",
                   help=help_text + (f" ({default_help})" if default_help else ""))
    g.add_argument("--top", type=_int(1, "an integer >= 1"), default=4, metavar="K",
                   help="how many of the best grasps to draw and list")


def _add_optimize(sub, builtins: str) -> None:
    from ._objectives import OBJECTIVES
    from ._optimize import DEFAULT_LEARNING_RATE, REFINE_LEARNING_RATE

    p = sub.add_parser(
        "optimize", help="move contacts over the surface by gradient to make grasps better",
        description="Optimize --starts grasps of OBJECT by gradient (grasp_jax.optimize): every start moves\n"
                    "its contacts over the surface for --steps steps; the best iterate of each is scored\n"
                    "exactly (force-closure, Q), written to --out and summarized. Starts are random, or the\n"
                    "best grasps of a file written by 'grasp-jax sample' (--from: sample, then refine).",
        epilog=_epilog(builtins), formatter_class=_Formatter)
    p.add_argument("object", metavar="OBJECT", nargs="?", default=None,
                   help="built-in name or mesh / polygon CSV file (default: the --from file's object)")
    _add_hole(p)
    g = p.add_argument_group("optimization")
    g.add_argument("--fingers", type=_int(2, "an integer >= 2"), default=None,
                   help="contacts per grasp (default: the --from file's, else 4)")
    g.add_argument("--starts", type=_count, default=1024,
                   help="grasps optimized together (random starts; with --from, its best STARTS grasps)")
    g.add_argument("--steps", type=_count, default=200, help="optimizer steps")
    g.add_argument("--seed", type=_int(0, "an integer >= 0"), default=0,
                   help="random seed of the starts (and of the figure's random grasps)")
    g.add_argument("--objective", choices=OBJECTIVES, default="closure",
                   help="what is maximized: 'closure' = min(signed Q, 4 x torque margin), positive exactly "
                        "at force-closure; 'closure_any' the same for every choice of c_1; 'min_weight' the "
                        "classical margin; 'signed_q'; 'dfc', 'dfc_eig' the DFC energies (baselines)")
    g.add_argument("--lr", type=_positive_float, default=None,
                   help=f"peak learning rate of Adam (cosine decay), in object radii per step (default "
                        f"{DEFAULT_LEARNING_RATE} from random starts, {REFINE_LEARNING_RATE} with --from)")
    g.add_argument("--normals", choices=("smooth", "flat"), default="smooth",
                   help="normals of meshes and polygons while optimizing: interpolated ('smooth', sharp "
                        "edges kept) or face normals ('flat'); analytic shapes use exact normals")
    g.add_argument("--from", dest="from_file", type=Path, default=None, metavar="FILE",
                   help="start from the best --starts grasps (by force-closure, then Q; all if fewer) of "
                        "FILE, a result of 'grasp-jax sample' (.npz or .parquet)")
    s = p.add_argument_group("scoring")
    s.add_argument("--mu", type=_positive_float, default=None,
                   help=f"friction coefficient (default: the --from file's, else {DEFAULT_MU})")
    s.add_argument("--edges", type=_int(3, "an integer >= 3"), default=None,
                   help="edges of each linearized 3D friction cone (default: the --from file's, else 8)")
    _add_contact(s, " (default: the --from file's, else hard)")
    o = p.add_argument_group("output and performance")
    o.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="write every start's final grasp, scores, objective history and end reason to FILE "
                        "(.npz or .parquet), atomically")
    o.add_argument("--devices", type=_int(1, "an integer >= 1"), default=None, metavar="N",
                   help="CPU devices to split the cores into (default: one per core; ignored if XLA_FLAGS "
                        "already sets it)")
    o.add_argument("--json", action="store_true", help="print the summary as one JSON line")
    o.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    _add_plot(p, help_text="draw Q against step (median and best over starts, beside as many random grasps) "
                           "and the best distinct grasps on the object")
    p.set_defaults(func=_cmd_optimize, distributed=False)


def _add_dataset(sub) -> None:
    p = sub.add_parser(
        "dataset", help="sample and score grasps of many objects into one Parquet dataset (resumable, sharded)",
        description="Sample and score --num grasps of every object of OBJECTS (a folder of mesh files, or a "
                    "manifest: one mesh path or built-in name per line, optionally followed by a scale) with one "
                    "configuration, optionally with robust labels, into DIR/object=<name>/part.parquet (a "
                    "hive-partitioned Parquet dataset) and DIR/_manifest.json. Run it again to resume; --shard i/N "
                    "(or a SLURM array) splits the objects over processes.",
        formatter_class=_Formatter)
    p.add_argument("objects", metavar="OBJECTS", type=Path, help="folder of mesh files, or a manifest text file")
    p.add_argument("--out", type=Path, required=True, metavar="DIR", help="the dataset folder (created or resumed)")
    p.add_argument("--shard", default=None, metavar="i/N",
                   help="do objects i, i+N, i+2N, ... of the sorted list (default: SLURM_ARRAY_TASK_ID / "
                        "SLURM_ARRAY_TASK_COUNT in a SLURM array, else all)")
    _add_sampling(p, num=10_000)
    g = p.add_argument_group("scoring")
    g.add_argument("--mu", type=_positive_float, default=DEFAULT_MU, help="friction coefficient tan(alpha)")
    g.add_argument("--edges", type=_int(3, "an integer >= 3"), default=8, help="edges of each friction cone")
    g.add_argument("--torque-test", choices=("exact", "paper"), default="exact", help="the torque test")
    _add_contact(g)
    _add_critical(g)
    _add_gripper(p)
    _add_robust(p)
    o = p.add_argument_group("performance and output")
    o.add_argument("--chunk", type=_count, default=None, metavar="N", help="grasps per chunk (default 65536 on a CPU)")
    o.add_argument("--devices", type=_int(1, "an integer >= 1"), default=None, metavar="N",
                   help="CPU devices to split the cores into (default: one per core)")
    o.add_argument("--json", action="store_true", help="print the summary as one JSON line")
    o.add_argument("-q", "--quiet", action="store_true", help="no progress bar and no summary")
    p.set_defaults(func=_cmd_dataset, distributed=False)


def build_parser() -> argparse.ArgumentParser:
    try:
        from .objects import BUILTIN_NAMES

        builtins = ", ".join(BUILTIN_NAMES)
    except Exception:  # noqa: BLE001 - help must work even if objects cannot be imported
        builtins = "glass, part, quad, star, sphere, box, cylinder, ellipsoid"
    parser = _Parser(prog=PROG, description=_DESCRIPTION, epilog=_epilog(builtins),
                     formatter_class=_Formatter)
    from . import __version__

    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    p = sub.add_parser("sample", help="sample random grasps of an object and score them",
                       description="Sample NUM random grasps of OBJECT, score each (force-closure, Q), "
                                   "stream them to --out and print a summary.",
                       epilog=_epilog(builtins), formatter_class=_Formatter)
    p.add_argument("object", metavar="OBJECT", help="built-in name or mesh / polygon CSV file")
    _add_hole(p)
    _add_sampling(p, num=10_000)
    _add_scoring(p, from_file=False)
    _add_gripper(p)
    _add_plot(p)
    p.set_defaults(func=_cmd_sample)

    p = sub.add_parser("score", help="score grasps stored in a .npz or .parquet file",
                       description="Score the grasps (arrays 'points' and 'normals', shape (N, n, d)) "
                                   "of FILE, print a summary and optionally write the scores to --out.",
                       formatter_class=_Formatter)
    p.add_argument("file", metavar="FILE", type=Path, help=".npz or .parquet file with points and normals")
    p.add_argument("--object", default=None,
                   help="the object the grasps are on, for --epsilon and --plot (default: the file's metadata)")
    _add_hole(p, from_file=True)
    _add_scoring(p, from_file=True)
    _add_plot(p)
    p.set_defaults(func=_cmd_score)

    p = sub.add_parser("show", help="draw the best grasps of a result file on their object",
                       description="Draw the --top best force-closure grasps of a result FILE on their "
                                   "object and list them.", formatter_class=_Formatter)
    p.add_argument("file", metavar="FILE", type=Path, help="result file (.npz or .parquet) with quality")
    p.add_argument("--object", default=None, help="the object (default: the file's metadata)")
    _add_hole(p, from_file=True)
    _add_plot(p, default_help="default: FILE with suffix .png, unless --html is given")
    p.add_argument("--html", type=Path, default=None, metavar="PAGE.html",
                   help="write an interactive, self-contained page of the --top best grasps (opens offline; "
                        "grasp_jax.interactive.result_page)")
    p.set_defaults(func=_cmd_show)

    _add_optimize(sub, builtins)
    _add_dataset(sub)

    p = sub.add_parser("demo", help=f"the default run: {DEMO_NUM:,} 4-finger grasps of the {DEMO_OBJECT}",
                       description="Sample and score random grasps of a built-in object and print what was "
                                   "found (about half a minute on two CPU cores).",
                       formatter_class=_Formatter)
    p.add_argument("object", metavar="OBJECT", nargs="?", default=DEMO_OBJECT,
                   help="built-in name or mesh / polygon CSV file")
    _add_hole(p)
    _add_sampling(p, num=DEMO_NUM)
    _add_scoring(p, from_file=False)
    _add_plot(p)
    p.set_defaults(func=_cmd_demo)
    return parser


# ---------------------------------------------------------------------------------------------
# Helpers


def _say(args, text: str = "") -> None:
    if not args.quiet and not getattr(args, "json", False):
        print(text, flush=True)


def _warn(text: str) -> None:
    print(f"{PROG}: warning: {text}", file=sys.stderr, flush=True)


def _check_plot_path(path: Path | None) -> Path | None:
    from . import storage

    return None if path is None else storage.check_output_path(path, suffixes=PLOT_SUFFIXES, what="figure")


def _setup(args) -> None:
    """Devices and processes, before JAX starts its backend. (Compiled programs are kept by the
    library's own cache, ``grasp_jax._cache``; JAX's persistent cache stays off: see there.)"""
    from . import devices

    devices.configure_cpu_devices(args.devices)
    if args.distributed or devices.distributed_requested():
        devices.initialize_distributed(force=True)
        args.distributed = True


def _load_object(spec: str, holes=()):
    from . import objects

    obj = objects.load(spec, holes=holes or ())
    for w in getattr(obj, "warnings", ()) or ():
        _warn(w)
    return obj


def _holes(args, meta) -> list:
    """--hole, else the holes stored with the file's object (unless --object names another)."""
    if args.hole:
        return args.hole
    if args.object is not None and args.object != meta.get("object"):
        return []
    return list(meta.get("object_holes") or ())


def plot_best(obj, best, *, mu: float, num_edges: int, path: Path, title: str | None = None) -> Path:
    """Draw the grasps of a :class:`grasp_jax.summary.BestGrasps` on ``obj`` in one figure (atomic)."""
    import numpy as np

    from . import plotting

    plt = plotting._pyplot()  # noqa: SLF001 - the Agg backend, as the plotting module uses
    k = len(best)
    cols = k if k <= 3 else math.ceil(math.sqrt(k))
    rows = -(-k // cols)
    height = 4.2
    if obj.dim == 2 and hasattr(obj, "rings"):  # equal-aspect panels of a long, flat polygon
        w, h = np.ptp(np.concatenate(obj.rings), axis=0)  # would leave rows of white space
        if w > 0:
            height = float(np.clip(4.2 * h / w + 0.8, 2.0, 4.2))
    fig = plt.figure(figsize=(4.2 * cols, height * rows), dpi=100)
    try:
        for i in range(k):
            label = f"#{int(best.index[i])}"
            if obj.dim == 2:
                ax = fig.add_subplot(rows, cols, i + 1)
                plotting.plot_grasp_2d(_rings(obj), best.points[i], best.normals[i], mu=mu,
                                       quality=float(best.quality[i]), ax=ax, title=label)
            else:
                ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
                plotting.plot_grasp_3d(_mesh(obj), best.points[i], best.normals[i], mu=mu, num_edges=num_edges,
                                       quality=float(best.quality[i]), ax=ax, title=label)
        if title:
            fig.suptitle(title, fontsize=11)
        fig.tight_layout()
        _save_figure(fig, path)
    finally:
        plt.close(fig)
    return path


def _save_figure(fig, path: Path) -> None:
    """Write ``fig`` to ``path`` atomically (a temporary file renamed into place)."""
    from . import storage

    storage.write_atomically(path, lambda f: fig.savefig(f, format=path.suffix.lower()[1:], dpi=fig.dpi,
                                                         bbox_inches="tight"), mode="wb", what="figure")


def _rings(obj):
    """What plot_grasp_2d draws for a planar object."""
    for attr in ("rings", "polygon", "vertices"):
        if hasattr(obj, attr):
            return obj if attr == "rings" else getattr(obj, attr)
    raise ValueError(f"cannot draw object {obj.name!r}: it has no polygon rings")


def _mesh(obj):
    """What plot_grasp_3d draws for a 3D object."""
    if hasattr(obj, "mesh") or (hasattr(obj, "vertices") and hasattr(obj, "faces")):
        return obj
    raise ValueError(f"cannot draw object {obj.name!r}: it has no mesh")


def _report(args, summary, best_lines: int = 0) -> None:
    from . import summary as _summary

    if args.quiet:
        return
    if args.json:
        print(_summary.summary_json(summary), flush=True)
        return
    print(summary.format(best=max(best_lines, 1)), flush=True)


def _plot_summary(args, obj, summary, mu, edges) -> None:
    if args.plot is None:
        return
    if summary.best is None or not len(summary.best):
        _warn(f"no force-closure grasp: nothing drawn to {args.plot}")
        return
    from .summary import BestGrasps

    best = BestGrasps(*(a[: args.top] for a in (summary.best.index, summary.best.points,
                                                 summary.best.normals, summary.best.quality)))
    plot_best(obj, best, mu=mu, num_edges=edges, path=args.plot,
              title=f"{obj.name}: best {len(best)} of {summary.num:,} grasps")
    _say(args, f"figure         {args.plot}")


# ---------------------------------------------------------------------------------------------
# Commands


def _cmd_sample(args) -> int:
    from . import pipeline, storage

    if args.out is not None:
        storage.check_output_path(args.out)
    _check_plot_path(args.plot)
    jaw, contact, torsion = _jaw_settings(args) if hasattr(args, "gripper") else ({}, *_contact_settings(args, args.mu))
    _robust_settings(args)
    _setup(args)
    obj = _load_object(args.object, args.hole)
    summary = pipeline.run(
        obj, args.num, args.fingers, mu=args.mu, num_edges=args.edges, seed=args.seed, scheme=args.scheme,
        torque_test=args.torque_test, chunk=args.chunk, epsilon=args.epsilon, origin=args.origin,
        torque_scale=args.torque_scale, out=args.out, progress=not args.quiet, top=max(args.top, 5),
        distributed=args.distributed, object_spec=args.object, first_contact=args.first_contact,
        object_holes=args.hole, contact=contact, torsion=torsion, critical=args.critical_friction,
        robust=_robust_settings(args, obj),
        **jaw,
    )
    _report(args, summary, best_lines=5)
    _plot_summary(args, obj, summary, args.mu, args.edges)
    return 0


def _cmd_demo(args) -> int:
    code = _cmd_sample(args)
    if not args.quiet and not args.json:
        print()
        print("next: grasp-jax sample glass --num 1e6 --out glass.parquet --plot glass.png   "
              "(see grasp-jax --help)")
    return code


def _cmd_score(args) -> int:
    from . import pipeline, storage

    storage.check_input_path(args.file)
    if args.out is not None:
        storage.check_output_path(args.out)
        if args.out.resolve() == args.file.resolve():
            raise ValueError("--out must differ from the input file")
    _check_plot_path(args.plot)
    robust = _robust_settings(args)
    _setup(args)
    meta = storage.read_metadata(args.file)
    obj = None
    spec = args.object or meta.get("object")
    need_obj = (args.epsilon and (args.origin is None or args.torque_scale is None)) or args.plot is not None
    need_obj = need_obj or (robust is not None and robust.noise.moves_contacts)
    if need_obj:
        if spec is None:
            raise ValueError("the file names no object: pass --object (needed for --epsilon, --plot and noise that "
                             "moves contacts)")
        obj = _load_object(spec, _holes(args, meta))
    contact, torsion = _contact_settings(args, args.mu if args.mu is not None else meta.get("mu", DEFAULT_MU), {})
    summary = pipeline.score_file(
        args.file, mu=args.mu, num_edges=args.edges, torque_test=args.torque_test, chunk=args.chunk,
        epsilon=args.epsilon, origin=args.origin, torque_scale=args.torque_scale, obj=obj, out=args.out,
        progress=not args.quiet, top=max(args.top, 5), contact=contact, torsion=torsion,
        critical=bool(args.critical_friction), robust=_robust_settings(args, obj),
    )
    _report(args, summary, best_lines=5)
    if obj is not None:
        _plot_summary(args, obj, summary, summary.metadata["mu"], summary.metadata["edges"])
    return 0


def _cmd_show(args) -> int:
    from . import storage, summary

    storage.check_input_path(args.file)
    page = None if args.html is None else storage.check_output_path(args.html, suffixes=(".html", ".htm"),
                                                                     what="page")
    plot = args.plot if args.plot is not None or page is not None else args.file.with_suffix(".png")
    _check_plot_path(plot)
    best, meta = summary.best_in_file(args.file, args.top)
    spec = args.object or meta.get("object")
    if spec is None:
        raise ValueError(f"{str(args.file)!r} names no object: pass --object")
    obj = _load_object(spec, _holes(args, meta))
    if page is not None:
        from . import interactive

        interactive.result_page(args.file, page, top=args.top, obj=obj)
    if best is None or not len(best):
        print(f"{PROG}: no force-closure grasp in {args.file}: nothing to draw"
              + (f" but the best tries, on page {page}" if page is not None else ""), file=sys.stderr)
        return 1 if page is None else 0
    if best.points.shape[-1] != obj.dim:
        raise ValueError(f"the grasps are {best.points.shape[-1]}D but object {obj.name!r} is {obj.dim}D")
    mu = float(meta.get("mu", DEFAULT_MU))
    edges = int(meta.get("edges", 8))
    if plot is not None:
        plot_best(obj, best, mu=mu, num_edges=edges, path=plot,
                  title=f"{obj.name}: best {len(best)} grasps of {args.file.name}")
        robust_plot = plot_robust(args.file, plot.with_name(plot.stem + ".robust" + plot.suffix))
    print("rank  grasp        Q")
    for r, (i, q) in enumerate(zip(best.index, best.quality), 1):
        print(f"{r:4d}  {int(i):9d}  {q:.4f}")
    if plot is not None:
        print(f"figure {plot}")
        if robust_plot is not None:
            print(f"figure {robust_plot} (nominal Q against P(force-closure))")
    if page is not None:
        print(f"page   {page}")
    return 0


#: Most grasps drawn in the scatter of :func:`plot_robust` (a seeded random subset beyond).
ROBUST_SCATTER = 20000


def plot_robust(file: Path, path: Path) -> Path | None:
    """Nominal Q against P(force-closure) of a result file with robust labels (``--robust N``:
    column ``p_fc``), and the histogram of P(force-closure) of the nominally force-closure grasps
    and of the others, in one figure (atomic); ``None`` where the file has no ``p_fc``."""
    import numpy as np

    from . import plotting, storage

    src = storage.ResultFile(file)
    if "p_fc" not in src.fields:
        return None
    parts = list(src.iter_chunks(("quality", "force_closure", "p_fc")))
    q, fc, p = (np.concatenate([c[k] for c in parts]) for k in ("quality", "force_closure", "p_fc"))
    fc = fc.astype(bool)
    meta = storage.read_metadata(file)
    shown = np.arange(len(q))
    if len(q) > ROBUST_SCATTER:
        shown = np.sort(np.random.default_rng(0).choice(len(q), ROBUST_SCATTER, replace=False))
    plt = plotting._pyplot()  # noqa: SLF001
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4.2), dpi=100)
    try:
        a.scatter(q[shown], p[shown], s=4, alpha=0.35, c=np.where(fc[shown], "tab:blue", "tab:gray"), linewidths=0)
        a.set_xlabel("nominal Q")
        a.set_ylabel("P(force-closure) under noise")
        a.set_ylim(-0.03, 1.03)
        a.set_title(f"{len(shown):,} of {len(q):,} grasps (blue: nominally force-closure)", fontsize=9)
        bins = np.linspace(0, 1, 21)
        b.hist([p[fc], p[~fc]], bins=bins, label=[f"force-closure ({fc.sum():,})", f"not ({(~fc).sum():,})"],
               color=["tab:blue", "tab:gray"], stacked=True)
        b.set_xlabel("P(force-closure) under noise")
        b.set_ylabel("grasps")
        b.legend(fontsize=8)
        robust = meta.get("robust", {})
        noise = robust.get("noise", {})
        noise = (", ".join(f"{k} {v}" for k, v in noise.items() if v and v != [1.0, 1.0]) or "none"
                 if isinstance(noise, dict) else str(noise))
        fig.suptitle(f"{file.name}: robust labels, {robust.get('samples', '?')} perturbations ({noise})",
                     fontsize=10)
        fig.tight_layout()
        _save_figure(fig, path)
    finally:
        plt.close(fig)
    return path


#: Most random grasps drawn beside the optimization curves of ``optimize --plot``.
MAX_SAMPLED = 1 << 18


def _cmd_dataset(args) -> int:
    from . import dataset

    if args.first_contact is not None or args.scheme != "uniform":
        raise ValueError("a dataset samples every object uniformly: leave out --scheme and --first-contact")
    shard = dataset.parse_shard(args.shard) if args.shard is not None else dataset.shard_from_environment()
    jaw, contact, torsion = _jaw_settings(args)
    robust = _robust_settings(args)
    dataset.list_objects(args.objects)  # an empty folder or a bad manifest: before JAX starts
    _setup(args)
    summary = dataset.build(
        args.objects, args.out, num=args.num, fingers=args.fingers, mu=args.mu, num_edges=args.edges, seed=args.seed,
        torque_test=args.torque_test, contact=contact, torsion=torsion, robust=robust, chunk=args.chunk,
        shard=shard, progress=not args.quiet, critical=args.critical_friction, **jaw,
    )
    for name, reason in summary.failed.items():
        _warn(f"{name}: failed: {reason}")
    figure = dataset.plot_summary(summary.out)
    if args.json:
        from .summary import summary_json

        print(summary_json({"out": str(summary.out), "shard": list(summary.shard), "done": summary.done,
                            "skipped": summary.skipped, "failed": summary.failed, "seconds": summary.seconds,
                            "objects": summary.rows}), flush=True)
    elif not args.quiet:
        print(summary.format(), flush=True)
        if figure is not None:
            print(f"figure         {figure} (every object done so far, all shards)", flush=True)
    return 0


def _same_object(spec: str, stored: str, meta: dict) -> bool:
    """Whether OBJECT names the object a file's metadata names."""
    if spec in (stored, meta.get("object_name")):
        return True
    try:
        return os.path.exists(spec) and os.path.exists(stored) and os.path.samefile(spec, stored)
    except OSError:
        return False


def _cmd_optimize(args) -> int:
    from . import storage, summary

    if args.out is not None:
        storage.check_output_path(args.out)
    _check_plot_path(args.plot)
    meta_in, src = {}, None
    if args.from_file is not None:
        storage.check_input_path(args.from_file, what="--from file")
        if args.out is not None and args.out.resolve() == args.from_file.resolve():
            raise ValueError("--out must differ from the --from file")
        src = storage.ResultFile(args.from_file)
        meta_in = dict(src.metadata)
        if args.fingers is not None and args.fingers != src.fingers:
            raise ValueError(f"--from file {str(args.from_file)!r} holds {src.fingers}-finger grasps, "
                             f"not {args.fingers} (--fingers)")
        stored = meta_in.get("object")
        if args.object is not None and stored is not None and not _same_object(args.object, stored, meta_in):
            raise ValueError(f"--from file {str(args.from_file)!r} holds grasps of {stored!r}, not of "
                             f"{args.object!r}: omit OBJECT to use the file's")
        if args.object is None:
            args.object = stored
    if args.object is None:
        raise ValueError(f"--from file {str(args.from_file)!r} names no object: give OBJECT" if src is not None
                         else "no OBJECT: name a built-in object or a mesh / polygon file (or --from FILE)")
    fingers = args.fingers if args.fingers is not None else (src.fingers if src is not None else 4)
    mu = args.mu if args.mu is not None else float(meta_in.get("mu", DEFAULT_MU))
    edges = args.edges if args.edges is not None else int(meta_in.get("edges", 8))
    contact, torsion = _contact_settings(args, mu, meta_in)
    contact = contact or "hard"
    args.contact_model = (contact, torsion)
    _setup(args)
    stored = meta_in.get("object")
    same = stored is not None and _same_object(args.object, stored, meta_in)
    holes = args.hole or (list(meta_in.get("object_holes") or ()) if same else [])
    obj = _load_object(args.object, holes)
    init, starts = None, args.starts
    if src is not None:
        if src.dim != obj.dim:
            raise ValueError(f"--from file {str(args.from_file)!r} holds {src.dim}D grasps but object "
                             f"{obj.name!r} is {obj.dim}D")
        best_in, _ = summary.best_starts(args.from_file, args.starts)
        init, starts = (best_in.points, best_in.normals), len(best_in)
    result = _optimize(args, obj, fingers=fingers, starts=starts, mu=mu, edges=edges, init=init)
    meta = storage.metadata(
        command="optimize",
        object=storage.object_spec(obj, args.object),
        object_name=str(obj.name),
        dim=int(obj.dim),
        mu=float(mu),
        edges=int(edges),
        fingers=int(fingers),
        seed=int(args.seed),
        num=int(starts),
        torque_test="exact",
        **({"contact": contact} if contact == "hard" else {"contact": contact, "torsion": float(torsion)}),
        objective=args.objective,
        steps=int(args.steps),
        learning_rate=float(result.learning_rate),
        normals=result.normal_kind,
        init="random" if src is None else str(args.from_file.resolve()),
        seconds=round(float(result.seconds), 3),
    )
    if holes:
        meta["object_holes"] = [storage.object_spec(obj, h) for h in holes]
    path = _write_optimized(args.out, result, meta) if args.out is not None else None
    best = _distinct_best(result, max(args.top, 5))
    sampled = _sampled_quality(args, obj, fingers, mu, edges, starts) if args.plot is not None else None
    report = summary.optimize_summary(result, meta, best=best, output=path, sampled=sampled)
    if not args.quiet:
        print(summary.summary_json(report) if args.json else summary.format_optimize(report), flush=True)
    if args.plot is not None:
        _plot_optimization(args, obj, result, best, sampled, mu, edges)
        _say(args, f"figure         {args.plot}")
    return 0


def _optimize(args, obj, *, fingers, starts, mu, edges, init):
    import warnings

    import grasp_jax as gj

    try:
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
            return gj.optimize(obj, args.seed, fingers=fingers, mu=mu, starts=starts, steps=args.steps,
                               num_edges=edges, objective=args.objective, learning_rate=args.lr,
                               normals=args.normals, init=init, progress=not args.quiet,
                               contact=args.contact_model[0], torsion=args.contact_model[1])
    except (TypeError, NotImplementedError) as e:  # an object kind the optimizer cannot move contacts on
        raise ValueError(f"cannot optimize grasps of {obj.name!r}: {e}") from None


def _write_optimized(path: Path, result, meta: dict) -> Path:
    """The optimize result file: the fields of ``sample`` plus the per-start history, atomically."""
    import numpy as np

    from . import storage

    ev = result.evaluation
    batch = {
        "points": np.asarray(result.points, float),
        "normals": np.asarray(result.normals, float),
        "force_closure": np.asarray(ev.force_closure, bool),
        "quality": np.asarray(ev.quality, float),
        "converged": np.asarray(ev.converged, bool),
        "initial_points": np.asarray(result.initial_points, float),
        "objective": np.asarray(result.objective, float),
        "reason": np.asarray(result.reason, np.int8),
        "history": np.asarray(result.history, float),
    }
    if result.quality_history is not None:
        batch["quality_history"] = np.asarray(result.quality_history, float)
    if result.path is not None:
        batch["path"] = np.asarray(result.path, float)
    fields = [*storage.RESULT_FIELDS, *(f for f in batch if f not in storage.RESULT_FIELDS)]
    with storage.open_writer(path, meta, fields, fingers=batch["points"].shape[1], dim=batch["points"].shape[2],
                             steps=batch["history"].shape[1],
                             frames=batch["path"].shape[1] if "path" in batch else None) as w:
        w.write(batch)
    return w.path


def _distinct_best(result, k: int):
    """The ``k`` best distinct force-closure grasps of an optimization, as :class:`BestGrasps`."""
    import numpy as np

    from .summary import BestGrasps

    index = np.asarray(result.distinct(), np.int64)[:k]
    return BestGrasps(index, np.asarray(result.points, float)[index], np.asarray(result.normals, float)[index],
                      np.asarray(result.quality, float)[index])


def _sampled_quality(args, obj, fingers, mu, edges, starts):
    """Q (0 where not force-closure) of as many random grasps as starts x steps (at most
    :data:`MAX_SAMPLED`), for the figure."""
    import warnings

    import numpy as np

    import grasp_jax as gj

    from . import sampling

    num = int(min(starts * args.steps, MAX_SAMPLED))
    points, normals = sampling.sample_grasps(obj, num, fingers, seed=args.seed)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*did not converge", category=RuntimeWarning)
        contact, torsion = getattr(args, "contact_model", ("hard", None))
        res = gj.evaluate(points, normals, mu=mu, num_edges=edges, contact=contact, torsion=torsion)
    return np.where(np.asarray(res.force_closure), np.asarray(res.quality, float), 0.0)


def _plot_optimization(args, obj, result, best, sampled, mu, edges) -> None:
    import numpy as np

    from . import plotting

    plt = plotting._pyplot()  # noqa: SLF001 - the Agg backend, as the plotting module uses
    if result.quality_history is not None:
        curves, ylabel = result.quality_history, "Q (0 while not force-closure)"
    else:
        curves, ylabel, sampled = result.history, f"objective {result.objective_name!r}", None
    grasps = [(best.points[i], best.normals[i], float(best.quality[i]), f"start #{int(best.index[i])}")
              for i in range(min(args.top, len(best)))]
    if not grasps:
        _warn("no force-closure grasp: only the curves are drawn")
    geometry = (_rings(obj) if obj.dim == 2 else _mesh(obj)) if grasps else None
    fc = float(np.mean(result.force_closure))
    title = (f"{obj.name}: {len(result.force_closure):,} starts x {result.steps} steps, objective "
             f"{result.objective_name!r}: {100 * fc:.0f}% force-closure")
    fig = plotting.plot_optimization(curves, sampled_quality=sampled, grasps=grasps, geometry=geometry, mu=mu,
                                     num_edges=edges, ylabel=ylabel, title=title)
    try:
        _save_figure(fig, args.plot)
    finally:
        plt.close(fig)


# ---------------------------------------------------------------------------------------------
# Entry point


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    if isinstance(exc, (FileNotFoundError, PermissionError, IsADirectoryError, NotADirectoryError)) and exc.filename:
        text = f"{exc.strerror or text}: {exc.filename!s}"
    return " ".join(text.split())


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that partial output is removed on the way out."""


def _on_sigterm(signum, frame):  # pragma: no cover - exercised through a subprocess
    raise _Terminated()


def main(argv=None) -> int:
    """Run the ``grasp-jax`` command line; returns the exit status."""
    import signal

    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    if not argv or (argv[0].startswith("-") and argv[0] not in ("-h", "--help", "--version")):
        argv = ["demo", *argv]  # "grasp-jax" and "grasp-jax --num 5000" run the demo
    try:
        if hasattr(signal, "SIGTERM") and _is_main_thread():
            signal.signal(signal.SIGTERM, _on_sigterm)
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except _UsageError as e:
            print(f"{PROG}: error: {e}", file=sys.stderr)
            return 2
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
    except _Terminated:
        print(f"{PROG}: terminated", file=sys.stderr)
        return 128 + signal.SIGTERM
    except _UsageError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except (ValueError, FileNotFoundError, IsADirectoryError, NotADirectoryError, PermissionError) as e:
        print(f"{PROG}: error: {_one_line(e)}", file=sys.stderr)
        return 2
    except OSError as e:  # disk full and the like: not a mistake, but still one line
        print(f"{PROG}: error: {_one_line(e)}", file=sys.stderr)
        return 1


def _is_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
