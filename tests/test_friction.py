"""Critical friction (``grasp_jax._friction``): against bisection of HiGHS's min-weight margin,
GraspNet-1Billion's labels against its procedure (force-closure at each friction of its list),
implicit-function gradients against finite differences, batching against a loop, statuses and bad
input."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from _grasps import grasps, sample_box, sample_cylinder, unit
from _jit import jit

import grasp_jax as gj
from grasp_jax import reference
from grasp_jax._api import GRASPNET_FRICTIONS

FOUND, ABOVE_CAP, FRICTIONLESS = gj.FrictionStatus.FOUND, gj.FrictionStatus.ABOVE_CAP, gj.FrictionStatus.FRICTIONLESS
SAMPLERS = {"box": sample_box, "cylinder": sample_cylinder}
#: (shape, contact model, fingers, torsion)
CASES = [("box", "hard", 3, None), ("cylinder", "hard", 4, None), ("cylinder", "soft", 2, 0.1),
         ("box", "dexnet-soft", 3, 0.05)]


def _batch(shape, n, count, seed):
    return grasps(SAMPLERS[shape], count, n, np.random.default_rng(seed))


def _kw(contact, torsion):
    return {} if contact == "hard" else {"contact": contact, "torsion": torsion}


@pytest.mark.parametrize("shape,contact,n,torsion", CASES, ids=["-".join(map(str, c[:3])) for c in CASES])
def test_against_bisection_of_highs(shape, contact, n, torsion):
    points, normals = _batch(shape, n, 40, seed=n)
    mu, status = map(np.asarray, gj.critical_friction(points, normals, **_kw(contact, torsion)))
    ref = np.array([reference.critical_friction_highs(p, q, 8, contact, torsion or 0.0) for p, q in zip(points, normals)])
    assert (status != gj.FrictionStatus.NOT_CONVERGED).all()
    np.testing.assert_array_equal(np.isinf(mu), np.isinf(ref))
    np.testing.assert_array_equal(status == ABOVE_CAP, np.isinf(ref))
    finite = np.isfinite(ref)
    assert finite.sum() >= 20
    rel = np.abs(mu[finite] - ref[finite]) / ref[finite]
    # 1e-6 relative where l* rises steeply enough at the root; the interior-point margins are good
    # to ~1e-8, and where l* rises by 1e-3 per unit of mu that is 1e-5 in mu* (the reference's own
    # threshold of 1e-10 moves its root by 1e-7 there). Measured on 1,200 grasps: 3 above 1e-6.
    assert np.mean(rel <= 1e-6) >= 0.95, np.sort(rel)[-5:]
    assert rel.max() <= 2e-5, np.sort(rel)[-5:]


def test_graspnet_labels_follow_its_procedure():
    """GraspNet-1Billion's label: the first friction of 0.2, 0.4, ..., 1.2 at which the grasp is
    force-closure (Dex-Net's soft fingers), -1 where none; here by HiGHS at each level."""
    points, normals = _batch("box", 3, 40, seed=7)
    torsion = float(gj.dexnet_torsion(0.1, 0.5))
    mu, _ = map(np.asarray, gj.critical_friction(points, normals, contact="dexnet-soft", torsion=torsion))
    labels = gj.friction_label(mu)
    levels = GRASPNET_FRICTIONS
    expected = []
    for p, q in zip(points, normals):
        center = p.mean(0)
        scale = np.sqrt(((p - center) ** 2).sum(1).max())
        holds = [reference.min_weight_highs(p, q, level, 8, center, scale, contact="dexnet-soft", torsion=torsion,
                                            tight=True) > 1e-10 for level in levels]
        expected.append(levels[holds.index(True)] if any(holds) else -1.0)
    expected = np.array(expected)
    # a grasp whose mu* is within 1e-5 of a level may fall either side of it
    clear = np.min(np.abs(mu[:, None] - np.array(levels)[None]), axis=1) > 1e-5
    assert clear.sum() >= 35 and len(set(expected[clear])) >= 3
    np.testing.assert_array_equal(labels[clear], expected[clear])


def test_friction_label_levels():
    np.testing.assert_array_equal(gj.friction_label([0.0, 0.2, 0.25, 1.19, 1.2, np.inf]),
                                  [0.2, 0.4, 0.4, 1.2, -1.0, -1.0])
    with pytest.raises(ValueError, match="increasing"):
        gj.friction_label([0.3], levels=(0.4, 0.2))


def _found_grasps():
    points, normals = _batch("cylinder", 4, 24, seed=3)
    mu, status = map(np.asarray, gj.critical_friction(points, normals))
    keep = np.flatnonzero((status == FOUND) & (mu > 0.05) & (mu < 3.0))[:3]
    assert keep.size == 3
    return points[keep], normals[keep], mu[keep]


def test_gradient_against_finite_differences():
    points, normals, mu = _found_grasps()
    rng = np.random.default_rng(0)
    direction = rng.normal(size=points.shape)

    def total(p):
        return jnp.sum(gj.critical_friction(p, normals)[0])

    grad = np.asarray(jit(jax.grad(total))(jnp.asarray(points)))  # op by op: 471 programs, 20 s of compiling
    h = 1e-4
    plus = np.asarray(gj.critical_friction(points + h * direction, normals)[0])
    minus = np.asarray(gj.critical_friction(points - h * direction, normals)[0])
    fd = (plus - minus) / (2 * h)  # per grasp: the grasps are independent
    analytic = np.sum(grad * direction, axis=(1, 2))
    np.testing.assert_allclose(analytic, fd, rtol=2e-3, atol=1e-4)


def test_second_pass_resumes_the_first_pass_bracket():
    """A search cut short (2 steps of a short LP budget: most are left open) and resumed from the
    state it ended with (what ``gj.critical_friction``'s second pass does) finds the ``mu*`` of a
    search run whole from ``[0, cap]``."""
    from grasp_jax import _friction
    from grasp_jax._contact import ContactModel

    points, normals = _batch("cylinder", 4, 24, seed=11)
    run = jit(jax.vmap(lambda p, q, steps, its, start: _friction.critical_friction_one(
        p, q, 4.0, ContactModel(num_edges=8), steps=steps, iterations=its, start=start), in_axes=(0, 0, None, None, 0)))
    fresh = jnp.zeros((len(points), _friction.RESUME))
    _, first, state = run(points, normals, 2, 10, fresh)
    mu, status, _ = run(points, normals, 64, 30, state)
    whole, whole_status, _ = run(points, normals, 64, 30, fresh)
    assert np.sum(np.asarray(first) == gj.FrictionStatus.NOT_CONVERGED) >= len(points) // 2
    assert (np.asarray(status) == FOUND).all() and (np.asarray(whole_status) == FOUND).all()
    np.testing.assert_allclose(mu, whole, rtol=1e-6)


def test_batch_equals_a_loop_and_jit():
    points, normals = _batch("box", 3, 6, seed=11)
    mu, status = map(np.asarray, gj.critical_friction(points, normals))
    for i in range(len(points)):
        mu_i, status_i = gj.critical_friction(points[i], normals[i])
        assert int(status_i) == status[i]
        np.testing.assert_allclose(float(mu_i), mu[i], rtol=1e-7)  # the LPs' rounding depends on the batch
    traced = jit(lambda p, q: gj.critical_friction(p, q))(points, normals)
    np.testing.assert_allclose(np.asarray(traced[0]), mu, rtol=1e-7)
    np.testing.assert_array_equal(np.asarray(traced[1]), status)


def test_statuses():
    # two hard contacts never span the wrench space: above any cap
    two = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    mu, status = gj.critical_friction(two, two)
    assert np.isinf(float(mu)) and int(status) == ABOVE_CAP
    # ... two soft ones along a diameter need no friction but some: FOUND, mu* tiny
    mu, status = gj.critical_friction(two, two, contact="soft", torsion=0.05)
    assert int(status) == FOUND and 0 <= float(mu) <= 1e-6
    # seven contacts on a sphere whose normals positively span every direction hold without friction?
    # No: frictionless contacts on a sphere all pass through its centre (no torque). On a box, seven
    # well placed contacts do.
    box = np.array([[1, 0.5, 0.2], [1, -0.5, -0.2], [-1, 0.3, -0.4], [-1, -0.3, 0.4], [0.4, 1, 0.3], [-0.4, -1, -0.3],
                    [0.2, 0.3, 1.0]])
    box_normals = np.array([[1, 0, 0], [1, 0, 0], [-1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1.0]])
    mu, status = gj.critical_friction(box, box_normals)
    assert int(status) in (FRICTIONLESS, FOUND)
    if int(status) == FRICTIONLESS:
        assert float(mu) == 0.0


def test_float32():
    points, normals = _batch("cylinder", 4, 8, seed=5)
    mu64, st64 = map(np.asarray, gj.critical_friction(points, normals))
    mu32, st32 = gj.critical_friction(points.astype(np.float32), normals.astype(np.float32))
    assert mu32.dtype == np.float32
    ok = (st64 == FOUND) & (np.asarray(st32) == FOUND)
    assert ok.sum() >= 5
    np.testing.assert_allclose(np.asarray(mu32)[ok], mu64[ok], rtol=1e-3)


@pytest.mark.parametrize("kwargs,match", [
    ({"cap": 0.0}, "cap"),
    ({"cap": -1.0}, "cap"),
    ({"contact": "soft", "torsion": -0.1}, "torsion"),
    ({"contact": "soft"}, "torsion"),
    ({"contact": "sticky", "torsion": 0.1}, "contact"),
    ({"num_edges": 2}, "num_edges"),
])
def test_bad_input(kwargs, match):
    points, normals = _batch("box", 3, 2, seed=1)
    with pytest.raises(ValueError, match=match):
        gj.critical_friction(points, normals, **kwargs)


def test_bad_shapes():
    with pytest.raises(ValueError):
        gj.critical_friction(np.zeros((4, 3, 3)), np.zeros((4, 2, 3)))
    with pytest.raises(ValueError):
        gj.critical_friction(np.zeros((4, 3, 4)), np.zeros((4, 3, 4)))
    sphere = unit(np.random.default_rng(0).normal(size=(3, 3)))
    with pytest.raises(ValueError, match="NaN|finite"):
        gj.critical_friction(np.where(np.eye(3, dtype=bool), np.nan, sphere), sphere)


def test_sphere_antipodal_soft_pair_needs_the_angle_s_tangent():
    """Two soft contacts on a unit sphere at angle theta off antipodal: the closing line makes
    angle theta / 2 with each normal, so mu* = tan(theta / 2) / cos(pi / m) (the inscribed pyramid)."""
    theta = 0.4
    p1 = np.array([1.0, 0, 0])
    p2 = -np.array([np.cos(theta), np.sin(theta), 0])
    points = np.stack([p1, p2])
    # (a torsion much below 1e-4 of the grasp's size makes the wrenches rank deficient numerically:
    # their Gram matrix's eigenvalues go with its square)
    mu, status = gj.critical_friction(points, points, contact="soft", torsion=1e-3, num_edges=8)
    assert int(status) == FOUND
    # the line from p1 to p2, at angle theta/2 from each normal; the pyramid's inscribed cone has
    # half-angle atan(mu cos(pi/m)); the line's tangential direction decides how far in it is
    need = np.tan(theta / 2)
    assert need * 0.998 <= float(mu) <= need / np.cos(np.pi / 8) * 1.001


def test_cli_critical_friction_columns(monkeypatch, tmp_path, capsys):
    import signal

    from grasp_jax import cli, storage

    before = signal.getsignal(signal.SIGTERM)
    monkeypatch.chdir(tmp_path)
    try:
        rc = cli.main(["sample", "box", "--fingers", "3", "--num", "200", "--critical-friction", "--out", "a.npz"])
        out = capsys.readouterr().out
        assert rc == 0 and "critical mu" in out
        arrays, meta = storage.read_results(tmp_path / "a.npz")
        assert arrays["critical_mu"].shape == (200,) and arrays["critical_status"].dtype == np.int8
        mu_star = arrays["critical_mu"]
        clear = np.abs(mu_star - meta["mu"]) > 1e-4
        np.testing.assert_array_equal(arrays["force_closure"][clear], mu_star[clear] < meta["mu"])
        np.testing.assert_array_equal(arrays["friction_label"], gj.friction_label(mu_star))
        # score recomputes them from the stored contacts; without the flag there are none
        assert cli.main(["score", "a.npz", "--critical-friction", "--out", "b.npz", "-q"]) == 0
        again, _ = storage.read_results(tmp_path / "b.npz")
        np.testing.assert_allclose(again["critical_mu"], mu_star, rtol=1e-9)
        assert cli.main(["sample", "box", "--fingers", "3", "--num", "50", "--out", "c.npz", "-q"]) == 0
        assert "critical_mu" not in storage.read_results(tmp_path / "c.npz")[0]
    finally:
        signal.signal(signal.SIGTERM, before)


def test_optimizer_objective_lowers_the_friction_needed():
    from grasp_jax import objects

    box = objects.load("box")
    result = gj.optimize(box, 1, fingers=3, mu=0.5, starts=8, steps=12, objective="friction")
    history = np.asarray(result.history)
    assert np.all(np.isfinite(history))
    # the objective is -mu* (or below -cap where not force-closure at the cap); the best iterate
    # needs no more friction than the start, and most need less
    assert np.all(np.asarray(result.objective) >= history[:, 0] - 1e-12)
    assert np.mean(np.asarray(result.objective) > history[:, 0] + 1e-3) >= 0.5
    need, _ = gj.critical_friction(result.points, result.normals)
    found = np.asarray(result.objective) > -4.0
    np.testing.assert_allclose(-np.asarray(need)[found], np.asarray(result.objective)[found], rtol=1e-5, atol=1e-6)
