"""Soft contacts (``grasp_jax._contact``): verdicts, Q and margins against HiGHS on the soft wrench
set built in NumPy (``grasp_jax.reference``), two soft contacts against the closing-line
condition, Dex-Net's grasp matrix, gradients against finite differences, and bad input."""

from __future__ import annotations

import functools

import jax
import numpy as np
import pytest

import grasp_jax as gj
import grasp_jax.objects  # noqa: F401
from grasp_jax import reference

from _jit import jit
from _grasps import MU, grasps, load_mesh, mesh_sampler, sample_box, sample_cylinder, sample_sphere, unit

#: Real meshes held out for this file (no other test grasps them).
MESHES = ("pybullet_mug.obj", "ycb_050_medium_clamp.obj")
#: A verdict is compared where the reference margin is clear of this (the library decides at 1e-7).
CLEAR = 1e-6
M = 8


@functools.lru_cache(maxsize=None)
def _scored(contact: str):
    """evaluate and min_weight of a batch in one compiled function per contact model."""

    def run(P, Nrm, torsion):
        ev = gj.evaluate(P, Nrm, mu=MU, num_edges=M, contact=contact, torsion=torsion)
        mw = gj.min_weight(P, Nrm, mu=MU, num_edges=M, contact=contact, torsion=torsion)
        return ev.force_closure, ev.quality, ev.torque_span, mw

    return jit(run)


@pytest.fixture(scope="module")
def samplers(request):
    out = {"box": sample_box, "cylinder": sample_cylinder, "sphere": sample_sphere}
    try:
        mesh_dir = request.getfixturevalue("mesh_dir")
    except pytest.skip.Exception:
        return out
    for name in MESHES:
        out[name] = mesh_sampler(load_mesh(mesh_dir / name))
    return out


@pytest.mark.parametrize("contact,n", [("soft", 2), ("soft", 3), ("soft", 4), ("soft", 5),
                                       ("dexnet-soft", 2), ("dexnet-soft", 4)])
def test_soft_verdicts_q_and_margin_equal_highs(samplers, contact, n):
    """Verdicts clear of the tolerance equal the min-weight reference on the soft wrench set
    (torques about the origin, the objects' centre); Q and l* equal HiGHS's within 1e-7."""
    rng = np.random.default_rng(100 + n + 10 * len(contact))
    per = 12 if n < 5 else 8
    checked = disagree = positive = 0
    for name, sampler in samplers.items():
        P, Nrm = grasps(sampler, per, n, rng)
        for torsion in (0.02, 0.2):
            fc, q, span, mw = map(np.asarray, _scored(contact)(P, Nrm, torsion))
            for k in range(per):
                margin = reference.min_weight_highs(P[k], Nrm[k], MU, M, contact=contact, torsion=torsion)
                q_ref, _ = reference.quality_highs(P[k], Nrm[k], MU, M, contact=contact, torsion=torsion)
                assert abs(q[k] - q_ref) <= 1e-7, (name, torsion, k, q[k], q_ref)
                if np.isfinite(margin):
                    assert abs(mw[k] - margin) <= 1e-7, (name, torsion, k, mw[k], margin)
                # Dex-Net's pure moments come in pairs that cancel, so its l* >= 0 always, and
                # exactly 0 on every grasp that is not force-closure: those are clear too.
                if abs(margin) > CLEAR or (contact == "dexnet-soft" and margin <= 0):
                    checked += 1
                    positive += margin > 0
                    disagree += bool(fc[k]) != (margin > 0)
    assert disagree == 0
    assert checked >= 0.8 * len(samplers) * per * 2
    assert positive > 0  # both verdicts occur (soft contacts make two-finger grasps force-closure)


def _strictly_inside(direction, normal, mu, m=M):
    """Distance of the unit ``direction`` inside the linearized friction pyramid of a contact
    (outward ``normal``), in the pyramid's face inequalities; > 0 strictly inside (NumPy, from the
    frame of ``reference.frame``, not from the library's edges)."""
    z = -normal
    x, y = reference.frame(z)
    along = direction @ z
    if along <= 0:
        return along
    a, b = direction @ x / along, direction @ y / along
    # The m-gon with vertices mu (cos 2 pi j/m, sin 2 pi j/m): faces at angles (2j + 1) pi / m.
    faces = (2 * np.arange(m) + 1) * np.pi / m
    return along * np.min(mu * np.cos(np.pi / m) - (np.cos(faces) * a + np.sin(faces) * b))


def test_two_soft_contacts_and_the_closing_line():
    """10,000 random pairs (points and normals at random; ``inside``: how far the segment c_1 c_2
    lies inside both pyramids, clear of their boundary by 1e-6 where compared).

    The classical condition (force-closure iff the segment lies strictly inside both pyramids) is
    sufficient for any torsion, and exact as the torsion goes to 0. A finite torsion also holds
    pairs whose segment is slightly outside a pyramid (a moment about a normal that is not along
    the segment has a component across it, which tangential forces would otherwise supply):
    never by more than ``torsion / |c_2 - c_1|`` here (HiGHS on the NumPy wrench set agrees).
    """
    rng = np.random.default_rng(5)
    count = 10_000
    P = rng.uniform(-1, 1, size=(count, 2, 3))
    axis = unit(P[:, 1] - P[:, 0])
    length = np.linalg.norm(P[:, 1] - P[:, 0], axis=1)
    # Normals near the closing line (outward: against the squeeze), so both verdicts are common.
    Nrm = unit(np.stack([-axis, axis], axis=1) + rng.normal(scale=0.25, size=(count, 2, 3)))
    inside = np.array([min(_strictly_inside(a, nr[0], MU), _strictly_inside(-a, nr[1], MU))
                       for a, nr in zip(axis, Nrm)])
    clear = np.abs(inside) > 1e-6
    assert clear.sum() > 0.99 * count
    assert 0.2 < np.mean(inside > 0) < 0.8
    for torsion in (1e-5, 0.05):
        fc = np.asarray(gj.force_closure(P, Nrm, mu=MU, num_edges=M, contact="soft", torsion=torsion))
        assert np.all(fc[clear & (inside > 0)])  # sufficient
        band = (inside <= 0) & (inside > -torsion / length)
        np.testing.assert_array_equal(fc[clear & ~band], inside[clear & ~band] > 0)
        if torsion == 1e-5:
            assert not np.any(fc[clear & (inside <= 0)])  # exact for a small torsion
        else:
            assert np.any(fc[inside < 0])  # and not for a large one
    # No torsion: a hard pair, never force-closure in 3D.
    assert not np.any(gj.force_closure(P[:200], Nrm[:200], mu=MU, num_edges=M, contact="soft", torsion=0.0))
    assert not np.any(gj.force_closure(P[:200], Nrm[:200], mu=MU, num_edges=M))


def test_sphere_antipodal_grasp_holds_with_soft_fingers():
    p = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    assert not gj.force_closure(p, p, mu=0.5)
    for contact, torsion in (("soft", gj.patch_torsion(0.01, 0.5)), ("dexnet-soft", gj.dexnet_torsion(0.005, 0.5))):
        res = gj.evaluate(p, p, mu=0.5, contact=contact, torsion=torsion)
        assert res.force_closure and res.quality == pytest.approx(1.0, abs=1e-7)


def test_zero_torsion_is_the_hard_contact():
    """(Three fingers: the soft program is the one test_patch_torsion_and_more_torsion_never_hurts
    runs.)"""
    rng = np.random.default_rng(3)
    P, Nrm = grasps(sample_cylinder, 60, 3, rng)
    hard = gj.evaluate(P, Nrm, mu=MU, num_edges=M)
    assert 0 < np.count_nonzero(np.asarray(hard.force_closure)) < len(P)  # both verdicts
    for contact in ("soft", "dexnet-soft"):
        soft = gj.evaluate(P, Nrm, mu=MU, num_edges=M, contact=contact, torsion=0.0)
        np.testing.assert_array_equal(soft.force_closure, hard.force_closure)
        np.testing.assert_allclose(soft.quality, hard.quality, atol=1e-7)


def test_patch_torsion_and_more_torsion_never_hurts():
    assert gj.patch_torsion(0.03, 0.5) == pytest.approx(0.01)
    assert gj.dexnet_torsion(0.005, 0.4) == pytest.approx(np.pi * 0.005**2 * 0.4)
    rng = np.random.default_rng(4)
    P, Nrm = grasps(sample_box, 60, 3, rng)
    small = gj.evaluate(P, Nrm, mu=MU, contact="soft", torsion=0.01)
    large = gj.evaluate(P, Nrm, mu=MU, contact="soft", torsion=0.1)
    # The soft wrench set grows with the torsion (pairs with a smaller torsion are convex
    # combinations of those with a larger one): verdicts and Q can only grow.
    assert np.all(large.force_closure >= small.force_closure)
    assert np.all(np.asarray(large.quality) >= np.asarray(small.quality) - 1e-9)


def _dexnet_grasp_matrix(forces, torques, normals, finger_radius, friction_coef, rho):
    """Dex-Net's ``PointGraspMetrics3D.grasp_matrix(..., soft_fingers=True)`` (forces, torques:
    ``(3, K)``, normals ``(3, n)``; torques already divided by ``rho`` as its ferrari_canny_L1 does),
    transcribed: one column per force, then ``+torsion`` of each contact, then ``-torsion``."""
    num_normals = 2 * normals.shape[1]
    G = np.zeros([6, forces.shape[1] + num_normals])
    G[:3, : forces.shape[1]] = forces
    G[3:, : forces.shape[1]] = torques
    torsion = np.pi * finger_radius**2 * friction_coef * normals / rho
    G[3:, -num_normals : -num_normals // 2] = torsion
    G[3:, -num_normals // 2 :] = -torsion
    return G


def test_dexnet_model_is_dexnets_grasp_matrix():
    """The columns of ``contact="dexnet-soft"`` are those of Dex-Net's grasp matrix, and its
    margin is the min-weight LP on that matrix."""
    rng = np.random.default_rng(6)
    P, Nrm = grasps(sample_sphere, 6, 3, rng)
    radius, rho = 0.3, 1.7
    torsion = gj.dexnet_torsion(radius, MU)
    mw = np.asarray(gj.min_weight(P, Nrm, mu=MU, num_edges=M, contact="dexnet-soft", torsion=torsion,
                                  torque_scale=rho))
    for k in range(len(P)):
        edges = reference.cone_edges(Nrm[k], MU, M).reshape(-1, 3)
        arms = np.repeat(P[k], M, axis=0)
        G = _dexnet_grasp_matrix(edges.T, np.cross(arms, edges).T / rho, Nrm[k].T, radius, MU, rho)
        ours = reference.wrenches(P[k], Nrm[k], MU, M, None, rho, contact="dexnet-soft", torsion=torsion)
        np.testing.assert_allclose(np.sort(ours, axis=0), np.sort(G.T, axis=0), atol=1e-12)
        assert mw[k] == pytest.approx(_min_weight_of(G), abs=1e-7)


def _min_weight_of(G):
    from scipy.optimize import linprog

    D, K = G.shape
    A_eq = np.vstack([np.hstack([G, np.zeros((D, 1))]), np.r_[np.ones(K), 0.0]])
    res = linprog(np.r_[np.zeros(K), -1.0], A_ub=np.hstack([-np.eye(K), np.ones((K, 1))]), b_ub=np.zeros(K),
                  A_eq=A_eq, b_eq=np.r_[np.zeros(D), 1.0], bounds=[(None, None)] * (K + 1), method="highs")
    return -res.fun


def _soft_fc_grasps(count, seed, torsion):
    """Generic soft force-closure grasps of 3 contacts: HiGHS margin clearly positive, Q clear of
    0 and of its bound, normals clear of the frame's flip (normal_z = 0)."""
    rng = np.random.default_rng(seed)
    out_p, out_n = [], []
    while len(out_p) < count:
        (p,), (nr,) = grasps(sample_sphere, 1, 3, rng)
        if np.abs(nr[:, 2]).min() < 0.05:
            continue
        q, eq = reference.quality_highs(p, nr, MU, M, contact="soft", torsion=torsion)
        margin = reference.min_weight_highs(p, nr, MU, M, contact="soft", torsion=torsion)
        if eq and 0.05 < q < np.sqrt(1 + MU**2) - 0.05 and margin > 1e-3:
            out_p.append(p)
            out_n.append(nr)
    return np.stack(out_p), np.stack(out_n)


def test_soft_quality_gradients_equal_finite_differences_of_highs():
    """dQ/d(points, normals, mu, torsion) of a soft grasp (envelope theorem) against central
    differences of HiGHS on the NumPy soft wrench set."""
    torsion = 0.15
    P, Nrm = _soft_fc_grasps(4, 11, torsion)
    grad = jit(jax.grad(lambda P, Nrm, mu, t: gj.quality(P, Nrm, mu=mu, num_edges=M, contact="soft",
                                                         torsion=t).sum(), argnums=(0, 1, 2, 3)))
    gp, gn, gmu, gt = map(np.asarray, grad(P, Nrm, MU, torsion))
    h = 1e-6

    def q(p, nr, mu=MU, t=torsion):
        return reference.quality_highs(p, nr, mu, M, contact="soft", torsion=t)[0]

    for k in range(len(P)):
        for which, g in ((0, gp[k]), (1, gn[k])):
            fd = np.zeros_like(g)
            for i in range(3):
                for j in range(3):
                    up = [P[k].copy(), Nrm[k].copy()]
                    down = [P[k].copy(), Nrm[k].copy()]
                    up[which][i, j] += h
                    down[which][i, j] -= h
                    fd[i, j] = (q(*up) - q(*down)) / (2 * h)
            assert np.linalg.norm(g - fd) <= 1e-5 * np.linalg.norm(fd) + 1e-7, (k, which, g, fd)
    fd_mu = sum((q(p, nr, mu=MU + h) - q(p, nr, mu=MU - h)) / (2 * h) for p, nr in zip(P, Nrm))
    fd_t = sum((q(p, nr, t=torsion + h) - q(p, nr, t=torsion - h)) / (2 * h) for p, nr in zip(P, Nrm))
    assert gmu == pytest.approx(fd_mu, rel=1e-5, abs=1e-7)
    assert gt == pytest.approx(fd_t, rel=1e-5, abs=1e-7)


def test_soft_objectives_and_optimizer():
    """The closure objective is positive exactly on soft force-closure grasps; the optimizer finds
    two-finger soft grasps on a box, which hard contacts never hold (measured, 32 starts x 60
    steps: 75% force-closure with ``"min_weight"``, 28% with ``"closure"``, whose torque margin
    about ``c_1`` is small on antipodal pairs)."""
    rng = np.random.default_rng(8)
    P, Nrm = grasps(sample_box, 30, 2, rng)
    fc = np.asarray(gj.force_closure(P, Nrm, mu=MU, contact="soft", torsion=0.05))
    value = np.asarray(gj.objective(P, Nrm, mu=MU, contact="soft", torsion=0.05))
    np.testing.assert_array_equal(value > 1e-7, fc)
    box = gj.objects.load("box")  # 8 x 5 x 3 cm; a 5 mm torsion
    res = gj.optimize(box, 0, fingers=2, mu=MU, starts=16, steps=60, contact="soft", torsion=0.005,
                      objective="min_weight")
    assert np.mean(res.evaluation.force_closure) > 0.5
    hard = gj.optimize(box, 0, fingers=2, mu=MU, starts=16, steps=10, objective="min_weight")
    assert not np.any(hard.evaluation.force_closure)


@pytest.mark.parametrize(
    "kwargs,message",
    [
        (dict(contact="soft"), "needs torsion="),
        (dict(contact="soft", torsion=-0.1), "torsion must be a finite number >= 0"),
        (dict(contact="soft", torsion=float("nan")), "torsion must be a finite number"),
        (dict(contact="soft", torsion=[0.1, 0.2]), "torsion must be a real scalar"),
        (dict(torsion=0.1), "torsion is the torsional coefficient of soft contacts"),
        (dict(contact="sticky", torsion=0.1), "contact must be one of"),
    ],
)
def test_bad_contact_arguments_are_one_clear_error(kwargs, message):
    p = np.array([[1.0, 0, 0], [-1.0, 0, 0]])
    for fn in (gj.evaluate, gj.quality, gj.min_weight, gj.objective, gj.ferrari_canny):
        with pytest.raises(ValueError, match=message):
            fn(p, p, mu=0.5, **kwargs)


def test_soft_contacts_are_refused_in_2d():
    p = np.array([[1.0, 0], [-1.0, 0]])
    with pytest.raises(ValueError, match="3D only"):
        gj.evaluate(p, p, mu=0.5, contact="soft", torsion=0.1)
