"""The chunked pipeline (grasp_jax.pipeline) and the result files (grasp_jax.storage).

Runs are small (a few thousand grasps); every run that compiles uses the same sizes so that JAX
compiles once per test session.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import grasp_jax as gj
from grasp_jax import _stream, pipeline, storage
from grasp_jax import devices as devs
from grasp_jax import summary as summaries

REPO = Path(__file__).resolve().parents[1]
NUM = 2000
CHUNK = 1000  # two chunks of NUM


def _objects():
    return pytest.importorskip("grasp_jax.objects")


@pytest.fixture(scope="module")
def glass():
    return _objects().load("glass")


def _subprocess_env(xla_cache, **extra):
    env = dict(os.environ)
    env.pop("XLA_FLAGS", None)
    env["GRASP_JAX_CACHE"] = xla_cache  # the suite's (conftest.py)
    env["PYTHONWARNINGS"] = "ignore::DeprecationWarning"
    env.update(extra)
    return env


# ---------------------------------------------------------------------------------------------
# storage


FIELDS = ("points", "normals", "force_closure", "quality", "converged")


def _fake_rows(rng, rows, fingers=3, dim=3):
    p = rng.normal(size=(rows, fingers, dim))
    return dict(points=p, normals=-p, force_closure=rng.random(rows) < 0.5, quality=rng.random(rows),
                converged=np.ones(rows, bool))


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_storage_round_trip(tmp_path, rng, suffix):
    path = tmp_path / f"r{suffix}"
    meta = {"object": "glass", "mu": 0.364, "num": 7}
    chunks = [_fake_rows(rng, k) for k in (3, 0, 4)]
    with storage.open_writer(path, meta, FIELDS, fingers=3, dim=3) as w:
        for c in chunks:
            w.write(c)
    arrays, got = storage.read_results(path)
    assert got == meta
    for name in FIELDS:
        want = np.concatenate([c[name] for c in chunks])
        np.testing.assert_array_equal(arrays[name], want)
        assert arrays[name].dtype == want.dtype
    assert sorted(os.listdir(tmp_path)) == [path.name]  # no temporary files left
    f = storage.ResultFile(path)
    assert (f.num, f.fingers, f.dim) == (7, 3, 3)
    sizes = [len(c["points"]) for c in f.iter_chunks(chunk=3)]
    assert sizes == [3, 3, 1]


def test_npz_is_plain_numpy(tmp_path, rng):
    path = tmp_path / "r.npz"
    rows = _fake_rows(rng, 5)
    with storage.open_writer(path, {"a": [1, 2]}, FIELDS, fingers=3, dim=3) as w:
        w.write(rows)
    with np.load(path) as f:  # allow_pickle=False by default
        assert json.loads(str(f["metadata"])) == {"a": [1, 2]}
        np.testing.assert_array_equal(f["points"], rows["points"])


def test_parquet_layout(tmp_path, rng):
    pq = pytest.importorskip("pyarrow.parquet")
    path = tmp_path / "r.parquet"
    rows = _fake_rows(rng, 5, fingers=4, dim=2)
    with storage.open_writer(path, {"mu": 0.5}, FIELDS, fingers=4, dim=2) as w:
        w.write(rows)
    table = pq.read_table(path)
    assert table.num_rows == 5
    assert str(table.schema.field("points").type) == (
        "fixed_size_list<element: fixed_size_list<element: double>[2]>[4]")
    assert json.loads(table.schema.metadata[b"grasp_jax"]) == {"mu": 0.5}
    assert table.column("points").to_pylist()[2] == rows["points"][2].tolist()


@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_writer_leaves_nothing_on_error(tmp_path, rng, suffix):
    path = tmp_path / f"r{suffix}"
    with pytest.raises(RuntimeError, match="boom"):
        with storage.open_writer(path, {}, FIELDS, fingers=3, dim=3) as w:
            w.write(_fake_rows(rng, 4))
            raise RuntimeError("boom")
    assert os.listdir(tmp_path) == []


def test_writer_replaces_existing_file_only_at_the_end(tmp_path, rng):
    path = tmp_path / "r.npz"
    path.write_bytes(b"old")
    with pytest.raises(KeyboardInterrupt):
        with storage.open_writer(path, {}, FIELDS, fingers=3, dim=3) as w:
            w.write(_fake_rows(rng, 4))
            raise KeyboardInterrupt
    assert path.read_bytes() == b"old"
    assert os.listdir(tmp_path) == ["r.npz"]



@pytest.mark.parametrize("suffix", [".npz", ".parquet"])
def test_storage_optimizer_fields(tmp_path, rng, suffix):
    """The per-start fields of grasp-jax optimize: start points, end reasons, per-step series."""
    path = tmp_path / f"o{suffix}"
    fields = FIELDS + ("initial_points", "objective", "reason", "history", "quality_history")
    rows = _fake_rows(rng, 5, fingers=3, dim=2)
    rows.update(initial_points=rng.normal(size=(5, 3, 2)), objective=rng.random(5),
                reason=np.array([0, 1, 2, 0, 1], np.int8), history=rng.random((5, 7)),
                quality_history=rng.random((5, 7)))
    with storage.open_writer(path, {}, fields, fingers=3, dim=2, steps=7) as w:
        w.write(rows)
    arrays, _ = storage.read_results(path)
    for name in fields:
        np.testing.assert_array_equal(arrays[name], rows[name])
        assert arrays[name].dtype == rows[name].dtype
    assert [len(c["history"]) for c in storage.ResultFile(path).iter_chunks(("history",), 2)] == [2, 2, 1]
    with pytest.raises(ValueError, match="number of steps"):
        storage.open_writer(tmp_path / f"p{suffix}", {}, fields, fingers=3, dim=2)

@pytest.mark.parametrize(
    "name, message",
    [("r.csv", "must end in"), ("missing/r.npz", "does not exist"), ("r", "must end in")],
)
def test_bad_output_paths(tmp_path, name, message):
    with pytest.raises(ValueError, match=message):
        storage.open_writer(tmp_path / name, {}, FIELDS, fingers=3, dim=3)


def test_reader_rejects_files_without_grasps(tmp_path):
    path = tmp_path / "x.npz"
    np.savez(path, a=np.zeros(3))
    with pytest.raises(ValueError, match="no 'points' and 'normals'"):
        storage.ResultFile(path)
    bad = tmp_path / "bad.npz"
    bad.write_text("not a zip")
    with pytest.raises(ValueError, match="not a readable"):
        storage.ResultFile(bad)
    with pytest.raises(FileNotFoundError):
        storage.ResultFile(tmp_path / "nope.npz")


# ---------------------------------------------------------------------------------------------
# statistics and helpers


def test_histogram_percentiles_match_numpy(rng):
    q = rng.beta(2, 5, size=20000) * 1.06
    hist = summaries._QualityHistogram(1.07)
    for part in np.array_split(q, 7):
        hist.add(part)
    for p in summaries.PERCENTILES:
        assert abs(hist.percentile(p) - np.percentile(q, p)) < 1e-4
    assert hist.max == q.max()


def test_top_k_is_the_best_in_order(rng):
    q = np.round(rng.random(500), 2)  # ties on purpose
    fc = rng.random(500) < 0.6
    pts = rng.normal(size=(500, 2, 2))
    keep = summaries._TopK(7)
    for start in range(0, 500, 64):
        sl = slice(start, start + 64)
        keep.add(start, pts[sl], pts[sl], q[sl], fc[sl])
    idx = np.flatnonzero(fc)
    want = idx[np.lexsort((idx, -q[idx]))][:7]
    np.testing.assert_array_equal(keep.best.index, want)
    np.testing.assert_array_equal(keep.best.points, pts[want])


def test_slices_and_part_names():
    bounds = [devs.slice_bounds(10, i, 3) for i in range(3)]
    assert bounds == [(0, 3), (3, 6), (6, 10)]
    assert devs.part_path("a/r.npz", 1, 3) == Path("a/r.1-of-3.npz")
    assert devs.part_path("r.npz", 0, 1) == Path("r.npz")
    chunks = [(np.arange(k, k + 4), np.arange(k, k + 4)) for k in range(0, 12, 4)]
    got = list(pipeline._slice_chunks(iter(chunks), 3, 9))
    np.testing.assert_array_equal(np.concatenate([c["points"] for c in got]), np.arange(3, 9))
    got = list(pipeline._slice_chunks(iter(chunks), 1, 12, 5))
    assert [c["points"].tolist() for c in got] == [[1, 2, 3, 4, 5], [6, 7, 8, 9, 10], [11]]


def test_configure_cpu_devices_in_a_fresh_process(xla_cache):
    code = (
        "import grasp_jax.devices as p, jax; print(p.configure_cpu_devices(3)); "
        "print(len(jax.devices())); print(p.configure_cpu_devices(2))"
    )
    env = _subprocess_env(xla_cache)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["3", "3", "None"]
    env["XLA_FLAGS"] = "--xla_force_host_platform_device_count=1"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert out.stdout.split() == ["None", "1", "None"]


def test_run_rejects_bad_settings(glass, tmp_path):
    with pytest.raises(ValueError, match="num"):
        pipeline.run(glass, 0, 4)
    with pytest.raises(ValueError, match="fingers"):
        pipeline.run(glass, 10, 1)
    with pytest.raises(ValueError, match="mu"):
        pipeline.run(glass, 10, 4, mu=0.0)
    with pytest.raises(ValueError, match="does not exist"):
        pipeline.run(glass, 10, 4, out=tmp_path / "no" / "r.npz")


# ---------------------------------------------------------------------------------------------
# runs (one compiled size: chunks of CHUNK grasps, 4 fingers, 3D)


@pytest.fixture(scope="module")
def reference_run(glass, tmp_path_factory):
    """NUM grasps of the glass in two chunks, written to .npz."""
    out = tmp_path_factory.mktemp("ref") / "glass.npz"
    summary = pipeline.run(glass, NUM, 4, seed=3, chunk=CHUNK, out=out, object_spec="glass")
    arrays, meta = storage.read_results(out)
    return summary, arrays, meta


def test_run_matches_evaluate_and_summary(glass, reference_run):
    summary, arrays, meta = reference_run
    from grasp_jax import sampling

    points, normals = sampling.sample_grasps(glass, NUM, 4, seed=3)
    np.testing.assert_array_equal(arrays["points"], points)
    np.testing.assert_array_equal(arrays["normals"], normals)
    # Evaluated in the pipeline's chunks, padded as it pads them: the same compiled program.
    import jax

    size = max(CHUNK, pipeline.MIN_ROWS * len(jax.local_devices()))
    res = [gj.evaluate(pipeline._pad(points[s:s + CHUNK], size), pipeline._pad(normals[s:s + CHUNK], size),
                       mu=pipeline.DEFAULT_MU)[:CHUNK] for s in range(0, NUM, CHUNK)]
    np.testing.assert_array_equal(arrays["force_closure"], np.concatenate([r.force_closure for r in res]))
    np.testing.assert_array_equal(arrays["quality"], np.concatenate([r.quality for r in res]))
    fc = arrays["force_closure"]
    assert summary.num == NUM and summary.force_closure == fc.sum() > 0
    q = arrays["quality"][fc]
    for p, v in summary.quality_percentiles.items():
        assert abs(v - np.percentile(q, p)) < 1e-3
    assert summary.quality_max == q.max()
    assert summary.best.quality[0] == q.max()
    np.testing.assert_array_equal(summary.best.points[0], arrays["points"][summary.best.index[0]])
    for key in ("object", "mu", "edges", "fingers", "seed", "scheme", "num", "torque_test",
                "grasp_jax_version", "date"):
        assert key in meta
    assert (meta["object"], meta["num"], meta["seed"], meta["fingers"]) == ("glass", NUM, 3, 4)
    assert meta["grasp_jax_version"] == gj.__version__
    text = summary.format()
    assert "force-closure" in text and "grasps/s" in text and str(summary.output) in text
    assert f"best grasp     #{int(summary.best.index[0])} Q " in text
    listed = [line for line in summary.format(best=3).splitlines() if line.startswith("best grasps")]
    assert len(listed) == 1 and listed[0].count(" Q ") == min(3, len(summary.best))


def test_seeded_runs_repeat_and_seeds_differ(glass, reference_run, tmp_path):
    _, arrays, _ = reference_run
    again = tmp_path / "again.parquet"
    pipeline.run(glass, NUM, 4, seed=3, chunk=CHUNK, out=again)
    got, _ = storage.read_results(again)
    for name in FIELDS:
        np.testing.assert_array_equal(got[name], arrays[name])
    other = tmp_path / "other.npz"
    pipeline.run(glass, NUM, 4, seed=4, chunk=CHUNK, out=other)
    assert not np.array_equal(storage.read_results(other)[0]["points"], arrays["points"])


def test_chunked_equals_unchunked(glass, reference_run, tmp_path):
    _, arrays, _ = reference_run
    for chunk in (NUM, 700):  # one chunk; uneven chunks with a padded last one
        out = tmp_path / f"c{chunk}.npz"
        pipeline.run(glass, NUM, 4, seed=3, chunk=chunk, out=out)
        got, meta = storage.read_results(out)
        for name in FIELDS:
            np.testing.assert_array_equal(got[name], arrays[name], err_msg=f"{name}, chunk {chunk}")


def test_process_slices_concatenate_to_the_whole(glass, reference_run, tmp_path, monkeypatch):
    """Multi-host mode without a cluster: pretend to be process i of 3."""
    _, arrays, _ = reference_run
    parts = []
    for i in range(3):  # the pipeline's view of the job; the devices stay this process's own
        monkeypatch.setattr(devs, "process_slot", lambda i=i: (i, 3))
        summary = pipeline.run(glass, NUM, 4, seed=3, chunk=CHUNK, out=tmp_path / "p.npz", distributed=True)
        assert summary.output == tmp_path / f"p.{i}-of-3.npz"
        got, meta = storage.read_results(summary.output)
        assert meta["slice"] == [*devs.slice_bounds(NUM, i, 3), NUM]
        parts.append(got)
    for name in FIELDS:
        np.testing.assert_array_equal(np.concatenate([p[name] for p in parts]), arrays[name])


def test_score_file_round_trip(reference_run, tmp_path):
    summary, arrays, _ = reference_run
    out = tmp_path / "rescored.parquet"
    again = pipeline.score_file(summary.output, chunk=CHUNK, out=out)
    assert again.agree == NUM
    got, meta = storage.read_results(out)
    np.testing.assert_array_equal(got["force_closure"], arrays["force_closure"])
    np.testing.assert_array_equal(got["quality"], arrays["quality"])
    assert meta["source"] == str(Path(summary.output).resolve()) and meta["object"] == "glass"
    best, meta = summaries.best_in_file(out, top=3)
    np.testing.assert_array_equal(best.index, summary.best.index[:3])


def test_epsilon_baseline_on_a_polygon(tmp_path):
    objects = _objects()
    star = objects.load("star")
    out = tmp_path / "star.npz"
    summary = pipeline.run(star, 300, 3, seed=1, chunk=300, epsilon=True, out=out)
    arrays, meta = storage.read_results(out)
    np.testing.assert_allclose(meta["epsilon_origin"], star.center)
    assert meta["epsilon_torque_scale"] == pytest.approx(star.radius)
    eps, vol = gj.ferrari_canny(arrays["points"], arrays["normals"], mu=pipeline.DEFAULT_MU, num_edges=8,
                                origin=star.center, torque_scale=star.radius)
    np.testing.assert_array_equal(arrays["epsilon"], eps)
    np.testing.assert_array_equal(arrays["volume"], vol)
    # The baseline and Proposition 2 agree away from marginal grasps.
    assert summary.epsilon_disagree <= 3
    assert summary.epsilon_positive == (eps > pipeline.EPSILON_ZERO).sum()
    assert summary.epsilon_disagree == ((eps > pipeline.EPSILON_ZERO) != arrays["force_closure"]).sum()


def test_epsilon_round_off_is_not_counted_as_force_closure(tmp_path, monkeypatch):
    """On grasps exactly on the boundary of force-closure (contacts on parallel faces) qhull's
    epsilon is round-off, about 1e-17 (seen on pyvista_nut.ply); the summary must not count it as
    a force-closure verdict of the baseline that disagrees with Proposition 2."""
    # An antipodal pair, each contact doubled: every contact on the x axis, so no torque about it,
    # never force-closure; 4 contacts in 3D, the suite's common grasp shape (no program of its own).
    points = np.array([[[1.0, 0, 0], [-1.0, 0, 0], [1.0, 0, 0], [-1.0, 0, 0]]] * 4)
    np.savez(tmp_path / "pair.npz", points=points, normals=points)

    def round_off(points, normals, **kwargs):
        return np.full(len(points), 1.4e-17), np.zeros(len(points))

    monkeypatch.setattr(_stream, "ferrari_canny", round_off)  # the name the stream calls
    summary = pipeline.score_file(tmp_path / "pair.npz", epsilon=True, origin=[0, 0, 0], torque_scale=1.0)
    assert summary.force_closure == 0
    assert summary.epsilon_positive == 0 and summary.epsilon_disagree == 0


@pytest.mark.parametrize("devices", ["2"])
def test_two_cpu_devices_give_the_single_device_results(tmp_path, xla_cache, devices):
    """Sharding a chunk over two CPU devices changes nothing but the speed: the same verdicts,
    and Q equal to within the LP tolerance (the sharded program is compiled separately, so its
    rounding may differ in the last digits)."""
    outs = {}
    for count in ("1", devices):
        out = tmp_path / f"d{count}.npz"
        env = _subprocess_env(xla_cache, XLA_FLAGS=f"--xla_force_host_platform_device_count={count}")
        run = subprocess.run(
            [sys.executable, "-m", "grasp_jax", "sample", "glass", "--num", str(NUM), "--seed", "3",
             "--chunk", str(CHUNK), "--out", str(out), "--json"],
            env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path,
        )
        assert run.returncode == 0, run.stderr
        assert json.loads(run.stdout)["devices"] == int(count)
        outs[count] = storage.read_results(out)[0]
    a, b = outs["1"], outs[devices]
    np.testing.assert_array_equal(a["points"], b["points"])
    np.testing.assert_array_equal(a["force_closure"], b["force_closure"])
    np.testing.assert_array_equal(a["converged"], b["converged"])
    np.testing.assert_allclose(a["quality"], b["quality"], rtol=0, atol=1e-8)


def test_two_processes_on_one_host(reference_run, tmp_path, xla_cache):
    """The multi-host path for real, with two processes on this machine (one CPU device each):
    each scores its slice, and the two files concatenate to the single-process result."""
    import socket

    _, arrays, _ = reference_run
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    procs = []
    for i in range(2):
        env = _subprocess_env(xla_cache, JAX_COORDINATOR_ADDRESS=f"127.0.0.1:{port}",
                              JAX_NUM_PROCESSES="2", JAX_PROCESS_ID=str(i))
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "grasp_jax", "sample", "glass", "--num", str(NUM), "--seed", "3", "--chunk",
             str(CHUNK), "--devices", "1", "--out", "d.npz", "--quiet"],
            env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    for p in procs:
        _, err = p.communicate(timeout=300)
        assert p.returncode == 0, err
    parts = [storage.read_results(tmp_path / f"d.{i}-of-2.npz") for i in range(2)]
    assert [m["slice"] for _, m in parts] == [[0, NUM // 2, NUM], [NUM // 2, NUM, NUM]]
    for name in FIELDS:
        np.testing.assert_array_equal(np.concatenate([a[name] for a, _ in parts]), arrays[name])
