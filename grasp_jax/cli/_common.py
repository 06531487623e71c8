"""What the commands share at run time: the settings read from the options (contact model, robust
labels, gripper), devices, objects, and the messages printed beside the results.

Each check raises ``ValueError`` with the one line that ``grasp-jax: error:`` prints; the checks
run before JAX starts its backend.
"""

from __future__ import annotations

import sys

from .. import Noise, devices, dexnet_torsion, patch_torsion
from ._options import PROG


def say(args, text: str = "") -> None:
    """Print ``text`` unless --quiet or --json."""
    if not args.quiet and not getattr(args, "json", False):
        print(text, flush=True)


def warn(text: str) -> None:
    print(f"{PROG}: warning: {text}", file=sys.stderr, flush=True)


def setup(args) -> None:
    """Devices and processes, before JAX starts its backend. (Compiled programs are kept by the
    library's own cache, ``grasp_jax._cache``; JAX's persistent cache stays off: see there.)"""
    devices.configure_cpu_devices(args.devices)
    if args.distributed or devices.distributed_requested():
        devices.initialize_distributed(force=True)
        args.distributed = True


def load_object(spec: str, holes=()):
    """The object OBJECT names (its load warnings printed)."""
    from .. import objects

    obj = objects.load(spec, holes=holes or ())
    for w in getattr(obj, "warnings", ()) or ():
        warn(w)
    return obj


def holes(args, meta) -> list:
    """--hole, else the holes stored with the file's object (unless --object names another)."""
    if args.hole:
        return args.hole
    if args.object is not None and args.object != meta.get("object"):
        return []
    return list(meta.get("object_holes") or ())


def contact_settings(args, mu, meta: dict | None = None) -> tuple[str | None, float | None]:
    """``(contact, torsion)`` from --contact, --torsion and --patch-radius (``None``: the file's
    metadata, else hard contacts, where ``meta`` is given)."""
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


def noise_given(args) -> list[str]:
    """The noise flags set on the command line."""
    return [flag for flag, value in (("--sigma-pos", args.sigma_pos), ("--sigma-normal", args.sigma_normal),
                                     ("--mu-range", args.mu_range), ("--mu-sigma", args.mu_sigma),
                                     ("--sigma-pose", args.sigma_pose)) if value]


def robust_settings(args, obj=None):
    """The :class:`grasp_jax.pipeline.RobustLabels` of --robust and the noise flags (``None``
    without --robust). Checked before any work: call it once without ``obj`` first."""
    given = noise_given(args)
    if args.robust is None:
        extra = given + [f for f, v in (("--no-margin", args.no_margin), ("--robust-seed", args.robust_seed),
                                        ("--quantile", args.quantile != 0.1)) if v]
        if extra:
            raise ValueError(f"{extra[0]} sets the robust labels: add --robust N (perturbations per grasp)")
        return None
    if not given:
        raise ValueError("--robust N needs noise: --sigma-pos, --sigma-normal, --mu-range, --mu-sigma or --sigma-pose")
    from ..pipeline import RobustLabels

    rot, trans = args.sigma_pose or (0.0, 0.0)
    noise = Noise(position=args.sigma_pos, normal=args.sigma_normal, friction=args.mu_range or (1.0, 1.0),
                  friction_sigma=args.mu_sigma, rotation=rot, translation=trans)
    seed = args.robust_seed if args.robust_seed is not None else getattr(args, "seed", 0)
    return RobustLabels(noise, samples=args.robust, seed=seed, quantile=args.quantile, margin=not args.no_margin,
                        obj=obj)


def jaw_settings(args) -> tuple[dict, str | None, float | None]:
    """``(run keywords, contact, torsion)`` of ``--gripper`` (``({}, ...)`` without it)."""
    given = [f for f, v in (("--max-width", args.max_width), ("--min-width", args.min_width),
                            ("--collision", args.collision), ("--finger-size", args.finger_size),
                            ("--palm-size", args.palm_size)) if v not in (None, False)]
    if args.gripper is None:
        if given:
            raise ValueError(f"{given[0]} describes a gripper: add --gripper parallel-jaw")
        return {}, *contact_settings(args, args.mu)
    if args.max_width is None:
        raise ValueError("--gripper parallel-jaw needs --max-width W (the largest opening, in the object's units)")
    if args.fingers not in (2, 4) or args.scheme != "uniform" or args.first_contact is not None:
        raise ValueError("--gripper parallel-jaw grasps have 2 contacts, sampled antipodally: leave out --fingers, "
                         "--scheme and --first-contact")
    args.fingers = 2
    gripper = _parallel_jaw(args)
    if args.contact is None:
        args.contact = "soft"
        if args.torsion is None and args.patch_radius is None:
            args.patch_radius = args.max_width / 20
    contact, torsion = contact_settings(args, args.mu)
    return {"gripper": gripper, "collision": bool(args.collision)}, contact, torsion


def _parallel_jaw(args):
    """The :class:`grasp_jax.grippers.ParallelJaw` of --max-width, --min-width, --collision and
    the box sizes (python-fcl checked for --collision)."""
    from ..grippers import ParallelJaw
    from ..grippers._contacts import require_collision_support

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
        try:
            require_collision_support()
        except ImportError as e:
            raise ValueError(str(e)) from None
    return gripper
