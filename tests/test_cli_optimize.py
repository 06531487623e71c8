"""``grasp-jax optimize`` through :func:`grasp_jax.cli.main`, in this process.

Every run has the same small shape (the built-in 2D ``quad``, 3 fingers, 16 starts, 10 steps,
4 cone edges), so the optimizer step is compiled once for the whole file; the mistakes are caught
before anything is compiled.
"""

from __future__ import annotations

import contextlib
import io
import json
import os

import numpy as np
import pytest

import grasp_jax as gj
from grasp_jax import storage, summary

START = ["--fingers", "3", "--starts", "16", "--steps", "10", "--edges", "4"]
FIELDS = {"points", "normals", "force_closure", "quality", "converged", "initial_points", "objective",
          "reason", "history", "quality_history", "path"}


@pytest.fixture(scope="module")
def cli():
    """``main`` with the process's devices and JAX configuration left alone."""
    pytest.importorskip("grasp_jax.objects")
    import jax

    from grasp_jax.cli import main

    jax.devices()  # the backend runs: main() cannot change the device count of this process
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))
        mp.setenv("GRASP_JAX_CACHE", "off")  # no jax.config change from main()
        yield main


def _run(cli, capsys, *args):
    code = cli(list(args))
    out = capsys.readouterr()
    assert code == 0, (args, out.err)
    assert "Traceback" not in out.err
    return out.out


@pytest.fixture(scope="module")
def runs(cli, tmp_path_factory):
    """``sample`` to s.npz; ``optimize`` from random starts (o.npz, o.png); ``optimize --from
    s.npz`` (r.parquet, JSON summary)."""
    d = tmp_path_factory.mktemp("optimize")
    outs = {}
    cwd = os.getcwd()
    os.chdir(d)
    try:
        for name, args in [
            ("sample", ["sample", "quad", "--fingers", "3", "--num", "64", "--edges", "4", "--seed", "1",
                        "--out", "s.npz", "--quiet"]),
            ("random", ["optimize", "quad", *START, "--out", "o.npz", "--plot", "o.png"]),
            ("from", ["optimize", "--from", "s.npz", "--starts", "16", "--steps", "10", "--out", "r.parquet",
                      "--json"]),
        ]:
            stdout, stderr = io.StringIO(), io.StringIO()
            with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
                code = cli(args)
            assert code == 0, (args, stderr.getvalue())
            assert "Traceback" not in stderr.getvalue()
            outs[name] = (stdout.getvalue(), stderr.getvalue())
    finally:
        os.chdir(cwd)
    return d, outs


def test_output_file_has_the_sample_fields_and_the_history(runs):
    d, outs = runs
    arrays, meta = storage.read_results(d / "o.npz")
    assert set(arrays) == FIELDS
    assert arrays["points"].shape == arrays["normals"].shape == arrays["initial_points"].shape == (16, 3, 2)
    assert arrays["history"].shape == arrays["quality_history"].shape == (16, 10)
    # the contacts' path: the start, then the contacts after each compiled segment of steps
    assert arrays["path"].shape[0] == 16 and arrays["path"].shape[2:] == (3, 2) and arrays["path"].shape[1] >= 2
    np.testing.assert_array_equal(arrays["path"][:, 0], arrays["initial_points"])
    for name in ("force_closure", "quality", "converged", "objective", "reason"):
        assert arrays[name].shape == (16,)
    assert arrays["reason"].dtype == np.int8
    # the end reason says force-closure exactly where the exact test does
    np.testing.assert_array_equal(arrays["reason"] == gj.EndReason.FORCE_CLOSURE, arrays["force_closure"])
    assert set(np.unique(arrays["reason"])) <= {int(r) for r in gj.EndReason}
    # the stored verdicts and Q are evaluate's for the stored points and normals
    res = gj.evaluate(arrays["points"], arrays["normals"], mu=0.364, num_edges=4)
    np.testing.assert_array_equal(np.asarray(res.force_closure), arrays["force_closure"])
    np.testing.assert_array_equal(np.asarray(res.quality), arrays["quality"])
    # the reported iterate: the best Q among force-closure ones, else the best objective
    assert np.all(arrays["objective"] <= arrays["history"].max(axis=1) + 1e-12)
    assert np.all(arrays["quality"] >= arrays["quality_history"].max(axis=1) - 1e-9)
    for key, value in dict(command="optimize", object="quad", dim=2, fingers=3, mu=0.364, edges=4, seed=0,
                           num=16, steps=10, objective="closure", learning_rate=0.3, init="random",
                           torque_test="exact").items():
        assert meta[key] == value, key
    assert meta["normals"] in ("smooth", "flat", "exact")
    assert sorted(p.name for p in d.iterdir()) == ["o.npz", "o.png", "r.parquet", "s.npz"]  # no temporaries


def test_summary_and_figure(runs):
    d, outs = runs
    stdout, stderr = outs["random"]
    arrays, _ = storage.read_results(d / "o.npz")
    fc = arrays["force_closure"]
    lines = {line.split()[0]: line for line in stdout.splitlines()}
    assert f"{fc.sum()} of 16 ({100 * fc.mean():.1f}%)" in lines["force-closure"]
    assert "16 starts x 10 steps" in lines["optimized"] and "start-steps/s" in lines["optimized"]
    assert "end" in lines and "force-closure reached" in lines["end"]
    assert "random" in lines and "160" in lines["random"]  # as many random grasps as starts x steps
    if fc.any():
        assert "p50" in lines["Q"] and f"max {arrays['quality'][fc].max():.4f}" in lines["Q"]
        best = int(np.argmax(np.where(fc, arrays["quality"], -1)))
        assert lines["best"].split()[2] == f"#{best}"
    assert "o.npz" in lines["output"] and "o.png" in lines["figure"]
    assert "step" in stderr  # the progress bar over steps
    assert (d / "o.png").stat().st_size > 10_000


def test_show_and_score_read_an_optimize_file(runs, cli, capsys, monkeypatch):
    d, _ = runs
    monkeypatch.chdir(d)
    out = _run(cli, capsys, "show", "o.npz", "--plot", "show.png", "--top", "3")
    arrays, _ = storage.read_results(d / "o.npz")
    best = int(np.argmax(np.where(arrays["force_closure"], arrays["quality"], -1)))
    assert out.splitlines()[1].split()[:2] == ["1", str(best)]
    assert (d / "show.png").stat().st_size > 10_000
    report = json.loads(_run(cli, capsys, "score", "o.npz", "--json"))
    assert report["num"] == 16 and report["agree"] == 16
    assert report["metadata"]["mu"] == 0.364 and report["metadata"]["edges"] == 4
    (d / "show.png").unlink()


def test_sample_then_refine(runs):
    d, outs = runs
    arrays, meta = storage.read_results(d / "r.parquet")
    assert set(arrays) == FIELDS and arrays["history"].shape == (16, 10)
    assert meta["init"] == str((d / "s.npz").resolve())
    assert meta["object"] == "quad" and meta["fingers"] == 3 and meta["edges"] == 4  # from the file
    # the starts are the file's 16 best grasps (force-closure first, then by Q), on the surface
    best, _ = summary.best_starts(d / "s.npz", 16)
    np.testing.assert_allclose(arrays["initial_points"], best.points, atol=1e-9)
    sampled, _ = storage.read_results(d / "s.npz")
    ranked = np.lexsort((np.arange(64), -sampled["quality"], ~sampled["force_closure"]))
    np.testing.assert_array_equal(best.index, ranked[:16])
    # the first step scores the starts themselves (Q where force-closure), and the reported
    # grasp is the best iterate by the objective
    q0 = np.where(sampled["force_closure"], sampled["quality"], 0.0)[best.index]
    np.testing.assert_allclose(arrays["quality_history"][:, 0], q0, atol=1e-7)
    # the reported iterate: the best Q among force-closure ones, else the best objective
    assert np.all(arrays["objective"] <= arrays["history"].max(axis=1) + 1e-12)
    assert np.all(arrays["quality"] >= arrays["quality_history"].max(axis=1) - 1e-9)
    report = json.loads(outs["from"][0])
    assert report["starts"] == 16 and report["force_closure"] == int(arrays["force_closure"].sum())
    assert report["distinct_force_closure"] <= report["force_closure"]
    assert sum(report["reasons"].values()) == 16
    # fewer grasps in the file than --starts: all of them
    assert len(summary.best_starts(d / "s.npz", 100)[0]) == 64


@pytest.fixture
def mistakes_dir(tmp_path):
    rng = np.random.default_rng(0)
    p = rng.normal(size=(8, 4, 2))
    np.savez(tmp_path / "four.npz", points=p, normals=p)  # 4-finger grasps, no metadata
    p = rng.normal(size=(8, 3, 3))
    np.savez(tmp_path / "solid.npz", points=p, normals=p)  # 3D grasps
    p = rng.normal(size=(8, 3, 2))
    with storage.open_writer(tmp_path / "quad.npz", {"object": "quad", "mu": 0.364}, ("points", "normals"),
                             fingers=3, dim=2) as w:
        w.write({"points": p, "normals": p})
    (tmp_path / "notes.txt").write_text("not grasps\n")
    return tmp_path


MISTAKES = [
    (["optimize"], "no OBJECT"),
    (["optimize", "no_such_object"], "no_such_object"),
    (["optimize", "quad", "--fingers", "1"], "--fingers"),
    (["optimize", "quad", "--steps", "0"], "--steps"),
    (["optimize", "quad", "--starts", "0"], "--starts"),
    (["optimize", "quad", "--steps", "-2"], "--steps"),
    (["optimize", "quad", "--lr", "0"], "--lr"),
    (["optimize", "quad", "--objective", "best"], "--objective"),
    (["optimize", "quad", "--fingers", "3", "--from", "four.npz"], "4-finger"),
    (["optimize", "quad", "--from", "solid.npz"], "3D grasps"),
    (["optimize", "--from", "four.npz"], "names no object"),
    (["optimize", "sphere", "--from", "quad.npz"], "omit OBJECT"),
    (["optimize", "quad", "--from", "missing.npz"], "missing.npz"),
    (["optimize", "quad", "--from", "notes.txt"], "must end in"),
    (["optimize", "--from", "quad.npz", "--out", "quad.npz"], "must differ"),
    (["optimize", "quad", "--out", "o.csv"], "o.csv"),
    (["optimize", "quad", "--out", "no/dir/o.npz"], "does not exist"),
    (["optimize", "quad", "--plot", "o.txt"], "o.txt"),
    (["optimize", "quad", "--plot", "no/dir/o.png"], "does not exist"),
]


def test_user_mistakes_exit_2_with_one_line_and_no_file(cli, mistakes_dir, monkeypatch, capsys):
    monkeypatch.chdir(mistakes_dir)
    before = sorted(p.name for p in mistakes_dir.iterdir())
    for args, expect in MISTAKES:
        code = cli(args)
        out = capsys.readouterr()
        lines = out.err.strip().splitlines()
        assert code == 2, (args, out.err)
        assert len(lines) == 1 and lines[0].startswith("grasp-jax: error: "), (args, out.err)
        assert expect in lines[0], (args, out.err)
        assert out.out == "", args
    assert sorted(p.name for p in mistakes_dir.iterdir()) == before


def test_plot_optimization_draws_curves_beside_random_grasps(tmp_path):
    from grasp_jax import plotting

    rng = np.random.default_rng(1)
    history = np.maximum.accumulate(rng.random((8, 5)), axis=1)
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    grasp = (np.array([[0.5, 0.0], [0.5, 1.0]]), np.array([[0.0, -1.0], [0.0, 1.0]]), 1.0, "start #0")
    fig = plotting.plot_optimization(history, sampled_quality=rng.random(40) * (rng.random(40) < 0.3),
                                     grasps=[grasp, grasp], geometry=square, mu=0.364, title="t",
                                     path=tmp_path / "f.png")
    assert len(fig.axes) == 4  # curves, the random grasps' histogram, two grasps
    labels = fig.axes[0].get_legend_handles_labels()[1]
    assert "median over starts" in labels and "best of 40 random grasps" in labels
    assert (tmp_path / "f.png").stat().st_size > 5_000
    import matplotlib.pyplot as plt

    plt.close(fig)
    with pytest.raises(ValueError, match="starts, steps"):
        plotting.plot_optimization(np.zeros(5))
    with pytest.raises(ValueError, match="geometry"):
        plotting.plot_optimization(history, grasps=[grasp])
