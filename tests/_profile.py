"""Sums up the files of ``GRASP_JAX_PROFILE_COMPILES`` (``tests/conftest.py``), test helper.

``python tests/_profile.py compiles.gw0.jsonl compiles.gw1.jsonl [--tests N] [--programs N]``: per
file of tests, its tests, compilations, compile seconds and summed test seconds; the N tests with
the most compile seconds; the N programs compiled most often (name and argument shapes) and the
files that compile each.
"""

from __future__ import annotations

import argparse
import collections
import json


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("files", nargs="+")
    parser.add_argument("--tests", type=int, default=25)
    parser.add_argument("--programs", type=int, default=30)
    parser.add_argument("--names", type=int, default=0, help="programs by name only, N of them")
    parser.add_argument("--json", help="write the per-file table here")
    args = parser.parse_args(argv)
    tests = []
    for name in args.files:
        with open(name) as f:
            if name.endswith(".jsonl"):
                tests.extend(json.loads(line) for line in f if line.strip())
                continue
            data = json.load(f)
        for t in data["tests"]:
            t["worker"] = data["worker"]
            tests.append(t)
    per_file = collections.defaultdict(lambda: [0, 0, 0.0, 0.0])
    for t in tests:
        row = per_file[t["test"].split("::")[0]]
        row[0] += 1
        row[1] += t["compiles"]
        row[2] += t["compile_s"]
        row[3] += t["wall_s"]
    total = [sum(r[k] for r in per_file.values()) for k in range(4)]
    print(f"{'file':32s} {'tests':>6s} {'compiles':>9s} {'compile_s':>10s} {'test_s':>9s}")
    for name, r in sorted(per_file.items(), key=lambda kv: -kv[1][3]):
        print(f"{name:32s} {r[0]:6d} {r[1]:9d} {r[2]:10.1f} {r[3]:9.1f}")
    print(f"{'total':32s} {total[0]:6d} {total[1]:9d} {total[2]:10.1f} {total[3]:9.1f}")
    for worker in sorted({t["worker"] or "-" for t in tests}):
        mine = [t for t in tests if (t["worker"] or "-") == worker]
        print(f"worker {worker}: {len(mine)} tests, {sum(t['wall_s'] for t in mine):.1f} s")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({k: dict(zip(("tests", "compiles", "compile_s", "test_s"), v)) for k, v in per_file.items()},
                      f, indent=1)
    print("\nTests with the most compile seconds:")
    for t in sorted(tests, key=lambda t: -t["compile_s"])[: args.tests]:
        print(f"{t['compile_s']:7.1f} s {t['compiles']:4d} compiles {t['wall_s']:7.1f} s wall  {t['test']}")
    programs = collections.defaultdict(lambda: [0, 0.0, set()])
    names = collections.defaultdict(lambda: [0, 0.0, set()])
    for t in tests:
        for name, shapes, secs in t["programs"]:
            for key, table in (((name, shapes), programs), (name, names)):
                table[key][0] += 1
                table[key][1] += secs
                table[key][2].add(t["test"].split("::")[0].replace("tests/", ""))
    print("\nPrograms compiled most often (same name and shapes):")
    for (name, shapes), (n, secs, files) in sorted(programs.items(), key=lambda kv: -kv[1][1])[: args.programs]:
        if n > 1:
            print(f"{n:4d}x {secs:7.1f} s {name} {str(shapes)[:160]}  [{', '.join(sorted(files))[:120]}]")
    if args.names:
        print("\nPrograms by name:")
        for name, (n, secs, files) in sorted(names.items(), key=lambda kv: -kv[1][1])[: args.names]:
            print(f"{n:4d}x {secs:7.1f} s {name}  [{', '.join(sorted(files))[:150]}]")


if __name__ == "__main__":
    main()
