"""``grasp-jax demo`` (and ``grasp-jax`` with no command): ``sample`` of a built-in object, with
the next command to try."""

from __future__ import annotations

from . import _options as opt
from . import sample

DEMO_OBJECT = "glass"
DEMO_NUM = 100_000


def add_parser(subparsers):
    p = subparsers.add_parser("demo", help=f"the default run: {DEMO_NUM:,} 4-finger grasps of the {DEMO_OBJECT}",
                              description="Sample and score random grasps of a built-in object and print what was "
                                          "found (about half a minute on two CPU cores).",
                              formatter_class=opt.Formatter)
    p.add_argument("object", metavar="OBJECT", nargs="?", default=DEMO_OBJECT,
                   help="built-in name or mesh / polygon CSV file")
    opt.add_hole(p)
    opt.add_sampling(p, num=DEMO_NUM)
    opt.add_scoring(p, from_file=False)
    opt.add_plot(p)
    return p


def run(args) -> int:
    code = sample.run(args)
    if not args.quiet and not args.json:
        print()
        print("next: grasp-jax sample glass --num 1e6 --out glass.parquet --plot glass.png   "
              "(see grasp-jax --help)")
    return code
