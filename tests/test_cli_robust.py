"""``grasp-jax sample / score --robust N``: robust columns beside the nominal ones, through the
streaming pipeline, equal to :func:`grasp_jax.robust` of the same grasps (run as subprocesses,
one device, as ``test_cli.py`` runs the command line; ``grasp_jax.robust`` in a process of its own
too, which loads the programs the command line compiled)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

from grasp_jax import storage

from test_cli import env, grasp_jax, grasp_jax_runs  # noqa: F401 - the fixture and the runners

NOISE = ["--sigma-pos", "0.02", "--mu-range", "0.8,1.2", "--sigma-pose", "0.02,0.01"]
ROBUST = ("p_fc", "p_fc_se", "q_mean", "q_mean_se", "q_low", "robust_unconverged")


#: ``gj.robust`` of a results file's grasps with the noise and seed of NOISE and ``--seed 3``, run by
#: :func:`_python_labels` in a process of its own.
PYTHON_LABELS = """
import sys
from grasp_jax import devices
devices.configure_cpu_devices(1)  # as --devices 1 does: the same device set, the same cached programs
import jax, numpy as np, grasp_jax as gj
from grasp_jax import objects, storage
a, _ = storage.read_results(sys.argv[1])
res = gj.robust(objects.Sphere(), a["points"], a["normals"], mu=0.364, key=jax.random.key(3), samples=8,
                noise=gj.Noise(position=0.02, friction=(0.8, 1.2), rotation=0.02, translation=0.01), margin=False)
np.savez(sys.argv[2], p_fc=np.asarray(res.p_fc), q_mean=np.asarray(res.q_mean))
"""


def _python_labels(env, cwd, name):
    out = subprocess.run([sys.executable, "-c", PYTHON_LABELS, name, "python.npz"], env=env, cwd=cwd,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    with np.load(cwd / "python.npz") as f:
        labels = dict(f)
    (cwd / "python.npz").unlink()
    return labels


def test_sample_and_score_write_robust_columns(env, tmp_path, in_process, capsys):  # noqa: F811
    # sample, then score the file again with the same noise and seed (one child process, in turn)
    out, _ = grasp_jax_runs(
        ("sample", "sphere", "--num", "300", "--seed", "3", "--robust", "8", *NOISE, "--no-margin", "--chunk", "150",
         "--devices", "1", "--out", "s.npz"),
        ("score", "s.npz", "--robust", "8", *NOISE, "--robust-seed", "3", "--no-margin", "--devices", "1",
         "--out", "r.parquet", "--quiet"), env=env, cwd=tmp_path)
    assert "robust         8 perturbations" in out.stdout and "P(FC) mean" in out.stdout
    a, meta = storage.read_results(tmp_path / "s.npz")
    assert set(ROBUST) <= set(a) and "margin_mean" not in a
    assert meta["robust"]["samples"] == 8 and meta["robust"]["noise"]["position"] == 0.02
    assert meta["robust"]["noise"]["friction"] == [0.8, 1.2] and meta["robust"]["seed"] == 3
    # the same labels from Python (one key for every chunk: they do not depend on the chunk size),
    # in a process of its own with the command line's cache: it loads the programs sample compiled
    res = _python_labels(env, tmp_path, "s.npz")
    np.testing.assert_array_equal(a["p_fc"], res["p_fc"])
    np.testing.assert_allclose(a["q_mean"], res["q_mean"], rtol=1e-9, atol=1e-12)  # another program: LP tolerance
    assert 0 < a["p_fc"].mean() < 1 and np.all(a["p_fc"][~a["force_closure"]] <= 1)
    # score: the same labels, beside the nominal columns
    b, meta_b = storage.read_results(tmp_path / "r.parquet")
    for name in ROBUST + ("force_closure", "quality"):
        np.testing.assert_array_equal(b[name], a[name], err_msg=name)
    assert meta_b["robust"] == meta["robust"]
    # show draws nominal Q against P(force-closure) beside the best grasps (in this process: a
    # process start less; the command line in a process of its own above and in test_cli.py)
    assert in_process(["show", "r.parquet", "--plot", "best.png", "--top", "2"]) == 0
    assert "best.robust.png" in capsys.readouterr().out and (tmp_path / "best.robust.png").stat().st_size > 10_000


def test_score_without_an_object_for_moving_noise(env, tmp_path):  # noqa: F811
    p = np.random.default_rng(0).normal(size=(10, 4, 3))
    np.savez(tmp_path / "plain.npz", points=p, normals=p)
    out = grasp_jax("score", "plain.npz", "--robust", "4", "--sigma-pos", "0.1", env=env, cwd=tmp_path,
                    check=False)
    assert out.returncode == 2 and out.stderr.strip().startswith("grasp-jax: error: the file names no object")
    assert sorted(f.name for f in tmp_path.iterdir()) == ["plain.npz"]
