"""The dtype rules of ``grasp_jax._precision``: no global configuration, float64 scoped to the call,
float32 in float32, traced inputs in the caller's dtype.

The suite runs with x64 on (``conftest.py``), so a float32 program is checked in a fresh
subprocess, where nothing has turned it on.
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import textwrap
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _grasps import MU, grasps, sample_box, sample_cylinder_side, sample_sphere

import grasp_jax as gj
from grasp_jax import _precision, reference

_FLOAT32_PROGRAM = textwrap.dedent(
    r"""
    import contextlib, json, sys, warnings
    warnings.simplefilter("error")
    import jax, jax.numpy as jnp, numpy as np

    out = {}
    before = dict(jax.config.values)
    f32 = jax.jit(lambda x: jnp.sin(x) * 2.0)
    out["before"] = [str(jnp.ones(3).dtype), str(f32(np.ones(3)).dtype)]

    import grasp_jax as gj
    out["changed_by_import"] = sorted(k for k, v in jax.config.values.items() if before.get(k) != v)

    # Small 2D grasps on a circle and one-pass budgets: the cheapest programs to compile.
    t = np.random.default_rng(0).uniform(0, 2 * np.pi, size=(40, 3))
    p = np.stack([np.cos(t), np.sin(t)], axis=-1)
    r64 = gj.evaluate(p, p, mu=0.364, iterations=30)
    r32 = gj.evaluate(p.astype(np.float32), p.astype(np.float32), mu=0.364, iterations=30)
    out["evaluate"] = [str(r64.quality.dtype), str(r32.quality.dtype), str(r64.certificate.dtype)]
    out["fc_equal"] = bool(np.array_equal(np.asarray(r64.force_closure), np.asarray(r32.force_closure)))
    out["quality"] = str(gj.quality(p, p, mu=0.364).dtype)
    out["min_weight"] = str(gj.min_weight(p, p, mu=0.364).dtype)
    out["central_axis"] = str(gj.central_axis(np.ones(3)).pitch.dtype)
    # Under the caller's transformations the library computes in the caller's (float32) dtype.
    # The dtype is fixed when the function is traced: eval_shape traces as jit does and compiles
    # nothing (jit compiled two programs here, 13 s; op by op, a program per operation).
    out["traced"] = str(jax.eval_shape(lambda x: gj.quality(x, x, mu=0.364), p[:3]).dtype)
    out["grad"] = str(jax.eval_shape(jax.grad(lambda x: gj.quality(x, p[0], mu=0.364)), p[0]).dtype)

    out["changed_by_calls"] = sorted(k for k, v in jax.config.values.items() if before.get(k) != v)
    out["after"] = [str(jnp.ones(3).dtype), str(f32(np.ones(3)).dtype), str(jnp.asarray(np.ones(2)).dtype)]

    # float64 asked for and not to be had: one clear error.
    jax.enable_x64 = lambda value=True: contextlib.nullcontext()
    try:
        gj.evaluate(p, p, mu=0.364, iterations=30)
        out["unavailable"] = None
    except TypeError as exc:
        out["unavailable"] = [type(exc).__name__, str(exc)]
    print("RESULT" + json.dumps(out))
    """
)


@pytest.fixture(scope="module")
def float32_program():
    env = {k: v for k, v in os.environ.items() if k != "JAX_ENABLE_X64"}
    env["JAX_PLATFORMS"] = "cpu"
    proc = subprocess.run(
        [sys.executable, "-c", _FLOAT32_PROGRAM], capture_output=True, text=True, env=env, timeout=300, check=False
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    line = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT")][-1]
    return json.loads(line[len("RESULT"):])


def test_import_changes_no_configuration(float32_program):
    assert float32_program["before"] == ["float32", "float32"]
    assert float32_program["changed_by_import"] == []


def test_float32_program_stays_float32(float32_program):
    assert float32_program["changed_by_calls"] == []
    assert float32_program["after"] == ["float32", "float32", "float32"]


def test_concrete_float64_is_scoped_float64(float32_program):
    assert float32_program["evaluate"] == ["float64", "float32", "float64"]
    assert float32_program["fc_equal"]
    for name in ("quality", "min_weight", "central_axis"):
        assert float32_program[name] == "float64", name


def test_traced_inputs_keep_the_callers_dtype(float32_program):
    assert float32_program["traced"] == "float32"
    assert float32_program["grad"] == "float32"


def test_float64_unavailable_is_one_clear_error(float32_program):
    name, message = float32_program["unavailable"]
    assert name == "Float64Unavailable"
    assert "float64" in message and "float32" in message


# ---------------------------------------------------------------------------------------------
# In this process (x64 on): the promotion rules.


def _grasps3(count=8, seed=0):
    return grasps(sample_sphere, count, 4, np.random.default_rng(seed))


@pytest.mark.parametrize(
    "dtypes, expected",
    [
        ((np.float64, np.float64), np.float64),
        ((np.float32, np.float32), np.float32),
        ((np.float32, np.float64), np.float64),
        ((np.int64, np.float32), np.float64),
        ((np.float16, np.float16), np.float32),
    ],
)
def test_working_dtype(dtypes, expected):
    assert _precision.working_dtype(*dtypes, traced=False) == expected


def test_result_dtypes_follow_the_inputs():
    p, n = _grasps3()
    for dt, expected in ((np.float64, jnp.float64), (np.float32, jnp.float32), (np.float16, jnp.float32)):
        ev = gj.evaluate(p.astype(dt), n.astype(dt), mu=MU)
        for name in ("quality", "delta", "torque_margin", "certificate"):
            assert getattr(ev, name).dtype == expected, (dt, name)
        assert ev.force_closure.dtype == bool and ev.quality_status.dtype == jnp.int8
    assert gj.evaluate(np.round(p * 4), n, mu=MU).quality.dtype == jnp.float64  # integer points


def test_scope_is_left_after_the_call():
    p, n = _grasps3()
    with jax.enable_x64(False):
        ev = gj.evaluate(p, n, mu=MU)
        assert ev.quality.dtype == np.float64
        assert not jax.config.jax_enable_x64
        assert jnp.ones(2).dtype == jnp.float32
    assert jax.config.jax_enable_x64


def test_float64_scope_nests():
    with jax.enable_x64(False):
        with _precision.float64_scope():
            assert jnp.ones(2).dtype == jnp.float64
            with _precision.float64_scope():
                assert jnp.ones(2).dtype == jnp.float64
            assert jnp.ones(2).dtype == jnp.float64
        assert jnp.ones(2).dtype == jnp.float32


# ---------------------------------------------------------------------------------------------
# float32 accuracy (the full 100,000-grasp table: experiments/float32_accuracy.py).

BAND = 1e-4

#: A box grasp whose only equilibrium is the first contact alone (see the test below).
UNFINISHED_GRASP = (
    np.array([[0.13945439457893372, 0.6000000238418579, -0.17477265000343323],
              [0.2870014011859894, 0.24085910618305206, 0.4000000059604645],
              [-0.9510809183120728, -0.6000000238418579, 0.02870021015405655],
              [-0.2120772749185562, -0.6000000238418579, -0.38295602798461914]], np.float32),
    np.array([[0, 1, 0], [0, 0, 1], [0, -1, 0], [0, -1, 0]], np.float32),
)


def _float64_grasps() -> dict:
    """``{name: (points, normals)}``: the grasps whose float64 results the float32 tests compare
    with (float64 arrays)."""
    out = {name: grasps(sampler, count, 4, np.random.default_rng(seed))
           for name, sampler, count, seed in (("box", sample_box, 2000, 5), ("sphere", sample_sphere, 2000, 6),
                                              ("cylinder", sample_cylinder_side, 300, 27))}
    out["unfinished"] = tuple(a.astype(np.float64) for a in UNFINISHED_GRASP)
    return out


FLOAT64_FIELDS = ("delta", "torque_margin", "equilibrium", "force_closure", "quality")


@pytest.fixture(scope="module")
def float64_results():
    """``{name: {field: array}}``: ``evaluate``'s float64 results on :func:`_float64_grasps` (the
    float64 program is the one the other tests use). In a child of
    ``test_float32_under_a_narrower_instruction_set`` they are read from the parent's file: the
    child checks float32 programs, and compiling the float64 one too cost it 12 s."""
    cases = _float64_grasps()
    path = os.environ.get(_FLOAT64_FILE)
    if path:
        with np.load(path) as f:
            for name, (p, n) in cases.items():  # the same grasps as the parent's
                np.testing.assert_array_equal(f[f"{name}.points"], p)
                np.testing.assert_array_equal(f[f"{name}.normals"], n)
            return {name: {field: f[f"{name}.{field}"] for field in FLOAT64_FIELDS} for name in cases}
    out = {}
    for name, (p, n) in cases.items():
        ev = gj.evaluate(p, n, mu=MU)
        out[name] = {"points": p, "normals": n, **{field: np.asarray(getattr(ev, field)) for field in FLOAT64_FIELDS}}
    return out


@pytest.fixture(scope="module")
def float32_vs_float64(float64_results):
    """2,000 random 4-finger grasps each of the box and the sphere: float32 against float64, no
    float64 anywhere on the float32 path."""
    out = {}
    cases = _float64_grasps()
    for name in ("box", "sphere"):
        p, n = cases[name]
        e64 = float64_results[name]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # unconverged LPs, counted below
            e32 = gj.evaluate(p.astype(np.float32), n.astype(np.float32), mu=np.float32(MU))
        assert e32.quality.dtype == jnp.float32 and e32.delta.dtype == jnp.float32
        delta, tm = np.asarray(e64["delta"]), np.asarray(e64["torque_margin"])
        clear = ((delta > -BAND) & (tm > -BAND)) == ((delta > BAND) & (tm > BAND))
        bounded = np.asarray(e32.quality_status) == gj.Status.BOUNDED
        out[name] = {
            # BOUNDED: unfinished, but weak duality proved delta* < 0 (a bound float64 must respect).
            "bounded_wrong": int(np.sum(bounded & (np.asarray(e64["equilibrium"])
                                                   | (delta > np.asarray(e32.delta, np.float64) + 1e-6)))),
            "disagree": int(np.sum(clear & (np.asarray(e32.force_closure) != np.asarray(e64["force_closure"])))),
            "dq": np.abs(np.asarray(e32.quality, np.float64) - np.asarray(e64["quality"])),
            "unconverged": int(np.sum(~e32.converged)),
        }
    return out


def test_float32_verdicts_and_quality(float32_vs_float64):
    """What holds today (a regression bound): equal verdicts outside the band on the box, and Q
    within 1e-4 on 99.5% of the grasps of both shapes."""
    assert float32_vs_float64["box"]["disagree"] == 0
    for name, r in float32_vs_float64.items():
        assert r["bounded_wrong"] == 0, name
        assert np.mean(r["dq"] <= 1e-4) >= 0.995, name
        assert r["unconverged"] <= 0.02 * len(r["dq"]), name


def test_float32_unfinished_quality_lp_bounded_by_its_dual(float64_results):
    """A box grasp whose only equilibrium is the first contact alone (delta* = -1, an ill-posed LP):
    in float32 its quality LP ends unfinished after the full budget, and the dual of its best
    iterate proves delta* < 0 (``BOUNDED``): not force-closure, Q = 0, converged, with a valid
    certificate, instead of an unconverged grasp."""
    p, n = UNFINISHED_GRASP
    ev = gj.evaluate(p, n, mu=np.float32(MU))
    assert ev.quality_status in (gj.Status.BOUNDED, gj.Status.OPTIMAL)  # BOUNDED on this CPU
    assert ev.converged and not ev.force_closure and ev.quality == 0.0
    assert ev.delta < -1e-4 and ev.delta >= float64_results["unfinished"]["delta"] - 1e-6
    w = reference.wrenches(p.astype(np.float64), n.astype(np.float64), MU, 8)
    cert = np.asarray(ev.certificate, np.float64)
    assert np.linalg.norm(cert) == pytest.approx(1.0, abs=1e-6)
    assert (w @ cert).min() >= -1e-5 * np.abs(w).max()


@pytest.mark.parametrize("name", ["box", "sphere"])
def test_float32_targets(float32_vs_float64, name):
    """Issue 8's float32 targets on 2,000 grasps per shape (100,000: experiments/float32_accuracy.py)."""
    r = float32_vs_float64[name]
    assert r["disagree"] == 0 and r["dq"].max() <= 1e-4 and r["unconverged"] == 0


# Two grasps whose torques about c_1 lie in a half-space (torque margin ~1e-11 in float64): the
# quality LP is degenerate, and its float32 vertex was not certified (Q32 0.457 and 0.808 before
# ``_closure.half_space_quality_lp``). A box (two contacts on the top face) and a cylinder (all
# contacts on the side).
HALF_SPACE_GRASPS = [
    ([[-1.0, 0.09364209, 0.08946599], [1.0, 0.00793534, -0.30250073],
      [-0.49042468, -0.07772665, 0.4], [0.14496602, -0.51325829, 0.4]],
     [[-1, 0, 0], [1, 0, 0], [0, 0, 1], [0, 0, 1]]),
    ([[0.37092757, -0.33528009, 0.00163357], [0.10671688, -0.48847877, -0.49702824],
      [-0.30818972, 0.39372465, 0.1628112], [-0.45788618, 0.20084882, -0.70267432]],
     [[0.74185514, -0.67056018, 0.0], [0.21343377, -0.97695754, 0.0],
      [-0.61637944, 0.78744929, 0.0], [-0.91577235, 0.40169764, 0.0]]),
]


def test_float32_quality_when_the_torques_lie_in_a_half_space():
    """float32 Q of ``evaluate`` and of ``quality`` within 1e-4 of HiGHS (float64) on the grasps
    above, from a certified vertex."""
    p = np.array([g[0] for g in HALF_SPACE_GRASPS], np.float32)
    n = np.array([g[1] for g in HALF_SPACE_GRASPS], np.float32)
    ev = gj.evaluate(p, n, mu=np.float32(MU))
    q32 = np.asarray(gj.quality(p, n, mu=np.float32(MU)))
    assert np.all(np.abs(np.asarray(ev.torque_margin)) <= 1e-6)
    assert np.all(np.asarray(ev.quality_status) == gj.Status.OPTIMAL)
    for k in range(len(p)):
        q64, _ = reference.quality_highs(p[k].astype(np.float64), n[k].astype(np.float64), MU)
        assert q64 > 0.1  # in equilibrium, with Q far from 0: no band to hide in
        assert abs(float(ev.quality[k]) - q64) <= 1e-4, k
        assert abs(float(q32[k]) - q64) <= 1e-4, k


def test_float32_on_grasps_whose_torques_lie_in_a_half_space(float64_results):
    """300 random grasps on the side of a cylinder (every one's torques about c_1 lie in a
    half-space: ill-posed quality LPs, the hardest float32 case): ``evaluate`` and ``quality`` in
    float32 against float64, |dQ| <= 1e-4 and equal verdicts outside the band."""
    p, n = _float64_grasps()["cylinder"]
    e64 = float64_results["cylinder"]
    p32, n32 = p.astype(np.float32), n.astype(np.float32)
    e32 = gj.evaluate(p32, n32, mu=np.float32(MU))
    q32 = np.asarray(gj.quality(p32, n32, mu=np.float32(MU)), np.float64)
    delta, tm = np.asarray(e64["delta"]), np.asarray(e64["torque_margin"])
    clear = ((delta > -BAND) & (tm > -BAND)) == ((delta > BAND) & (tm > BAND))
    assert np.all(e32.converged)
    assert np.max(np.abs(np.asarray(e32.quality, np.float64) - np.asarray(e64["quality"]))) <= 1e-4
    assert np.max(np.abs(q32 - np.asarray(e64["quality"]))) <= 1e-4
    assert not np.any(clear & (np.asarray(e32.force_closure) != np.asarray(e64["force_closure"])))


# ---------------------------------------------------------------------------------------------
# The float32 tests above under a narrower instruction set than the host's (issue 27): XLA compiles
# for the host's CPU, so vector width, FMA contraction and the order of reductions, and with them
# float32 results, differ between CPUs. ``--xla_cpu_max_isa`` compiles for a smaller instruction
# set on any x86-64 machine: AVX2 (no AVX-512: the AMD EPYC machines of this project) and SSE4.2,
# the smallest XLA offers.

#: Set in the child process, whose run of this file must not start children of its own.
_ISA_CHILD = "GRASP_JAX_TEST_ISA"
#: The parent's float64 results (``float64_results``) for the child, an ``.npz`` file: the
#: reference the float32 results are compared with, not what the child checks.
_FLOAT64_FILE = "GRASP_JAX_TEST_FLOAT64"
FLOAT32_TESTS = (
    "test_float32_verdicts_and_quality",
    "test_float32_targets",
    "test_float32_unfinished_quality_lp_bounded_by_its_dual",
    "test_float32_quality_when_the_torques_lie_in_a_half_space",
    "test_float32_on_grasps_whose_torques_lie_in_a_half_space",
)


@pytest.mark.skipif(platform.machine().lower() not in ("x86_64", "amd64"), reason="--xla_cpu_max_isa is x86-64's")
@pytest.mark.skipif(bool(os.environ.get(_ISA_CHILD)), reason="already under a narrower instruction set")
@pytest.mark.parametrize("isa", ["AVX2", "SSE4_2"])
def test_float32_under_a_narrower_instruction_set(isa, float64_results, tmp_path):
    np.savez(tmp_path / "float64.npz",
             **{f"{name}.{field}": v for name, r in float64_results.items() for field, v in r.items()})
    env = dict(os.environ, **{_ISA_CHILD: isa, _FLOAT64_FILE: str(tmp_path / "float64.npz")})
    env["XLA_FLAGS"] = f"{env.get('XLA_FLAGS', '')} --xla_cpu_max_isa={isa}".strip()
    tests = [f"{__file__}::{name}" for name in FLOAT32_TESTS]
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider", *tests],
        capture_output=True, text=True, env=env, timeout=900, check=False,
    )
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-2000:]
    assert f"{len(FLOAT32_TESTS) + 1} passed" in proc.stdout, proc.stdout[-2000:]  # targets: a parametrized pair
