"""Robust labels (grasp_jax.robust): a brute-force loop of evaluate over the same draws, zero noise
is the nominal grasp (verdicts and Q bit for bit, margins to rounding), perturbed contacts on the surface, common random numbers,
reproducibility, statistical agreement with a larger sample, bad input.

Every 3D grasp here has 4 contacts and 8 cone edges: one compiled program of each kind."""

from __future__ import annotations

import jax
import numpy as np
import pytest
from _grasps import MU
from _jit import jit

import grasp_jax as gj
from grasp_jax import _noise, objects, surfaces
from grasp_jax._contact import ContactModel

N = 4
NOISE = gj.Noise(position=0.03, normal=0.05, rotation=0.03, translation=0.01)


def _grasps(obj, count, seed=0, n=N):
    surface = surfaces.for_object(obj)
    with jax.enable_x64(True):
        contacts = surface.sample(jax.random.key(seed), count * n)
        p, nrm = jax.vmap(surface.embed)(contacts)
    d = obj.dim
    return np.asarray(p, float).reshape(count, n, d), np.asarray(nrm, float).reshape(count, n, d)


@pytest.fixture(scope="module")
def sphere():
    return objects.Sphere()


@pytest.fixture(scope="module")
def box():
    return objects.Box()


@pytest.fixture(scope="module")
def box_grasps(box):
    return _grasps(box, 12, seed=3)


def test_zero_noise_is_the_nominal_grasp(box, box_grasps):
    p, n = box_grasps
    res = gj.robust(box, p, n, mu=MU, noise=gj.Noise(), key=jax.random.key(0), samples=3)
    ev = gj.evaluate(p, n, mu=MU)
    fc, q = np.asarray(ev.force_closure), np.asarray(ev.quality)
    assert 0 < fc.sum() < len(fc)
    np.testing.assert_array_equal(res.p_fc, fc.astype(float))
    np.testing.assert_array_equal(res.q_mean, q)
    np.testing.assert_array_equal(res.q_low, q)
    np.testing.assert_array_equal(res.p_fc_se, 0.0)
    np.testing.assert_array_equal(res.q_mean_se, 0.0)
    # The margins come from two compiled programs (friction per contact here, one scalar in
    # gj.min_weight) whose float64 rounding differs by an ulp on some CPUs (AVX2: 7e-18 on 2 of 12
    # grasps; AVX-512: none), as LLVM contracts and vectorizes them differently: equal to rounding.
    margin = gj.min_weight(p, n, mu=MU, origin=box.center, torque_scale=box.radius)
    np.testing.assert_allclose(res.margin_mean, np.maximum(np.asarray(margin), 0.0), rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(res.margin_low, res.margin_mean)
    assert res.unconverged.sum() == 0 and res.samples == 3 and len(res) == 12
    line = str(res)
    assert "\n" not in line and "12 grasps x 3 samples" in line and "P(FC)" in line
    # a pytree: its arrays are leaves, samples and quantile static
    leaves = jax.tree_util.tree_leaves(res)
    assert len(leaves) == 9 and res[:2].p_fc.shape == (2,)


def test_p_fc_equals_a_loop_of_evaluate_over_the_same_draws(box, box_grasps):
    p, n = box_grasps
    noise = gj.Noise(position=0.03, normal=0.05, friction=(0.8, 0.8), rotation=0.03, translation=0.01)
    key = jax.random.key(7)
    res = gj.robust(box, p, n, mu=MU, noise=noise, key=key, samples=16, margin=False)
    pp, nn, mm = gj.perturb(box, p, n, mu=MU, noise=noise, key=key, samples=16)
    assert pp.shape == (12, 16, N, 3) and mm.shape == (12, 16, N)
    np.testing.assert_array_equal(mm, MU * 0.8)
    # The screening of gj.robust: perturbations that the nominal grasp's dual proves out of
    # equilibrium are settled without an LP (some are, here); evaluate agrees on every one.
    from grasp_jax import _closure

    with jax.enable_x64(True):  # jitted: op by op, these two compiled 220 programs
        duals = jit(jax.vmap(lambda a, b: _closure.quality_dual_one(a, b, MU, ContactModel(num_edges=8))))(p, n)
        settled = np.asarray(jit(jax.vmap(jax.vmap(lambda a, b, y: _closure.out_of_equilibrium(a, b, MU * 0.8, ContactModel(num_edges=8), y),
                                                       in_axes=(0, 0, None))))(pp, nn, duals))
    assert 0.05 < settled.mean() < 0.95
    for g in range(len(p)):  # brute force: one evaluate per grasp, over its 16 perturbations
        ev = gj.evaluate(pp[g], nn[g], mu=MU * 0.8)
        fc, q = np.asarray(ev.force_closure), np.asarray(ev.quality)
        assert not np.any(np.asarray(ev.equilibrium)[settled[g]])
        assert res.p_fc[g] == fc.mean()
        np.testing.assert_allclose(res.q_mean[g], q.mean(), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(res.q_low[g], np.quantile(q, 0.1), rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(res.q_mean_se[g], q.std(ddof=1) / 4.0, rtol=1e-9, atol=1e-15)
    assert 0 < res.p_fc.mean() < 1 and res.margin_mean is None
    # some perturbed grasps differ from the nominal verdict, and the standard error says by how much
    np.testing.assert_allclose(res.p_fc_se, np.sqrt(res.p_fc * (1 - res.p_fc) / 16))


def test_perturbed_contacts_stay_on_the_surface(sphere, box):
    for obj in (sphere, box):
        p, n = _grasps(obj, 6, seed=1)
        pp, nn, mm = gj.perturb(obj, p, n, mu=MU, noise=NOISE, key=jax.random.key(2), samples=50)
        surface = surfaces.for_object(obj)
        located = surface.locate(pp.reshape(-1, 3))
        with jax.enable_x64(True):
            q, _ = jax.vmap(surface.embed)(located)
        np.testing.assert_allclose(np.asarray(q), pp.reshape(-1, 3), atol=1e-12 * obj.radius)
        np.testing.assert_allclose(np.linalg.norm(nn, axis=-1), 1.0, atol=1e-12)
        moved = np.linalg.norm(pp - p[:, None], axis=-1) / obj.radius
        assert 0.01 < np.median(moved) < 0.15  # position 0.03 R per axis plus the pose
        np.testing.assert_array_equal(mm, MU)  # no friction noise
        if obj is sphere:
            np.testing.assert_allclose(np.linalg.norm(pp, axis=-1), obj.radius, rtol=1e-13)
            tilt = np.arccos(np.clip(np.sum(nn * pp / obj.radius, axis=-1), -1, 1))
            assert 0.03 < np.median(tilt) < 0.1  # Rayleigh(0.05): median 0.059


def test_common_random_numbers_and_reproducibility(box, box_grasps):
    p, n = box_grasps
    key = jax.random.key(11)
    noise = gj.Noise(position=0.02, friction=(0.7, 1.1))
    a = gj.robust(box, p, n, mu=MU, noise=noise, key=key, samples=8, margin=False)
    b = gj.robust(box, p, n, mu=MU, noise=noise, key=key, samples=8, margin=False)
    for name in ("p_fc", "q_mean", "q_low", "q_mean_se"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    # a grasp's labels do not depend on the batch it is in, nor on its place there
    c = gj.robust(box, p[[5, 0]], n[[5, 0]], mu=MU, noise=noise, key=key, samples=8, margin=False)
    np.testing.assert_array_equal(c.q_mean, a.q_mean[[5, 0]])
    # the same draws for every grasp: a grasp twice in a batch is perturbed identically
    pp, _, mm = gj.perturb(box, p[[1, 1]], n[[1, 1]], mu=MU, noise=noise, key=key, samples=8)
    np.testing.assert_array_equal(pp[0], pp[1])
    np.testing.assert_array_equal(mm[0], mm[1])
    assert np.all(mm[0, 0] != mm[0, 1])  # each sample and contact its own friction
    # friction is common across grasps: the multiplier of sample s, contact i is the same
    pp2, _, mm2 = gj.perturb(box, p[:3], n[:3], mu=MU, noise=noise, key=key, samples=8)
    np.testing.assert_array_equal(mm2[0], mm2[2])
    other = gj.perturb(box, p[:3], n[:3], mu=MU, noise=noise, key=jax.random.key(12), samples=8)[0]
    assert not np.allclose(other, pp2)
    # an integer seed is jax.random.key(seed), as in gj.optimize
    seeded = gj.perturb(box, p[:3], n[:3], mu=MU, noise=noise, key=12, samples=8)[0]
    np.testing.assert_array_equal(seeded, other)


def test_friction_distributions(box_grasps):
    p, n = box_grasps
    _, _, mm = gj.perturb(None, p, n, mu=MU, noise=gj.Noise(friction_sigma=0.2), key=jax.random.key(0),
                          samples=400)
    log = np.log(mm[0] / MU)
    assert abs(np.median(log)) < 0.05 and abs(log.std() - 0.2) < 0.02
    pp, nn, mm = gj.perturb(None, p, n, mu=MU, noise=gj.Noise(friction=(0.5, 1.5), normal=0.1),
                            key=jax.random.key(0), samples=100)
    assert mm.min() >= 0.5 * MU and mm.max() <= 1.5 * MU and abs(mm.mean() / MU - 1) < 0.05
    # without an object: the points stay, the normals tilt (Rayleigh(0.1): median 0.118 rad)
    np.testing.assert_array_equal(pp, np.broadcast_to(p[:, None], pp.shape))
    tilt = np.arccos(np.clip(np.sum(nn * n[:, None], axis=-1), -1, 1))
    assert 0.09 < np.median(tilt) < 0.15


def test_agrees_with_a_larger_sample(box, box_grasps):
    p, n = box_grasps
    small = gj.robust(box, p, n, mu=MU, noise=NOISE, key=jax.random.key(1), samples=40, margin=False)
    large = gj.robust(box, p, n, mu=MU, noise=NOISE, key=jax.random.key(2), samples=400, margin=False)
    se = np.sqrt(small.p_fc_se**2 + large.p_fc_se**2)
    close = np.abs(small.p_fc - large.p_fc) <= 3 * se + 1e-12
    assert close.mean() >= 0.9
    assert 0.0 < large.p_fc.mean() < 1.0


def test_planar_grasps():
    quad = objects.quad()
    p, n = _grasps(quad, 6, seed=4, n=3)
    res0 = gj.robust(quad, p, n, mu=MU, noise=gj.Noise(), key=jax.random.key(0), samples=2, margin=False)
    ev = gj.evaluate(p, n, mu=MU)
    np.testing.assert_array_equal(res0.q_mean, np.asarray(ev.quality))
    noise = gj.Noise(position=0.05, normal=0.05, rotation=0.05, translation=0.02)
    pp, nn, _ = gj.perturb(quad, p, n, mu=MU, noise=noise, key=jax.random.key(3), samples=10)
    surface = surfaces.for_object(quad)
    with jax.enable_x64(True):
        q, _ = jax.vmap(surface.embed)(surface.locate(pp.reshape(-1, 2)))
    np.testing.assert_allclose(np.asarray(q), pp.reshape(-1, 2), atol=1e-12 * quad.radius)
    res = gj.robust(quad, p, n, mu=MU, noise=noise, key=jax.random.key(3), samples=10, margin=False)
    assert res.p_fc.shape == (6,) and np.all((0 <= res.p_fc) & (res.p_fc <= 1))


@pytest.mark.parametrize("kwargs, match", [
    (dict(position=-0.1), "Noise.position must be a finite number >= 0"),
    (dict(normal=float("nan")), "Noise.normal"),
    (dict(rotation=-1), "Noise.rotation"),
    (dict(friction=(1.2, 0.8)), "0 < lo <= hi"),
    (dict(friction=(0.0, 1.0)), "0 < lo <= hi"),
    (dict(friction=3), "pair"),
    (dict(friction=(0.8, 1.2), friction_sigma=0.1), "not both"),
])
def test_bad_noise(kwargs, match):
    with pytest.raises(ValueError, match=match):
        gj.Noise(**kwargs)


def test_bad_arguments(box, box_grasps, monkeypatch):
    import grasp_jax._robust as robust_module

    def forbidden(*args, **kwargs):
        raise AssertionError("bad input reached map_grasps")

    monkeypatch.setattr(robust_module, "map_grasps", forbidden)
    p, n = box_grasps
    key = jax.random.key(0)
    call = dict(mu=MU, noise=NOISE, key=key)
    with pytest.raises(ValueError, match="moves contacts over the object"):
        gj.robust(None, p, n, **call)
    with pytest.raises(ValueError, match="samples must be an integer >= 2"):
        gj.robust(box, p, n, **call, samples=1)
    with pytest.raises(ValueError, match="quantile must be in"):
        gj.robust(box, p, n, **call, quantile=1.5)
    with pytest.raises(ValueError, match="key must be"):
        gj.robust(box, p, n, mu=MU, noise=NOISE, key=-3)
    with pytest.raises(ValueError, match="key must be"):
        gj.robust(box, p, n, mu=MU, noise=NOISE, key="seven")
    with pytest.raises(TypeError, match="noise must be a grasp_jax.Noise"):
        gj.robust(box, p, n, mu=MU, noise={"position": 0.1}, key=key)
    with pytest.raises(ValueError, match="mu must be a finite number > 0"):
        gj.robust(box, p, n, mu=-1.0, noise=NOISE, key=key)
    with pytest.raises(ValueError, match="normals must have the same shape"):
        gj.robust(box, p, n[..., :2], **call)
    with pytest.raises(ValueError, match="2D but the grasps are 3D"):
        gj.robust(objects.quad(), p, n, **call)


def test_optimize_for_robustness():
    """objective="robust": with zero noise exactly the steps of "closure"; with noise a finite mean
    objective whose best iterate is at least the start's; clear errors."""
    rectangle = objects.Polygon.from_vertices(np.array([[-1.0, -0.5], [1.0, -0.5], [1.0, 0.5], [-1.0, 0.5]]),
                                              name="rectangle")
    init = np.array([[[-1.0, 0.42], [1.0, 0.3]], [[-1.0, -0.4], [1.0, 0.1]]])
    kw = dict(init=init, fingers=2, mu=MU, steps=20, learning_rate=0.05)
    nominal = gj.optimize(rectangle, objective="closure", **kw)
    still = gj.optimize(rectangle, objective="robust", noise=gj.Noise(), **kw)
    np.testing.assert_allclose(still.history, nominal.history, rtol=1e-12, atol=1e-15)
    noisy = gj.optimize(rectangle, objective="robust", noise=gj.Noise(position=0.05, normal=0.05, friction=(0.7, 1.0)),
                        robust_samples=4, **kw)
    assert np.isfinite(noisy.history).all() and np.all(noisy.objective >= noisy.history[:, 0])
    assert noisy.force_closure.all() and noisy.objective_name == "robust"
    # friction lower than nominal by up to 30%: the mean objective is below the nominal one
    assert np.all(noisy.history[:, 0] < nominal.history[:, 0])
    with pytest.raises(ValueError, match="needs noise"):
        gj.optimize(rectangle, objective="robust", **kw)
    with pytest.raises(ValueError, match="noise is only used by it"):
        gj.optimize(rectangle, objective="closure", noise=gj.Noise(position=0.1), **kw)


def test_robust_objective_scores_the_perturbed_contacts_of_robust():
    """objective="robust" sees the very grasps ``gj.robust`` scores under the same draws (on a mesh,
    contacts walked across edges onto other faces, not kept in their face's plane), and its
    derivative in the chart displacement is that of the objective there (finite differences)."""
    import jax.numpy as jnp

    glass = objects.load("glass")
    surface = surfaces.for_object(glass, normals="flat")
    p, n = _grasps(glass, 1, seed=5)
    noise = gj.Noise(position=0.05, normal=0.05, friction=(0.7, 1.0))
    key, K = jax.random.key(3), 6
    pp, nn, mm = gj.perturb(glass, p, n, mu=MU, noise=noise, key=key, samples=K)
    rng = np.random.default_rng(0)
    W1, W2, w3 = rng.normal(size=(N, 3)), rng.normal(size=(N, 3)), rng.normal(size=N)

    def objective(points, normals, mu):
        return jnp.sum(points * W1) + jnp.sum(jnp.tanh(normals) * W2) + jnp.sum(mu * w3)

    with jax.enable_x64(True):
        contacts = surface.locate(p[0])
        draws = _noise.reparameterized(noise, key, K, N, 3, float(surface.scale), np.float64)

        @jax.jit  # and its gradient: op by op, they compiled 80 programs
        def mean(v):
            return _noise.robust_value(surface, contacts, v, MU, draws, objective, flags=noise._flags())

        (_, values), grad = jit(jax.value_and_grad(mean, has_aux=True))(jnp.zeros((N, 3)))
        expected = [objective(pp[0, k], nn[0, k], mm[0, k]) for k in range(K)]
        np.testing.assert_allclose(np.asarray(values), np.asarray(expected), rtol=0, atol=1e-12)
        h = 1e-6
        fd = np.zeros((N, 3))
        for i in range(N):
            for j in range(3):
                e = np.zeros((N, 3))
                e[i, j] = h
                fd[i, j] = (mean(jnp.asarray(e))[0] - mean(jnp.asarray(-e))[0]) / (2 * h)
        np.testing.assert_allclose(np.asarray(grad), fd, rtol=1e-6, atol=1e-8)
    moved = surface.locate(pp[0].reshape(-1, 3)).face.reshape(K, N)
    assert np.any(moved != np.asarray(contacts.face)[None])  # some contacts left their face
