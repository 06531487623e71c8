"""Batching: any leading batch shape, chunking, input types and dtypes give the same answers."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _grasps import MU, grasps, sample_box, sample_cylinder, sample_sphere
from _jit import jit

import grasp_jax as gj
import grasp_jax._api as api
from grasp_jax import _batch, reference
from grasp_jax._contact import ContactModel

N, D = 4, 3  # every batch below has this grasp shape: the concrete path compiles once (bucket 256)


def _batch_of(count, seed):
    rng = np.random.default_rng(seed)
    parts = [grasps(s, -(-count // 3), N, rng) for s in (sample_box, sample_cylinder, sample_sphere)]
    p = np.concatenate([a for a, _ in parts])[:count]
    n = np.concatenate([b for _, b in parts])[:count]
    order = rng.permutation(count)
    return p[order], n[order]


def _fields(ev):
    return {f: np.asarray(getattr(ev, f)) for f in ev.__dataclass_fields__}


def _assert_same(a: gj.GraspEvaluation, b: gj.GraspEvaluation, exact=True):
    fa, fb = _fields(a), _fields(b)
    for name in fa:
        assert fa[name].shape == fb[name].shape, name
        assert fa[name].dtype == fb[name].dtype, name
        if exact or fa[name].dtype.kind in "biu":
            np.testing.assert_array_equal(fa[name], fb[name], err_msg=name)
        else:
            np.testing.assert_allclose(fa[name], fb[name], rtol=1e-12, atol=1e-13, err_msg=name)


@pytest.fixture(scope="module")
def batch():
    p, n = _batch_of(24, seed=1)
    return p, n, gj.evaluate(p, n, mu=MU)


def test_batch_equals_loop(batch):
    p, n, ev = batch
    assert len(ev) == 24 and ev.force_closure.shape == (24,) and ev.certificate.shape == (24, 6)
    assert 0 < np.sum(ev.force_closure) < 24
    for k in range(len(p)):
        single = gj.evaluate(p[k], n[k], mu=MU)
        assert single.force_closure.shape == () and single.quality.shape == ()
        assert single.certificate.shape == (6,)
        _assert_same(single, ev[k])


def test_arbitrary_leading_shape(batch):
    p, n, ev = batch
    ev4 = gj.evaluate(p.reshape(2, 3, 4, N, D), n.reshape(2, 3, 4, N, D), mu=MU)
    assert ev4.force_closure.shape == (2, 3, 4) and ev4.certificate.shape == (2, 3, 4, 6)
    _assert_same(jax.tree_util.tree_map(lambda a: a.reshape((24,) + a.shape[3:]), ev4), ev)
    q = gj.quality(p.reshape(4, 6, N, D), n.reshape(4, 6, N, D), mu=MU)
    assert q.shape == (4, 6)
    np.testing.assert_allclose(np.asarray(q).reshape(-1), np.asarray(ev.quality), atol=1e-12)
    fc = gj.force_closure(p[:6].reshape(2, 3, N, D), n[:6].reshape(2, 3, N, D), mu=MU)
    assert fc.shape == (2, 3) and fc.dtype == bool
    np.testing.assert_array_equal(np.asarray(fc).reshape(-1), np.asarray(ev.force_closure[:6]))
    mw = gj.min_weight(p[:6].reshape(3, 2, N, D), n[:6].reshape(3, 2, N, D), mu=MU)
    assert mw.shape == (3, 2)
    assert np.ndim(gj.min_weight(p[0], n[0], mu=MU)) == 0 and np.ndim(gj.quality(p[0], n[0], mu=MU)) == 0


def test_numpy_jax_and_list_inputs_agree(batch):
    p, n, ev = batch
    _assert_same(gj.evaluate(jnp.asarray(p), jnp.asarray(n), mu=MU), ev)
    _assert_same(gj.evaluate(p.tolist(), n.tolist(), mu=jnp.float64(MU)), ev)
    _assert_same(gj.evaluate(p, jnp.asarray(n), mu=np.float64(MU)), ev)


def test_result_helpers(batch):
    p, n, ev = batch
    assert ev.converged.shape == (24,) and ev.converged.dtype == bool
    sub = ev[3:7]
    assert isinstance(sub, gj.GraspEvaluation) and len(sub) == 4
    np.testing.assert_array_equal(np.asarray(sub.quality), np.asarray(ev.quality)[3:7])
    assert ev.quality.dtype == jnp.float64 and ev.quality_status.dtype == jnp.int8
    assert ev.iterations.dtype == jnp.int32


def test_float32_inputs(batch):
    p, n, ev = batch
    ev32 = gj.evaluate(p.astype(np.float32), n.astype(np.float32), mu=MU)
    for name in ("quality", "delta", "torque_margin", "certificate"):
        assert getattr(ev32, name).dtype == jnp.float32, name
    assert ev32.force_closure.dtype == bool
    assert np.all(ev32.converged)
    # Verdicts agree with float64 wherever the grasp is clearly away from the boundary.
    l_ref = np.array([reference.min_weight_highs(a, b, MU) for a, b in zip(p, n)])
    clear = (np.abs(l_ref) > 1e-3) & (np.abs(np.asarray(ev.delta)) > 1e-2)
    assert clear.sum() >= 12
    np.testing.assert_array_equal(np.asarray(ev32.force_closure)[clear], np.asarray(ev.force_closure)[clear])
    np.testing.assert_array_equal(np.asarray(ev32.equilibrium)[clear], np.asarray(ev.equilibrium)[clear])
    np.testing.assert_allclose(np.asarray(ev32.quality)[clear], np.asarray(ev.quality)[clear], atol=2e-4)
    # One float64 input promotes to float64 (the float64 computation).
    mixed = gj.evaluate(p.astype(np.float32), n, mu=MU)
    assert mixed.quality.dtype == jnp.float64
    np.testing.assert_array_equal(np.asarray(mixed.force_closure), np.asarray(
        gj.evaluate(p.astype(np.float32).astype(np.float64), n, mu=MU).force_closure))


def _full_budget(p, n, chunk, progress=False):
    """``evaluate``'s single-grasp function with the full budget, mapped in chunks of ``chunk``."""
    fn = api._bind(api._evaluate_single, torque_test="exact")
    shared = ((np.asarray(MU), ContactModel(num_edges=8)), np.int32(api.default_iterations(api._lp_columns(N, D, 8))),
              np.int32(len(api.tolerances(np.float64).restarts)))
    return _batch.map_grasps(fn, (p, n, None), shared, (len(p),), chunk=chunk, progress=progress)


def _retry_chunk():
    return _batch._retry_sizes(tuple(jax.local_devices()), _batch.CHUNK, _batch.BLOCK)[0] * jax.local_device_count()


def test_chunks():
    """A batch that crosses the chunk size gives the same results as smaller calls, bit for bit:
    every call runs the one compiled program of its chunk size, whatever the batch size (here
    the chunk of evaluate's retry pass, and the default chunk)."""
    assert _batch.CHUNK >= _batch.BLOCK == 256
    chunk = _retry_chunk()
    p, n = _batch_of(2 * chunk + 100, seed=2)
    cuts = ((0, 100), (100, chunk + 100), (chunk + 100, 2 * chunk + 100))

    def pieces(score):
        parts = [score(p[a:b], n[a:b]) for a, b in cuts]
        return jax.tree_util.tree_map(lambda *xs: np.concatenate([np.asarray(x) for x in xs]), *parts)

    chunked = _full_budget(p, n, chunk, progress=True)
    assert chunked.force_closure.shape == (len(p),)
    _assert_same(chunked, pieces(lambda a, b: _full_budget(a, b, chunk)))
    # The padding of the last chunk copies its first grasp: no spill into real results.
    _assert_same(jax.tree_util.tree_map(lambda a: a[-1], chunked), _full_budget(p[-1:], n[-1:], chunk)[0])
    whole = gj.evaluate(p, n, mu=MU)
    _assert_same(whole, pieces(lambda a, b: gj.evaluate(a, b, mu=MU)))
    # Two programs (a fast pass and a retry against one full pass): the same verdicts, values equal
    # within the LP tolerance.
    for name in ("force_closure", "equilibrium", "torque_span", "quality_status", "torque_status"):
        np.testing.assert_array_equal(np.asarray(getattr(whole, name)), np.asarray(getattr(chunked, name)))
    np.testing.assert_allclose(np.asarray(whole.quality), np.asarray(chunked.quality), rtol=0, atol=1e-8)


def test_chunk_sizes():
    assert _batch._local_size(16384, 1, 256) == 16384
    assert _batch._local_size(16384, 2, 256) == 8192
    assert _batch._local_size(16384, 3, 256) == 5376  # whole blocks per device
    assert _batch._local_size(100, 2, 256) == 256  # at least one block


def test_zero_size_batch():
    for shape in ((0,), (2, 0)):
        p = np.zeros(shape + (N, D))
        n = np.ones(shape + (N, D))
        ev = gj.evaluate(p, n, mu=MU)
        assert ev.force_closure.shape == shape and ev.certificate.shape == shape + (6,)
        assert ev.quality.dtype == jnp.float64 and ev.force_closure.dtype == bool
        eps, vol = gj.ferrari_canny(p, n, mu=MU)
        assert eps.shape == shape and vol.shape == shape
    assert gj.quality(p, n, mu=MU).shape == shape
    assert gj.min_weight(p, n, mu=MU).shape == shape
    assert gj.force_closure(p, n, mu=MU).shape == shape
    p2 = np.zeros((0, 3, 2))
    assert gj.evaluate(p2, p2 + 1, mu=MU).certificate.shape == (0, 3)


def test_fast_pass_and_retry_equal_one_full_pass():
    """The concrete path scores a chunk with a short iteration budget and re-solves, gathered,
    the grasps it leaves unfinished (``_batch.Retry``): the results are those of one pass with
    the full budget, and some grasps did need the second pass. (The full pass in chunks of
    test_chunks's program: its results do not depend on the chunk size, test_chunks.)"""
    p, n = _batch_of(3000, seed=11)
    fast = gj.evaluate(p, n, mu=MU)
    full = _full_budget(p, n, _retry_chunk())
    _assert_same(fast, full, exact=False)
    np.testing.assert_array_equal(np.asarray(gj.evaluate(p, n, mu=MU, iterations=30).quality), np.asarray(full.quality))
    first = api.first_pass_iterations(api._lp_columns(N, D, 8))
    assert np.any(np.asarray(fast.iterations) > first)
    assert np.all(fast.converged)


def test_min_weight_streamed_blocks_equal_lock_step(monkeypatch):
    """``gj.min_weight`` runs its blocks (``api.MIN_WEIGHT_BLOCK`` = 512) with their LPs streamed
    through lanes; in lock-step blocks of 256 a grasp's margin is the same (each LP takes the
    iterations it takes alone), up to the rounding of another position in a vector (seen: 6e-15
    on a tenth of the grasps)."""
    p, n = _batch_of(2048, seed=12)
    streamed = np.asarray(gj.min_weight(p, n, mu=MU))
    small = np.asarray(gj.min_weight(p[:3], n[:3], mu=MU))  # padded to a block: the same program
    monkeypatch.setattr(api, "MIN_WEIGHT_BLOCK", 256)
    locked = np.asarray(gj.min_weight(p, n, mu=MU))
    np.testing.assert_allclose(streamed, locked, rtol=0, atol=1e-12)
    np.testing.assert_allclose(small, locked[:3], rtol=0, atol=1e-12)
    assert (streamed > 0).any() and (streamed < 0).any()


def test_retry_gathers_in_several_rounds():
    """More unfinished grasps than one gathered block holds: the second pass loops over rounds."""

    def fn(x, shared):
        scale, slow = shared
        return jnp.where((x[0] > 0.5) & ~slow, -1.0, x[0] * scale)  # "unfinished" where x > 0.5

    x = np.random.default_rng(0).uniform(size=(5000, 1))
    retry = _batch.Retry((np.float64(2.0), np.bool_(True)), lambda out: out < 0)
    out = _batch.map_grasps(fn, (x,), (np.float64(2.0), np.bool_(False)), (5000,), chunk=4096, retry=retry)
    np.testing.assert_array_equal(np.asarray(out), 2.0 * x[:, 0])
    with pytest.raises(TypeError, match="structure and types"):
        _batch.map_grasps(fn, (x,), (np.float64(2.0), np.bool_(False)), (5000,), chunk=4096,
                          retry=_batch.Retry((np.float64(2.0), np.float64(1.0)), lambda out: out < 0))


def test_retry_passes_in_turn():
    """A tuple of retries: each pass scores again only what the passes before it left unfinished
    (evaluate's float32 third pass), and the traced path runs the last pass's ``shared``."""
    calls = []

    def fn(x, shared):
        (level,) = shared
        return jnp.where(x[0] > level, -1.0, x[0])  # "unfinished" above the pass's level

    x = np.random.default_rng(1).uniform(size=(3000, 1))
    unfinished = lambda out: (calls.append(int(np.sum(np.asarray(out) < 0))), np.asarray(out) < 0)[1]
    passes = (_batch.Retry((np.float64(0.9),), unfinished), _batch.Retry((np.float64(2.0),), unfinished))
    out = _batch.map_grasps(fn, (x,), (np.float64(0.5),), (3000,), retry=passes)
    np.testing.assert_array_equal(np.asarray(out), x[:, 0])
    assert calls == [int(np.sum(x > 0.5)), int(np.sum(x > 0.9))]  # the second pass saw only x > 0.9
    traced = jax.jit(lambda x: _batch.map_grasps(fn, (x,), (np.float64(0.5),), (3000,), retry=passes))(x)
    np.testing.assert_array_equal(np.asarray(traced), x[:, 0])


def _toy_staged():
    """A two-stage function: the first settles ``x <= 0.5`` at -1 and hands ``3 x`` on; the second
    gives ``3 x + x`` where needed and -1 elsewhere (as the first: correct for every grasp)."""

    def first(x, missing, shared):
        assert missing is None
        return -jnp.ones((), x.dtype), 3.0 * x[0], x[0] > 0.5

    def second(x, missing, carry, shared):
        assert missing is None
        (offset,) = shared
        return jnp.where(x[0] > 0.5, carry + x[0] + offset, -1.0)

    return _batch.Staged(first, second)


def test_staged_second_stage_on_gathered_grasps():
    """``_batch.Staged``: the concrete path (the second stage on the gathered grasps that need it,
    chunks with padding, a missing input, a retry pass) equals the traced path (both stages on
    every grasp) and the expected values."""
    fn = _toy_staged()
    x = np.random.default_rng(3).uniform(size=(5000, 1))
    expected = np.where(x[:, 0] > 0.5, 4.0 * x[:, 0], -1.0)
    out = _batch.map_grasps(fn, (x, None), (np.float64(0.0),), (5000,), chunk=4096)
    np.testing.assert_array_equal(np.asarray(out), expected)
    traced = jax.jit(lambda x: _batch.map_grasps(fn, (x, None), (np.float64(0.0),), (5000,)))(x)
    np.testing.assert_array_equal(np.asarray(traced), expected)
    # A retry pass re-runs both stages on what the first pass left "unfinished" (here x > 0.9,
    # offset 1 in the first pass, 0 in the retry).
    retry = _batch.Retry((np.float64(0.0),), lambda out: np.asarray(out) > 4.0 * 0.9 + 1.0)
    out = _batch.map_grasps(fn, (x, None), (np.float64(1.0),), (5000,), chunk=4096, retry=retry)
    again = x[:, 0] > 0.9
    np.testing.assert_array_equal(np.asarray(out)[again], expected[again])
    np.testing.assert_array_equal(np.asarray(out)[~again], np.where(x[~again, 0] > 0.5, expected[~again] + 1.0, -1.0))


def test_staged_evaluate_equals_one_stage():
    """``gj.evaluate`` (float64, 3D, exact: ``_closure.torque_stage`` then ``quality_stage`` on
    the grasps that need it, the quality LP skipped where the torques are opposed) against the
    traced path: the same verdicts, certificates and margins; ``delta`` exactly -1 where the
    quality LP was skipped, as HiGHS finds."""
    p, n = _batch_of(600, seed=12)
    ev = gj.evaluate(p, n, mu=MU)
    skipped = np.asarray(ev.iterations) == 0
    assert 0.2 < skipped.mean() < 0.9
    # The traced path runs both stages on every grasp.
    one = jit(jax.vmap(lambda a, b: gj._closure.evaluate_one(a, b, MU, ContactModel(num_edges=8))))(p, n)
    for name in ("force_closure", "equilibrium", "torque_span", "quality_status", "torque_status"):
        np.testing.assert_array_equal(np.asarray(getattr(ev, name)), np.asarray(getattr(one, name)), err_msg=name)
    for name in ("quality", "delta", "torque_margin", "certificate"):
        np.testing.assert_allclose(np.asarray(getattr(ev, name)), np.asarray(getattr(one, name)), atol=1e-8,
                                   err_msg=name)
    np.testing.assert_array_equal(np.asarray(ev.delta)[skipped], -1.0)
    # HiGHS on the signed quality LP (delta free) of some skipped grasps: delta* = -1.
    from scipy.optimize import linprog

    for k in np.flatnonzero(skipped)[:20]:
        W = reference.wrenches(p[k], n[k], MU, 8, p[k][0], 1.0).T
        z1 = -n[k][0] / np.linalg.norm(n[k][0])
        A = np.vstack([np.hstack([W, np.concatenate([z1, np.zeros(3)])[:, None]]),
                       np.concatenate([np.ones(W.shape[1]), [0.0]])])
        b = np.zeros(7)
        b[-1] = 1.0
        res = linprog(np.eye(W.shape[1] + 1)[-1] * -1.0, A_eq=A, b_eq=b,
                      bounds=[(0, None)] * W.shape[1] + [(None, None)], method="highs")
        assert res.status == 0 and abs(-res.fun + 1.0) < 1e-9, (k, res.fun)


def test_one_compilation_per_grasp_shape(monkeypatch, caplog):
    """Batches of 1 to 100,000 grasps of one shape reuse the same compiled programs: one for
    ``quality``, one for ``evaluate`` (its first pass and its retry pass share it), each traced once
    (concrete calls run compiled executables: nothing is traced again). Counted in JAX's own
    compile log (``jax.log_compiles``) and in ``_batch.STATS``; the persistent cache is off, so
    that each program is compiled here. The shape (2D, 5 fingers) is used by no other test."""
    import logging

    monkeypatch.setenv("GRASP_JAX_CACHE", "off")
    rng = np.random.default_rng(3)
    sizes = (1, 255, 257, 1000, 20_000, 100_000)
    p = rng.normal(size=(max(sizes), 5, 2))
    n = p + 0.5 * rng.normal(size=p.shape)
    before = dict(_batch.STATS)
    results = {}
    with caplog.at_level(logging.WARNING), jax.log_compiles():
        for size in sizes:
            results[size] = gj.evaluate(p[:size], n[:size], mu=MU)
            np.asarray(gj.quality(p[:size], n[:size], mu=MU))
    made = {k: v - before.get(k, 0) for k, v in _batch.STATS.items()}
    assert made.get("traced") == 2 and made.get("compiled") == 2 and not made.get("loaded"), made
    log = [r.getMessage() for r in caplog.records]
    ours = f"jit({_batch.PROGRAM_NAME})"
    assert sum(m.startswith("Finished XLA compilation") and ours in m for m in log) == 2, log
    assert sum(m.startswith("Finished tracing") and _batch.PROGRAM_NAME in m for m in log) == 2, log
    keys = [k for k in _batch._PROGRAMS if k[1] == (((5, 2), np.dtype(np.float64)),) * 2]
    assert len(keys) == 2  # evaluate's (both passes), quality's
    # Any batch size runs the same program: a grasp's results do not depend on it.
    for size in sizes[:-1]:
        _assert_same(results[size], results[sizes[-1]][:size])
    assert np.any(np.asarray(results[sizes[-1]].iterations) > api.first_pass_iterations(api._lp_columns(5, 2, 8)))


def test_cache_is_read_only_beside_jax_persistent_cache(tmp_path):
    """A caller who switched on JAX's own persistent cache keeps it: grasp_jax's cache writes no
    file then (an executable JAX loaded from its cache would serialize incompletely), and the
    results are those of the default process. Run in a fresh process, where the switch is set
    before anything compiles."""
    import os
    import subprocess
    import sys

    code = (
        "import numpy as np, grasp_jax as gj\n"
        "from grasp_jax import _cache\n"
        "assert _cache.jax_cache_active()\n"
        "p = np.random.default_rng(0).normal(size=(50, 3, 2)); n = -p\n"
        "print(float(np.asarray(gj.quality(p.astype(np.float32), n.astype(np.float32), mu=0.5)).sum()))\n"
    )
    env = dict(os.environ, JAX_COMPILATION_CACHE_DIR=str(tmp_path / "jax"), GRASP_JAX_CACHE=str(tmp_path / "gj"),
               JAX_ENABLE_COMPILATION_CACHE="true", JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS="0")
    env.pop("XLA_FLAGS", None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert not list((tmp_path / "gj").glob("grasp_jax-*")), "grasp_jax's cache was written"
    assert list((tmp_path / "jax").iterdir()), "JAX's cache was not used"


def test_cache_key_names_the_host_cpu_and_the_xla_flags(monkeypatch):
    """A cache folder shared by machines of different CPUs (a cluster's home folder) or read under
    other ``XLA_FLAGS`` (``--xla_cpu_max_isa``) never hands over a program compiled for another
    instruction set."""
    from grasp_jax import _cache

    devices = tuple(jax.devices()[:1])
    base = _cache.key("module", {}, devices)
    assert _cache.key("module", {}, devices) == base
    monkeypatch.setattr(_cache, "host_cpu", lambda: "another CPU")
    assert _cache.key("module", {}, devices) != base
    monkeypatch.undo()
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_max_isa=AVX2")
    assert _cache.key("module", {}, devices) != base
