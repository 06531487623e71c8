"""The ``grasp-jax`` command line, run as a subprocess (``python -m grasp_jax``; the commands of one
test in one child process, ``grasp_jax_runs``).

Runs are small (2,000 grasps) and share one XLA compilation cache (the suite's, see
``conftest.py``), so only the first run of a session compiles, and none once the suite has run.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from grasp_jax import storage

NUM = "2000"


@pytest.fixture(scope="module")
def env(xla_cache):
    pytest.importorskip("grasp_jax.objects")
    pytest.importorskip("grasp_jax.sampling")
    e = dict(os.environ)
    e.pop("XLA_FLAGS", None)
    e["GRASP_JAX_CACHE"] = xla_cache
    e["PYTHONWARNINGS"] = "ignore::DeprecationWarning"
    return e


def grasp_jax(*args, env, cwd, timeout=300, check=True):
    out = subprocess.run([sys.executable, "-m", "grasp_jax", *map(str, args)], env=env, cwd=cwd,
                         capture_output=True, text=True, timeout=timeout)
    if check:
        assert out.returncode == 0, f"rc {out.returncode}\n{out.stdout}\n{out.stderr}"
        assert "Traceback" not in out.stderr
    return out


#: The child of :func:`grasp_jax_runs`: ``main`` of each command in turn, its output kept apart.
_RUNS = """
import contextlib, io, json, sys, traceback
from grasp_jax.cli import main
results = []
for args in json.loads(sys.argv[1]):
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        try:
            code = main(args)
        except BaseException:
            traceback.print_exc()
            code = -1
    results.append([code, stdout.getvalue(), stderr.getvalue()])
print("RESULTS" + json.dumps(results))
"""


def grasp_jax_runs(*commands, env, cwd, timeout=300):
    """Several ``grasp-jax`` commands one after another in one child process (``main`` of each in
    turn: the first as in a fresh process, the next ones without a process start and the loading
    of the programs again), each checked as :func:`grasp_jax` checks its process."""
    commands = [[str(a) for a in args] for args in commands]
    proc = subprocess.run([sys.executable, "-c", _RUNS, json.dumps(commands)], env=env, cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, f"rc {proc.returncode}\n{proc.stderr}"
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULTS")][-1]
    outs = []
    for args, (code, stdout, stderr) in zip(commands, json.loads(line[len("RESULTS"):])):
        assert code == 0, f"{args}: rc {code}\n{stdout}\n{stderr}"
        assert "Traceback" not in stderr, (args, stderr)
        outs.append(subprocess.CompletedProcess(args, code, stdout, stderr))
    return outs


@pytest.fixture(scope="module")
def sampled(env, tmp_path_factory):
    """``sample glass`` to .npz (with a figure) and to .parquet, same seed."""
    d = tmp_path_factory.mktemp("cli")
    npz, parquet = grasp_jax_runs(
        ("sample", "glass", "--num", NUM, "--seed", "5", "--out", "g.npz", "--plot", "g.png"),
        ("sample", "glass", "--num", NUM, "--seed", "5", "--out", "g.parquet", "--quiet"), env=env, cwd=d)
    return d, npz, parquet


def test_sample_writes_both_formats_with_metadata(sampled):
    d, npz, parquet = sampled
    a, meta_a = storage.read_results(d / "g.npz")
    b, meta_b = storage.read_results(d / "g.parquet")
    assert set(a) == {"points", "normals", "force_closure", "quality", "converged"}
    for name in a:
        np.testing.assert_array_equal(a[name], b[name])
    assert a["points"].shape == (2000, 4, 3)
    for meta in (meta_a, meta_b):
        assert meta["object"] == "glass" and meta["num"] == 2000 and meta["seed"] == 5
        assert meta["mu"] == 0.364 and meta["edges"] == 8 and meta["fingers"] == 4
        assert meta["scheme"] == "uniform" and meta["torque_test"] == "exact"
        assert "grasp_jax_version" in meta and "date" in meta
    # The summary: force-closure rate, Q percentiles, speed, output path; --quiet prints nothing.
    out = npz.stdout
    rate = 100 * a["force_closure"].mean()
    assert f"({rate:.1f}%)" in out and "grasps/s" in out and "p50" in out and "g.npz" in out
    assert parquet.stdout == ""
    assert (d / "g.png").stat().st_size > 10_000
    assert sorted(p.name for p in d.iterdir()) == ["g.npz", "g.parquet", "g.png"]


def test_score_round_trip_gives_the_same_verdicts(sampled, env):
    d, _, _ = sampled
    out, other = grasp_jax_runs(("score", "g.parquet", "--out", "rescored.npz", "--json"),
                                ("score", "g.npz", "--mu", "0.1", "--json"), env=env, cwd=d)
    summary = json.loads(out.stdout)
    assert summary["agree"] == 2000
    a, _ = storage.read_results(d / "g.parquet")
    b, meta = storage.read_results(d / "rescored.npz")
    np.testing.assert_array_equal(a["force_closure"], b["force_closure"])
    np.testing.assert_array_equal(a["quality"], b["quality"])
    assert meta["mu"] == 0.364 and meta["object"] == "glass"  # taken from the file
    # Other settings give other verdicts.
    assert json.loads(other.stdout)["force_closure"] < a["force_closure"].sum()


def test_soft_contacts_from_the_command_line(env, tmp_path):
    """Two soft fingers hold grasps of a sphere (hard ones never do); score takes the contact model
    from the file's metadata, and --contact hard on the same file finds no force-closure."""
    _, soft, hard = grasp_jax_runs(
        ("sample", "sphere", "--fingers", "2", "--num", NUM, "--contact", "soft", "--patch-radius", "0.01",
         "--out", "soft.npz", "--quiet"),
        ("score", "soft.npz", "--json"), ("score", "soft.npz", "--contact", "hard", "--json"), env=env, cwd=tmp_path)
    a, meta = storage.read_results(tmp_path / "soft.npz")
    assert meta["contact"] == "soft" and meta["torsion"] == pytest.approx(2 / 3 * 0.364 * 0.01)
    assert 0.02 < a["force_closure"].mean() < 0.5
    assert json.loads(soft.stdout)["agree"] == 2000
    assert json.loads(hard.stdout)["force_closure"] == 0


def test_score_a_plain_user_file(env, tmp_path):
    rng = np.random.default_rng(0)
    p = rng.normal(size=(300, 3, 2))
    np.savez_compressed(tmp_path / "mine.npz", points=p, normals=p / np.linalg.norm(p, axis=-1, keepdims=True))
    out = grasp_jax("score", "mine.npz", "--json", env=env, cwd=tmp_path)
    assert json.loads(out.stdout)["num"] == 300


def test_show_draws_the_best_grasps(sampled, env):
    d, _, _ = sampled
    out, _ = grasp_jax_runs(("show", "g.npz", "--top", "3"), ("show", "g.parquet", "--plot", "best.png"), env=env,
                            cwd=d)
    assert (d / "g.png").exists()
    a, _ = storage.read_results(d / "g.npz")
    best = int(np.argmax(np.where(a["force_closure"], a["quality"], -1)))
    assert out.stdout.splitlines()[1].split()[:2] == ["1", str(best)]
    assert (d / "best.png").stat().st_size > 10_000


def test_polygon_with_a_hole_round_trips(env, tmp_path):
    """--hole cuts a hole in a CSV polygon; score and show find it again from the metadata."""
    (tmp_path / "square.csv").write_text("0,0\n4,0\n4,4\n0,4\n")
    (tmp_path / "hole.csv").write_text("1,1\n3,1\n3,3\n1,3\n")
    _, _, out = grasp_jax_runs(
        ("sample", "square.csv", "--hole", "hole.csv", "--fingers", "3", "--num", NUM, "--quiet", "--out", "sq.npz"),
        ("show", "sq.npz", "--plot", "sq.png"), ("score", "sq.npz", "--epsilon", "--json"), env=env, cwd=tmp_path)
    a, meta = storage.read_results(tmp_path / "sq.npz")
    assert meta["object_holes"] == [str(tmp_path / "hole.csv")]
    # a quarter of the boundary length is the hole's: its contacts are inside the exterior
    inner = np.all((a["points"] > 0.5) & (a["points"] < 3.5), axis=-1)
    assert 0.15 < inner.mean() < 0.35
    assert json.loads(out.stdout)["agree"] == 2000
    # files are published with the usual permissions (0666 less the umask), not mkstemp's 0600
    mask = os.umask(0o022)
    os.umask(mask)
    for name in ("sq.npz", "sq.png"):
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o666 & ~mask
    # a hole in a built-in object: in MISTAKES (main() in this process; its messages in a real process below)


def test_demo_and_help(env, tmp_path, in_process, capsys):
    out = grasp_jax("--num", "2000", env=env, cwd=tmp_path)  # no command: the demo
    assert "glass" in out.stdout and "force-closure" in out.stdout
    assert list(tmp_path.iterdir()) == []  # the demo writes nothing unasked
    # The help in this process (argparse prints it and exits 0): the demo above is the real process.
    texts = []
    for args in (["--help"], ["sample", "--help"]):
        with pytest.raises(SystemExit) as exit_info:
            in_process(args)
        assert exit_info.value.code == 0
        texts.append(capsys.readouterr().out)
    assert "examples:" in texts[0] and "sample" in texts[0]
    assert "(default: 10000)" in texts[1] and "(default: 0.364)" in texts[1]


MISTAKES = [
    (["sample", "glass", "--num", "-3"], "--num"),
    (["sample", "glass", "--num", "1.5"], "--num"),
    (["sample", "glass", "--mu", "0"], "--mu"),
    (["sample", "glass", "--fingers", "1"], "--fingers"),
    (["sample", "glass", "--edges", "2"], "--edges"),
    (["sample", "no_such_object"], "no_such_object"),
    (["sample", "missing.obj"], "missing.obj"),
    (["sample", "garbage.obj"], "garbage.obj"),
    (["sample", "glass", "--out", "r.csv"], "r.csv"),
    (["sample", "glass", "--out", "no/dir/r.npz"], "does not exist"),
    (["sample", "glass", "--plot", "no/dir/f.png"], "does not exist"),
    (["score", "missing.npz"], "missing.npz"),
    (["score", "garbage.obj"], "must end in"),
    (["score", "empty.npz"], "points"),
    (["show", "missing.parquet"], "missing.parquet"),
    (["frobnicate"], "frobnicate"),
    (["sample"], "OBJECT"),
    (["sample", "."], "is a directory"),
    (["sample", "shape.csv", "--hole", "missing.csv"], "missing.csv"),
    (["sample", "glass", "--hole", "hole.csv"], "only be cut from a polygon"),
    (["sample", "sphere", "--contact", "soft"], "needs --torsion"),
    (["sample", "sphere", "--torsion", "0.01"], "add --contact soft"),
    (["sample", "sphere", "--contact", "soft", "--torsion", "-1"], "--torsion"),
    (["sample", "sphere", "--contact", "soft", "--torsion", "0.1", "--patch-radius", "0.1"], "not both"),
    (["sample", "quad", "--contact", "soft", "--torsion", "0.1"], "3D only"),
    (["sample", "sphere", "--sigma-pos", "0.1"], "add --robust N"),
    (["sample", "sphere", "--robust", "10"], "needs noise"),
    (["sample", "sphere", "--robust", "1", "--sigma-pos", "0.1"], "--robust"),
    (["sample", "sphere", "--robust", "10", "--sigma-pos", "-1"], "--sigma-pos"),
    (["sample", "sphere", "--robust", "10", "--mu-range", "1.2,0.8"], "--mu-range"),
    (["sample", "sphere", "--robust", "10", "--mu-range", "0.8,1.2", "--mu-sigma", "0.1"], "not both"),
    (["sample", "sphere", "--robust", "10", "--sigma-pose", "0.1,x"], "--sigma-pose"),
    (["score", "empty.npz", "--robust", "10"], "needs noise"),
]


def _check_mistake(args, expect, code, stdout, stderr):
    lines = stderr.strip().splitlines()
    assert code == 2, (args, stderr)
    assert len(lines) == 1, (args, stderr)
    assert lines[0].startswith("grasp-jax: error: "), (args, stderr)
    assert expect in lines[0], (args, stderr)
    assert stdout == ""


@pytest.fixture
def mistakes_dir(tmp_path):
    (tmp_path / "garbage.obj").write_text("this is not a mesh\n\x00\x01")
    np.savez(tmp_path / "empty.npz", other=np.zeros(2))
    return tmp_path


def test_user_mistakes_exit_2_with_one_line(env, mistakes_dir, monkeypatch, capsys):
    """Every mistake through main() in this process; the same, in real processes, below."""
    import jax

    from grasp_jax.cli import main

    jax.devices()  # main() must not change this process's device count (XLA_FLAGS) ...
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", ""))  # ... nor leave it set
    monkeypatch.chdir(mistakes_dir)
    monkeypatch.setenv("GRASP_JAX_CACHE", "off")
    for args, expect in MISTAKES:
        code = main(args)
        out = capsys.readouterr()
        _check_mistake(args, expect, code, out.out, out.err)
    assert sorted(p.name for p in mistakes_dir.iterdir()) == ["empty.npz", "garbage.obj"]


def test_user_mistakes_in_a_process(env, mistakes_dir):
    # One mistake of each kind: the parser's, a third-party loader's, an output path's, the command
    # name's (each process imports JAX: 3 s); every mistake: test_user_mistakes_exit_2_with_one_line.
    cases = [MISTAKES[k] for k in (0, 7, 9, 15)]
    procs = [
        (args, expect, subprocess.Popen([sys.executable, "-m", "grasp_jax", *args], env=env, cwd=mistakes_dir,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
        for args, expect in cases
    ]
    for args, expect, proc in procs:
        stdout, stderr = proc.communicate(timeout=300)
        assert "Traceback" not in stderr
        _check_mistake(args, expect, proc.returncode, stdout, stderr)
    assert sorted(p.name for p in mistakes_dir.iterdir()) == ["empty.npz", "garbage.obj"]


def _start_long_run(env, cwd, out):
    """The run, with SIGINT handled by default even where the suite itself was started with it
    ignored (a background job of a non-interactive shell), as in a user's terminal: an ignored
    signal stays ignored across ``exec``, and Python installs its KeyboardInterrupt handler only
    over the default action. Set in this process around the start, not in a ``preexec_fn``: forking
    a process that runs JAX's threads warns (an error here) and may deadlock the child."""
    ignored = signal.getsignal(signal.SIGINT) == signal.SIG_IGN
    if ignored:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
    try:
        return subprocess.Popen(
            [sys.executable, "-m", "grasp_jax", "sample", "glass", "--num", "5000000", "--chunk", NUM,
             "--out", out, "--quiet"],
            env=env, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
    finally:
        if ignored:
            signal.signal(signal.SIGINT, signal.SIG_IGN)


def _wait_for_data(proc, directory: Path, timeout=120):
    """Until the run has written its first chunk to a temporary file."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        sizes = [f.stat().st_size for f in directory.rglob("*") if f.is_file()]
        if sizes and max(sizes) > 0:
            return
        time.sleep(0.2)
    proc.kill()
    pytest.fail("the run wrote nothing")


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGKILL, -9)])
def test_interrupted_run_leaves_no_output(env, tmp_path, sig, code):
    proc = _start_long_run(env, tmp_path, "big.npz" if sig != signal.SIGTERM else "big.parquet")
    try:
        _wait_for_data(proc, tmp_path)
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:  # the test failed or was interrupted: no 5-million-grasp run left behind
            proc.kill()
            proc.communicate()
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr
    names = [p.name for p in tmp_path.iterdir()]
    assert "big.npz" not in names and "big.parquet" not in names
    if sig != signal.SIGKILL:  # a clean exit removes its temporary files too, and says why
        assert names == []
        word = "interrupted" if sig == signal.SIGINT else "terminated"
        assert stderr.strip().splitlines() == [f"grasp-jax: {word}"]
