"""``grasp-jax sample``: sample random grasps of an object, score them, stream them to a file."""

from __future__ import annotations

from .. import storage
from . import _options as opt
from ._common import contact_settings, jaw_settings, load_object, robust_settings, setup
from ._output import check_plot_path, plot_summary, report


def add_parser(subparsers):
    p = subparsers.add_parser("sample", help="sample random grasps of an object and score them",
                              description="Sample NUM random grasps of OBJECT, score each (force-closure, Q), "
                                          "stream them to --out and print a summary.",
                              epilog=opt.epilog(), formatter_class=opt.Formatter)
    p.add_argument("object", metavar="OBJECT", help="built-in name or mesh / polygon CSV file")
    opt.add_hole(p)
    opt.add_sampling(p, num=10_000)
    opt.add_scoring(p, from_file=False)
    opt.add_gripper(p)
    opt.add_plot(p)
    return p


def run(args) -> int:
    from .. import pipeline

    if args.out is not None:
        storage.check_output_path(args.out)
    check_plot_path(args.plot)
    jaw, contact, torsion = jaw_settings(args) if hasattr(args, "gripper") else ({}, *contact_settings(args, args.mu))
    robust_settings(args)
    setup(args)
    obj = load_object(args.object, args.hole)
    summary = pipeline.run(
        obj, args.num, args.fingers, mu=args.mu, num_edges=args.edges, seed=args.seed, scheme=args.scheme,
        torque_test=args.torque_test, chunk=args.chunk, epsilon=args.epsilon, origin=args.origin,
        torque_scale=args.torque_scale, out=args.out, progress=not args.quiet, top=max(args.top, 5),
        distributed=args.distributed, object_spec=args.object, first_contact=args.first_contact,
        object_holes=args.hole, contact=contact, torsion=torsion, critical=args.critical_friction,
        robust=robust_settings(args, obj),
        **jaw,
    )
    report(args, summary, best_lines=5)
    plot_summary(args, obj, summary, args.mu, args.edges)
    return 0
