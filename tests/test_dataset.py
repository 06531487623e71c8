"""``grasp-jax dataset``: a Parquet dataset partitioned by object, resumed after a kill with the same
rows, two shards equal to one run, a broken mesh recorded as failed among good ones, bad input, hand grasps.

Small: three meshes of a few hundred triangles, 300 grasps each, robust labels of 4 samples; the
built-in hand's grasps of two meshes, 8 starts x 10 steps."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pyarrow.dataset as pads
import pytest

from grasp_jax import dataset, pipeline
from grasp_jax._robust import Noise

from test_cli import env, grasp_jax  # noqa: F401 - the fixture and the runner

NUM = 300
ROBUST = pipeline.RobustLabels(Noise(position=0.02, friction=(0.8, 1.2)), samples=4, margin=False)
SETTINGS = dict(num=NUM, fingers=4, seed=1, robust=ROBUST)


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    import trimesh

    d = tmp_path_factory.mktemp("meshes")
    trimesh.creation.box((0.06, 0.04, 0.03)).export(d / "a_box.stl")
    trimesh.creation.icosphere(2, 0.03).export(d / "b_ball.obj")
    trimesh.creation.cylinder(0.02, 0.08, sections=24).export(d / "c_can.ply")
    (d / "notes.txt").write_text("not a mesh: skipped by suffix\n")
    return d


@pytest.fixture(scope="module")
def whole(meshes, tmp_path_factory):
    """One uninterrupted run over the three meshes, read back."""
    out = tmp_path_factory.mktemp("whole") / "ds"
    summary = dataset.build(meshes, out, **SETTINGS)
    assert summary.done == ["a_box", "b_ball", "c_can"] and not summary.failed
    return out, _rows(out)


def _rows(out):
    table = pads.dataset(out, format="parquet", partitioning="hive").to_table()  # no grasp_jax needed
    names = np.asarray(table.column("object").to_pylist())
    order = np.argsort(names, kind="stable")
    return {c: np.asarray(table.column(c).to_pylist())[order] for c in table.column_names}


def _assert_same_rows(a, b):
    assert set(a) == set(b)
    for name in a:
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)


def test_layout_manifest_and_columns(whole, meshes):
    out, rows = whole
    assert sorted(p.name for p in out.iterdir()) == [".lock", "_manifest.json", "_objects", "object=a_box",
                                                     "object=b_ball", "object=c_can"]
    assert len(rows["object"]) == 3 * NUM and set(rows["object"]) == {"a_box", "b_ball", "c_can"}
    assert {"points", "normals", "force_closure", "quality", "p_fc", "q_mean", "q_low"} <= set(rows)
    assert rows["points"].shape == (3 * NUM, 4, 3)
    manifest = json.loads((out / "_manifest.json").read_text())
    assert manifest["config"]["num"] == NUM and manifest["config"]["robust"]["samples"] == 4
    assert manifest["versions"]["grasp_jax"] and manifest["versions"]["jax"]
    assert manifest["objects_done"] == 3 and manifest["grasps"] == 3 * NUM
    box = manifest["objects"]["a_box"]
    assert box["status"] == "done" and box["num"] == NUM and box["part"] == "object=a_box/part.parquet"
    fc = rows["force_closure"][rows["object"] == "a_box"]
    assert box["force_closure"] == fc.sum() and 0 <= box["p_fc_mean"] <= 1
    assert dataset.read(out).num_rows == 3 * NUM


def test_two_shards_equal_one_run(whole, meshes, tmp_path):
    out = tmp_path / "ds"
    first = dataset.build(meshes, out, shard=(0, 2), **SETTINGS)
    second = dataset.build(meshes, out, shard=(1, 2), **SETTINGS)
    assert first.done == ["a_box", "c_can"] and second.done == ["b_ball"]
    _assert_same_rows(_rows(out), whole[1])
    assert json.loads((out / "_manifest.json").read_text())["objects_done"] == 3


def test_resume_after_a_partial_run(whole, meshes, tmp_path):
    listed = tmp_path / "two.txt"
    listed.write_text(f"# the first two\n{meshes / 'a_box.stl'}\n\n{meshes / 'b_ball.obj'}  # a ball\n")
    out = tmp_path / "ds"
    assert dataset.build(listed, out, **SETTINGS).done == ["a_box", "b_ball"]
    # what a kill -9 leaves: a temporary part, and a part published without its record
    (out / "object=c_can").mkdir()
    (out / "object=c_can" / ".part.parquet.x.tmp").write_bytes(b"half")
    (out / "_objects" / "b_ball.json").unlink()
    again = dataset.build(meshes, out, **SETTINGS)
    assert again.skipped == ["a_box"] and again.done == ["b_ball", "c_can"]
    assert not list((out / "object=c_can").glob(".*.tmp"))
    _assert_same_rows(_rows(out), whole[1])
    with pytest.raises(dataset.DatasetError, match="another configuration .*differs in num"):
        dataset.build(meshes, out, **{**SETTINGS, "num": NUM + 1})


def test_a_broken_mesh_is_recorded_as_failed(meshes, tmp_path):
    folder = tmp_path / "objects"
    folder.mkdir()
    for f in ("a_box.stl", "b_ball.obj"):
        (folder / f).write_bytes((meshes / f).read_bytes())
    (folder / "b_broken.obj").write_text("this is not a mesh\n\x00\x01")
    out = tmp_path / "ds"
    summary = dataset.build(folder, out, num=NUM, fingers=4)
    assert summary.done == ["a_box", "b_ball"] and list(summary.failed) == ["b_broken"]
    assert "b_broken.obj" in summary.failed["b_broken"]
    manifest = json.loads((out / "_manifest.json").read_text())
    assert manifest["objects"]["b_broken"]["status"] == "failed" and manifest["objects_failed"] == 1
    assert not (out / "object=b_broken").exists()
    text = summary.format()
    assert "failed" in text and "2 objects done" in text
    again = dataset.build(folder, out, num=NUM, fingers=4)  # done objects skipped, the failed one tried again
    assert again.skipped == ["a_box", "b_ball"] and list(again.failed) == ["b_broken"]


def test_killed_and_resumed_from_the_command_line(whole, meshes, env, tmp_path):  # noqa: F811
    args = ["dataset", meshes, "--out", "ds", "--num", NUM, "--seed", "1", "--robust", "4", "--sigma-pos", "0.02",
            "--mu-range", "0.8,1.2", "--robust-seed", "0", "--no-margin", "--devices", "1", "--quiet"]
    proc = subprocess.Popen([sys.executable, "-m", "grasp_jax", *map(str, args)], env=env, cwd=tmp_path,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    records = tmp_path / "ds" / "_objects"
    deadline = time.monotonic() + 240
    while proc.poll() is None and time.monotonic() < deadline and not list(records.glob("*.json")):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    done_before = len(list(records.glob("*.json")))
    assert done_before >= 1  # (1 when this was written: killed after the first object)
    out = grasp_jax(*args[:-1], "--json", env=env, cwd=tmp_path)
    summary = json.loads(out.stdout)
    assert len(summary["skipped"]) == done_before and len(summary["done"]) == 3 - done_before
    rows, ref = _rows(tmp_path / "ds"), whole[1]  # (_rows reads the folder with pyarrow: the figure is skipped)
    assert (tmp_path / "ds" / dataset.FIGURE).stat().st_size > 5_000  # every object: rates, Q, P(FC)
    for name in ref:  # another process, one device: the same rows (Q within the LP's tolerance)
        if ref[name].dtype.kind == "f":
            np.testing.assert_allclose(rows[name], ref[name], rtol=1e-7, atol=1e-10, err_msg=name)
        else:
            np.testing.assert_array_equal(rows[name], ref[name], err_msg=name)


def test_bad_input(tmp_path, usage):
    (tmp_path / "empty").mkdir()
    with pytest.raises(dataset.DatasetError, match="holds no mesh files"):
        dataset.list_objects(tmp_path / "empty")
    with pytest.raises(dataset.DatasetError, match="neither a folder"):
        dataset.list_objects(tmp_path / "missing")
    bad = tmp_path / "bad.txt"
    bad.write_text("sphere -2\n")
    with pytest.raises(dataset.DatasetError, match="scale must be a number > 0"):
        dataset.list_objects(bad)
    bad.write_text("# nothing\n\n")
    with pytest.raises(dataset.DatasetError, match="lists no objects"):
        dataset.list_objects(bad)
    bad.write_text("a/mug.obj\nb/mug.obj\n")
    with pytest.raises(dataset.DatasetError, match="two objects would be named 'mug'"):
        dataset.list_objects(bad)
    bad.write_text("sphere\nbox 0.5\n")
    assert dataset.list_objects(bad) == [dataset.ObjectEntry("sphere", "sphere"), dataset.ObjectEntry("box", "box", 0.5)]
    for text in ("2/2", "1", "a/b", "0/0"):
        with pytest.raises(dataset.DatasetError, match="shard must be i/N"):
            dataset.parse_shard(text)
    assert dataset.parse_shard("1/4") == (1, 4)
    assert dataset.shard_from_environment({}) is None
    slurm = {"SLURM_ARRAY_TASK_ID": "7", "SLURM_ARRAY_TASK_MIN": "5", "SLURM_ARRAY_TASK_COUNT": "4"}
    assert dataset.shard_from_environment(slurm) == (2, 4)
    with pytest.raises(dataset.DatasetError, match="SLURM array task 9 of 4"):
        dataset.shard_from_environment({"SLURM_ARRAY_TASK_ID": "9", "SLURM_ARRAY_TASK_COUNT": "4"})
    out = usage("dataset", "empty", "--out", "ds")
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and "holds no mesh files" in out.stderr
    assert not (tmp_path / "ds").exists()
    out = usage("dataset", "empty", "--out", "ds", "--collision")
    assert out.returncode == 2 and "--collision describes a gripper: add --gripper parallel-jaw" in out.stderr
    out = usage("dataset", "empty", "--out", "ds", "--gripper", "parallel-jaw")
    assert out.returncode == 2 and "needs --max-width" in out.stderr
    from grasp_jax.grippers import ParallelJaw

    with pytest.raises(dataset.DatasetError, match="2 contacts"):
        dataset.build(tmp_path, tmp_path / "ds", gripper=ParallelJaw(0.1), fingers=3)
    with pytest.raises(dataset.DatasetError, match="give a gripper too"):
        dataset.build(tmp_path, tmp_path / "ds", collision=True)


def test_parallel_jaw_dataset(meshes, tmp_path):
    """A dataset of parallel-jaw grasps (Dex-Net / GraspNet style): jaw poses, soft contacts, critical
    friction and GraspNet's friction label per grasp, robust labels with the jaws cast again; the
    same rows as ``pipeline.run`` on each object alone; resumed only with the same gripper."""
    from grasp_jax.grippers import ParallelJaw

    jaw = ParallelJaw(0.1)
    settings = dict(num=200, seed=3, mu=0.5, contact="soft", torsion=0.002, gripper=jaw,
                    robust=pipeline.RobustLabels(Noise(position=0.02), samples=4, margin=False))
    out = tmp_path / "ds"
    summary = dataset.build(meshes, out, **settings)
    assert summary.done == ["a_box", "b_ball", "c_can"]
    rows = _rows(out)
    assert {"center", "axis", "approach", "width", "jaw_status", "critical_mu", "friction_label", "p_fc"} <= set(rows)
    assert rows["points"].shape == (600, 2, 3) and np.all(rows["width"] <= 0.1)
    config = json.loads((out / "_manifest.json").read_text())["config"]
    assert config["fingers"] == 2 and config["scheme"] == "antipodal" and config["critical"] is True
    assert config["gripper"]["max_width"] == 0.1 and config["collision"] is False
    record = summary.rows["b_ball"]
    assert record["critical_mu_p50"] is not None and "mu* p50" in summary.format()
    alone = {k: v for k, v in settings.items() if k != "num"}
    ball = pipeline.run(dataset.load_entry(dataset.list_objects(meshes)[1]), 200, 2, out=tmp_path / "ball.parquet",
                        **alone)
    assert ball.force_closure == record["force_closure"]
    alone = pads.dataset(tmp_path / "ball.parquet", format="parquet").to_table()
    mine = rows["object"] == "b_ball"
    for name in ("force_closure", "quality", "critical_mu", "p_fc", "jaw_status"):
        np.testing.assert_array_equal(np.asarray(alone.column(name).to_pylist()), rows[name][mine], err_msg=name)
    with pytest.raises(dataset.DatasetError, match="differs in collision, critical, fingers, gripper"):
        dataset.build(meshes, out, num=200, seed=3, mu=0.5, contact="soft", torsion=0.002,
                      robust=settings["robust"])
    assert dataset.build(meshes, out, **settings).skipped == ["a_box", "b_ball", "c_can"]
