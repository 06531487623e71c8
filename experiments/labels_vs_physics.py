"""Which analytic label predicts whether a jaw grasp holds in MuJoCo (``grasp_jax.sim``)?

For each YCB mesh of ``../shared/data/meshes``: antipodal candidates
(``grasp_jax.grippers.antipodal_grasps``, closing directions in the friction cone of
``--sample-mu``, the body of ``ParallelJaw.scaled(--max-width)`` clear of the mesh by the
sampler's collision check), drawn in rounds until ``--num`` grasps are valid: two contacts
(``JawStatus.OK``) and a gripper that does not start inside the object's convex parts in the
simulation (``SimStatus.PENETRATION`` grasps are left out: no label here sees the gripper's body). Each valid grasp is simulated (``grasp_jax.sim.simulate_jaws``, default
``Protocol``, the objects decomposed by CoACD at ``--threshold``) and labelled:

* grasp_jax: force-closure of two hard and of two soft contacts, Q (soft), the min-weight margin
  (soft), the Ferrari-Canny epsilon (soft), the critical friction ``mu*`` (soft; lower is better),
  robust P(force-closure) and E[Q] of the jaws re-cast under pose and friction noise
  (``grippers.robust_jaws``);
* Dex-Net's antipodal test at ``--mu`` and its critical friction ``max tan alpha_i``;
* DexGraspNet's energy (``gj.objective(kind="dfc")``, larger is better);
* a baseline that is no grasp label: the distance from the centre of mass to the closing line
  (shorter is better), the lever of the load about the contacts.

Torques are taken about the centre of mass of the simulated object, in units of its radius.

For each label: ROC AUC for predicting simulated success (ties count one half) and the held rate
among the top 10% by the label (ties at the boundary broken at random, in expectation), per object
and pooled. Writes ``results.json``, ``results.md``, ``labels_vs_physics.png`` and the per-grasp
arrays (``grasps_<object>.npz``).

    python experiments/labels_vs_physics.py [--num 2000] [--objects ...]
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import SHARED_MESHES, Timer, parser, table, use_cpu_cores, write, write_json  # noqa: E402
from parallel_jaw import dexnet_critical, dexnet_force_closure  # noqa: E402

MESHES = ("ycb_011_banana", "ycb_006_mustard_bottle", "ycb_013_apple", "ycb_040_large_marker",
          "ycb_005_tomato_soup_can", "ycb_050_medium_clamp")
#: The labels, in table order: (key, title, higher is better).
LABELS = (
    ("fc_hard", "FC hard", True),
    ("fc_soft", "FC soft", True),
    ("q_soft", "Q (soft)", True),
    ("margin", "min-weight margin", True),
    ("epsilon", "Ferrari-Canny", True),
    ("critical_mu", "critical friction", False),
    ("p_fc", "robust P(FC)", True),
    ("q_mean", "robust E[Q]", True),
    ("dexnet", "Dex-Net antipodal", True),
    ("dexnet_mu", "Dex-Net critical mu", False),
    ("dfc", "DexGraspNet energy", True),
    ("lever", "(baseline) closing line to COM", False),
)


def auc(score, hit):
    """ROC AUC of ``score`` (higher: predicted success) for the bool ``hit``; ties count 1/2."""
    import numpy as np
    from scipy.stats import rankdata

    score, hit = np.asarray(score, float), np.asarray(hit, bool)
    score = np.where(np.isfinite(score), score, np.where(score > 0, np.finfo(float).max, -np.finfo(float).max))
    pos, neg = int(hit.sum()), int((~hit).sum())
    if pos == 0 or neg == 0:
        return float("nan")
    ranks = rankdata(score)
    return float((ranks[hit].sum() - pos * (pos + 1) / 2) / (pos * neg))


def top_precision(score, hit, fraction=0.1):
    """The expected held rate among the top ``fraction`` by ``score`` (ties at the boundary broken
    at random)."""
    import numpy as np

    score, hit = np.asarray(score, float), np.asarray(hit, float)
    score = np.where(np.isnan(score), -np.inf, score)
    n = max(1, int(round(fraction * len(score))))
    cut = np.sort(score)[::-1][n - 1]
    above, tied = score > cut, score == cut
    take = n - int(above.sum())
    return float((hit[above].sum() + take * hit[tied].mean()) / n)


def _take(g, rows):
    """The grasps ``rows`` of an ``AntipodalGrasps``."""
    return type(g)(*(getattr(g, f)[rows] for f in g._fields))


def valid_grasps(obj, gripper, protocol, args):
    """Antipodal grasps whose gripper body is clear of the mesh (the sampler's collision check),
    in rounds of ``--round`` candidates until ``--num`` are valid or ``--rounds`` are drawn:
    ``(grasps, SimResult, counts)`` of the valid ones (at most ``--num``); ``counts``: candidates,
    two contacts and a clear body (``JawStatus.OK``), simulated in penetration."""
    import numpy as np

    from grasp_jax import grippers, sim

    kept, results, counts = [], [], {"candidates": 0, "jaw_ok": 0, "sim_penetration": 0}
    for r in range(args.rounds):
        g = grippers.antipodal_grasps(obj, args.round, mu=args.sample_mu, gripper=gripper,
                                      seed=args.seed + 1000 * r, collision=True)
        counts["candidates"] += len(g)
        g = _take(g, g.status == grippers.JawStatus.OK)
        counts["jaw_ok"] += len(g)
        res = sim.simulate_jaws(obj, g.centers, g.axes, g.approaches, g.widths, gripper=gripper,
                                protocol=protocol, seed=args.seed, workers=args.workers, progress=args.progress)
        ok = res.status != sim.SimStatus.PENETRATION
        counts["sim_penetration"] += int((~ok).sum())
        kept.append(_take(g, ok))
        results.append(sim.SimResult(*(a[ok] for a in res)))
        if sum(len(x) for x in kept) >= args.num:
            break
    g = type(kept[0])(*(np.concatenate([getattr(x, f) for x in kept])[:args.num] for f in kept[0]._fields))
    res = sim.SimResult(*(a[:args.num] for a in sim.SimResult.concatenate(results)))
    return g, res, counts


def labels(obj, g, gripper, com, args):
    """Every label of the valid grasps ``g``: a dict of ``(k,)`` arrays. Torques are taken about
    the centre of mass ``com`` (that of the simulation) in units of the object's radius about it."""
    import numpy as np

    import grasp_jax as gj
    from grasp_jax import grippers

    torsion = float(gj.patch_torsion(args.patch_radius, args.mu))
    p, n = g.points, g.normals
    soft = grippers.score_grasps(p, n, g.status, mu=args.mu, torsion=torsion, contact="soft")
    hard = grippers.score_grasps(p, n, g.status, mu=args.mu, torsion=None, contact="hard", critical=False)
    radius = float(np.linalg.norm(np.asarray(obj.mesh.vertices) - com, axis=1).max())
    kw = dict(mu=args.mu, contact="soft", torsion=torsion)
    eps, _ = gj.ferrari_canny(p, n, origin=com, torque_scale=radius, **kw)
    lever = np.linalg.norm(np.cross(com - g.centers, g.axes), axis=1)
    noise = gj.Noise(position=args.sigma_pos, rotation=args.sigma_rot, translation=args.sigma_pos,
                     friction=(0.8, 1.2))
    rob = grippers.robust_jaws(obj, g.centers, g.axes, g.widths, g.approaches, mu=args.mu, noise=noise,
                               key=args.seed, samples=args.robust, gripper=gripper, torsion=torsion, margin=False)
    return {
        "fc_hard": np.asarray(hard.force_closure, float), "fc_soft": np.asarray(soft.force_closure, float),
        "q_soft": np.asarray(soft.quality, float),
        "margin": np.asarray(gj.min_weight(p, n, origin=com, torque_scale=radius, **kw), float),
        "epsilon": np.asarray(eps, float),
        "critical_mu": np.asarray(soft.critical_mu, float),
        "p_fc": np.asarray(rob.p_fc, float), "q_mean": np.asarray(rob.q_mean, float),
        "dexnet": dexnet_force_closure(p, n, args.mu).astype(float), "dexnet_mu": dexnet_critical(p, n),
        "dfc": np.asarray(gj.objective(p, n, kind="dfc", center=com, scale=radius, **kw), float),
        "lever": lever,
    }


def scores(values, hit):
    """``{label: (auc, top-10% precision)}``; labels where lower is better are negated."""
    out = {}
    for key, _, higher in LABELS:
        s = values[key] if higher else -values[key]
        out[key] = (auc(s, hit), top_precision(s, hit))
    return out


def figure(path, per_object, pooled, base):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    names = list(per_object) + ["pooled"]
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), dpi=110, sharey=True)
    width = 0.8 / len(names)
    y = np.arange(len(LABELS))
    for j, name in enumerate(names):
        res = pooled if name == "pooled" else per_object[name]
        for ax, m in zip(axes, (0, 1)):
            vals = [res[key][m] for key, _, _ in LABELS]
            ax.barh(y + (j - len(names) / 2 + 0.5) * width, vals, height=width,
                    label=name.replace("ycb_", ""), color="k" if name == "pooled" else None)
    axes[0].axvline(0.5, color="0.4", lw=0.8, ls="--")
    axes[0].set_xlim(0.3, 1.0)
    axes[0].set_xlabel("ROC AUC for simulated success")
    for name in names:
        rate = base[name]
        axes[1].axvline(rate, color="k" if name == "pooled" else "0.75", lw=0.8, ls=":")
    axes[1].set_xlim(0, 1.0)
    axes[1].set_xlabel("held rate among the top 10% (dotted: base rates)")
    axes[0].set_yticks(y, [title for _, title, _ in LABELS])
    axes[0].invert_yaxis()
    handles, names_ = axes[1].get_legend_handles_labels()
    fig.legend(handles, names_, fontsize=8, loc="lower center", ncol=len(names))
    fig.suptitle("Analytic labels of antipodal jaw grasps against the MuJoCo check (grasp_jax.sim)")
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    fig.savefig(path)


def replot(out: Path) -> None:
    """The figure again from ``out/results.json``."""
    import json

    data = json.loads((out / "results.json").read_text())
    res = {name: {k: (v["auc"], v["top10"]) for k, v in labels.items()} for name, labels in data["auc_top10"].items()}
    pooled = res.pop("pooled")
    figure(out / "labels_vs_physics.png", res, pooled, data["base_rate"])


def main(argv=None):
    ap = parser("labels_vs_physics", __doc__)
    ap.add_argument("--num", type=int, default=2000, help="valid grasps per object")
    ap.add_argument("--objects", nargs="+", default=list(MESHES))
    ap.add_argument("--round", type=int, default=4000, help="candidates per round")
    ap.add_argument("--rounds", type=int, default=5, help="at most this many rounds per object")
    ap.add_argument("--mu", type=float, default=0.5, help="friction of the labels (the simulation's too)")
    ap.add_argument("--sample-mu", type=float, default=1.0, help="friction cone of the sampled closing lines")
    ap.add_argument("--max-width", type=float, default=0.1)
    ap.add_argument("--patch-radius", type=float, default=0.005)
    ap.add_argument("--threshold", type=float, default=0.05, help="CoACD threshold")
    ap.add_argument("--robust", type=int, default=20, help="samples of the robust labels")
    ap.add_argument("--sigma-pos", type=float, default=0.05, help="position noise, object radii")
    ap.add_argument("--sigma-rot", type=float, default=0.05, help="rotation noise, radians")
    ap.add_argument("--jaw-force", type=float, default=None, help="Protocol.jaw_force (default: the Protocol's)")
    ap.add_argument("--workers", type=int, default=None)
    ap.add_argument("--progress", action="store_true")
    ap.add_argument("--replot", action="store_true", help="only draw the figure again from results.json")
    args = ap.parse_args(argv)
    if args.replot:
        return replot(args.out)
    use_cpu_cores()

    import warnings

    import numpy as np

    from grasp_jax import grippers, objects, sim

    timer = Timer()
    gripper = grippers.ParallelJaw.scaled(args.max_width)
    extra = {} if args.jaw_force is None else {"jaw_force": args.jaw_force}
    protocol = sim.Protocol(friction=args.mu, decomposition=sim.Decomposition(threshold=args.threshold), **extra)
    per_object, base, data, pooled_values, pooled_hit, counts = {}, {}, {}, {}, [], {}
    for name in args.objects:
        path = SHARED_MESHES / f"{name}.obj"
        if not path.is_file():
            print(f"skip {name}: {path} not found")
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            obj = objects.load(path)
        t = time.perf_counter()
        g, res, drawn = valid_grasps(obj, gripper, protocol, args)
        sim_s = time.perf_counter() - t
        t = time.perf_counter()
        com = sim.sim_object(obj, mass=protocol.mass, params=protocol.decomposition).com
        values = labels(obj, g, gripper, com, args)
        label_s = time.perf_counter() - t
        hit = np.asarray(res.success, bool)
        per_object[name] = scores(values, hit)
        base[name] = float(hit.mean())
        counts[name] = {**drawn, "valid": len(hit), "held": int(hit.sum()),
                        "status": {s.name: int(np.sum(res.status == s)) for s in sim.SimStatus},
                        "directions_held": res.directions.mean(axis=0).tolist(),
                        "simulation_s": sim_s, "labels_s": label_s}
        for key in values:
            pooled_values.setdefault(key, []).append(values[key])
        pooled_hit.append(hit)
        np.savez(args.out / f"grasps_{name}.npz" if args.out.is_dir() else _mkdir(args.out) / f"grasps_{name}.npz",
                 success=hit, directions=res.directions, status=res.status, centers=g.centers, axes=g.axes,
                 approaches=g.approaches, widths=g.widths, points=g.points, normals=g.normals, **values)
        timer.lap(name)
        print(name, counts[name], flush=True)
        print(_table({name: per_object[name]}, {name: base[name]}), flush=True)
    hit = np.concatenate(pooled_hit)
    pooled = scores({k: np.concatenate(v) for k, v in pooled_values.items()}, hit)
    base["pooled"] = float(hit.mean())
    text = _table({**per_object, "pooled": pooled}, base)
    print(text)
    figure(args.out / "labels_vs_physics.png", per_object, pooled, base)
    settings = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    data = {"settings": settings, "protocol": repr(protocol), "gripper": gripper.to_dict(), "counts": counts,
            "auc_top10": {name: {k: {"auc": a, "top10": p} for k, (a, p) in res.items()}
                          for name, res in {**per_object, "pooled": pooled}.items()},
            "base_rate": base}
    write_json(args.out, data)
    write(args.out, "# Analytic labels against the MuJoCo check\n\n" + text + "\n\n" + timer.report())


def _mkdir(path):
    path.mkdir(parents=True, exist_ok=True)
    return path


def _table(results, base):
    header = ["label"] + [f"{n.replace('ycb_', '')} AUC / top10%" for n in results]
    rows = [[title] + [f"{results[n][key][0]:.3f} / {results[n][key][1]:.3f}" for n in results]
            for key, title, _ in LABELS]
    rows.append(["(held rate)"] + [f"{base[n]:.3f}" for n in results])
    return table(header, rows)


if __name__ == "__main__":
    main()
