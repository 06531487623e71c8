"""Force-closure verdicts, quality Q, min-weight margins, certificates and the Ferrari-Canny
baseline of random grasps, against the independent NumPy/SciPy-HiGHS reference."""

from __future__ import annotations

import dataclasses
import functools

import jax
import numpy as np
import pytest
from scipy.spatial import ConvexHull

import grasp_jax as gj
from grasp_jax import reference

from _jit import jit
from _grasps import (MU, QUAD, STAR, grasps, load_mesh, mesh_sampler, sample_box, sample_cylinder,
                     sample_polygon, sample_sphere)

MARGIN = 1e-6  # grasps within this of the force-closure boundary are "marginal"
QMAX = np.sqrt(1 + MU**2)

# (d, n, m): one compilation per key (the dominant cost of this module), so 2D, which the
# reference confirms as readily, gets fewer finger counts than 3D.
KEYS_2D = [(2, n, 8) for n in (2, 3, 4, 6)]
KEYS_3D = [(3, n, 8) for n in (2, 3, 4, 5, 7)] + [(3, 4, 25)]
KEYS = KEYS_2D + KEYS_3D
MESHES = ("trimesh_featuretype.STL", "ycb_011_banana.obj")


@dataclasses.dataclass
class Case:
    points: np.ndarray
    normals: np.ndarray
    labels: np.ndarray
    m: int
    ev: gj.GraspEvaluation  # fields as NumPy arrays
    margin: np.ndarray  # gj.min_weight
    paper_fc: np.ndarray | None  # torque_test="paper" (None where not computed)
    q_ref: np.ndarray
    eq_ref: np.ndarray
    l_ref: np.ndarray

    @property
    def single_face(self):
        """Grasps whose contacts all have the same normal (on one flat face, or on parallel faces
        facing the same way): their min-weight LP is infeasible with a rank-deficient constraint
        matrix, see :func:`test_single_face_grasps_min_weight`."""
        return np.all(np.abs(self.normals - self.normals[:, :1]) < 1e-12, axis=(1, 2))

    @property
    def d(self):
        return self.points.shape[-1]

    def __len__(self):
        return len(self.points)


def _with_paper(key) -> bool:
    """In 2D eq. (21) is the exact test; it is compared on the smaller grasps only."""
    d, n, m = key
    return d == 3 or n <= 3


@functools.lru_cache(maxsize=None)
def _engine(m: int, paper: bool):
    """evaluate (exact, and paper) and min_weight of a batch under one jit: one compilation
    (with the suite's compiler options, ``_jit.py``)."""

    def run(points, normals):
        ev = gj.evaluate(points, normals, mu=MU, num_edges=m)
        margin = gj.min_weight(points, normals, mu=MU, num_edges=m)
        if not paper:
            return ev, margin, None
        paper_fc = gj.evaluate(points, normals, mu=MU, num_edges=m, torque_test="paper").force_closure
        return ev, margin, paper_fc

    return jit(run)


@pytest.fixture(scope="module")
def samplers(request):
    out = {"quad": lambda c, r: sample_polygon(QUAD, c, r), "star": lambda c, r: sample_polygon(STAR, c, r),
           "box": sample_box, "cylinder": sample_cylinder, "sphere": sample_sphere}
    try:
        mesh_dir = request.getfixturevalue("mesh_dir")
    except pytest.skip.Exception:
        return out
    for name in MESHES:
        out[name] = mesh_sampler(load_mesh(mesh_dir / name))
    return out


def _shapes_for(key, samplers):
    d, n, m = key
    if d == 2:
        return {"quad": 40, "star": 40}
    if m == 25:
        return {name: 12 for name in ("box", "cylinder", *MESHES) if name in samplers}
    per = {name: 16 for name in ("box", "cylinder", "sphere", *MESHES) if name in samplers}
    if n == 2:
        per["sphere"] = 60  # the eq. (15) false positives of MATH.md
    return per


@pytest.fixture(scope="module")
def cases(samplers):
    cache: dict = {}

    def get(key) -> Case:
        if key not in cache:
            d, n, m = key
            rng = np.random.default_rng(1000 * d + 10 * n + m)
            ps, ns, labels = [], [], []
            for p, nr in _single_face_grasps():
                if p.shape == (n, d):
                    ps.append(p[None])
                    ns.append(nr[None])
                    labels.append("constructed single face")
            for name, count in _shapes_for(key, samplers).items():
                p, nr = grasps(samplers[name], count, n, rng)
                ps.append(p)
                ns.append(nr)
                labels += [name] * count
            points, normals = np.concatenate(ps), np.concatenate(ns)
            ev, margin, paper = _engine(m, _with_paper(key))(points, normals)
            ev, margin = jax.tree_util.tree_map(np.asarray, (ev, margin))
            paper = None if paper is None else np.asarray(paper)
            q_ref, eq_ref = zip(*(reference.quality_highs(p, nr, MU, m) for p, nr in zip(points, normals)))
            l_ref = [reference.min_weight_highs(p, nr, MU, m) for p, nr in zip(points, normals)]
            cache[key] = Case(points, normals, np.array(labels), m, ev, margin, paper,
                              np.array(q_ref), np.array(eq_ref), np.array(l_ref))
        return cache[key]

    return get


def _ids(keys):
    return [f"d{d}-n{n}-m{m}" for d, n, m in keys]


# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("key", KEYS, ids=_ids(KEYS))
def test_statuses_and_invariants(cases, key):
    c = cases(key)
    ev = c.ev
    assert ev.force_closure.shape == (len(c),) and ev.certificate.shape == (len(c), 3 if c.d == 2 else 6)
    assert np.all(ev.quality_status == gj.Status.OPTIMAL)  # the normalized quality LP is always feasible
    assert np.all(np.isfinite(ev.quality)) and np.all(np.isfinite(ev.delta))
    assert np.all(ev.quality >= 0) and np.all(ev.quality <= QMAX + 1e-9)
    assert np.all(ev.delta <= QMAX + 1e-9) and np.all(ev.delta >= -1 - 1e-6)  # delta = -1 is always feasible
    np.testing.assert_array_equal(ev.quality, np.where(ev.equilibrium, ev.delta, 0.0))
    np.testing.assert_array_equal(ev.force_closure, ev.equilibrium & ev.torque_span)
    # The quality LP is solved unless the torque LP proves the torques opposed (l* < -margin,
    # hard contacts, float64): then delta = -1 exactly, with no iteration (_closure.torque_stage).
    opposed = (ev.torque_status == gj.Status.OPTIMAL) & (ev.torque_margin < -1e-7) if c.d == 3 else np.zeros(len(c), bool)
    assert np.all(ev.iterations[~opposed] > 0)
    np.testing.assert_array_equal(ev.iterations[opposed], 0)
    np.testing.assert_array_equal(ev.delta[opposed], -1.0)


@pytest.mark.parametrize("key", KEYS, ids=_ids(KEYS))
def test_lp_statuses(cases, key):
    """Every LP ends OPTIMAL or certified INFEASIBLE: no NOT_CONVERGED, single-face grasps
    (rank-deficient, inconsistent LPs) included."""
    c = cases(key)
    ev = c.ev
    assert np.all(np.isin(ev.torque_status, [gj.Status.OPTIMAL, gj.Status.INFEASIBLE])), np.flatnonzero(
        ev.torque_status == gj.Status.NOT_CONVERGED)
    assert np.all(ev.converged)


@pytest.mark.parametrize("key", KEYS, ids=_ids(KEYS))
def test_quality_vs_highs(cases, key):
    c = cases(key)
    q = c.ev.quality
    non_marginal = np.abs(c.q_ref) > MARGIN
    non_marginal |= ~c.eq_ref & (c.ev.delta < -MARGIN)
    assert non_marginal.mean() > 0.5
    np.testing.assert_allclose(q[non_marginal], c.q_ref[non_marginal], atol=1e-6, rtol=0)
    np.testing.assert_array_equal(c.ev.equilibrium[non_marginal], c.q_ref[non_marginal] > 0)
    # Every grasp, marginal or not, agrees to the same tolerance on Q itself.
    np.testing.assert_allclose(q, c.q_ref, atol=1e-6, rtol=0)


@pytest.mark.parametrize("key", KEYS, ids=_ids(KEYS))
def test_force_closure_vs_min_weight(cases, key):
    """The exact central-axis test is the classical definition: force-closure iff ``l* > 0``."""
    c = cases(key)
    decided = np.abs(c.l_ref) > MARGIN
    np.testing.assert_array_equal(c.ev.force_closure[decided], c.l_ref[decided] > 0)
    if not (c.d == 3 and key[1] == 2):
        assert decided.mean() > 0.5
    else:
        assert not np.any(c.ev.force_closure), "a 2-finger hard-contact grasp in 3D is never force-closure"
        assert np.all(c.l_ref <= MARGIN)


@pytest.mark.parametrize("key", KEYS, ids=_ids(KEYS))
def test_min_weight_vs_highs(cases, key):
    """gj.min_weight is HiGHS's ``l*`` (0 for rank-deficient wrenches, -inf for an infeasible LP)."""
    c = cases(key)
    margin, l_ref = c.margin, c.l_ref
    finite = np.isfinite(l_ref)
    np.testing.assert_allclose(margin[finite], l_ref[finite], atol=1e-7, rtol=1e-6)
    np.testing.assert_array_equal(margin[~finite], l_ref[~finite])
    assert np.all(c.margin <= 1.0 / (len(c.points[0]) * (2 if c.d == 2 else c.m)) + 1e-12)


def test_real_meshes_are_graspable(mesh_dir, cases):
    """The two real meshes load as closed volumes with outward normals, and their random grasps
    include force-closure ones (checked against HiGHS with the other grasps above)."""
    for name in MESHES:
        mesh = load_mesh(mesh_dir / name)
        assert mesh.is_watertight and mesh.volume > 0  # positive volume: outward face normals
    c = cases((3, 4, 8))
    for name in MESHES:
        sel = c.labels == name
        assert sel.sum() == 16
        np.testing.assert_allclose(np.linalg.norm(c.normals[sel], axis=-1), 1.0, rtol=1e-12)
        assert c.ev.force_closure[sel].any() and (c.l_ref[sel] > MARGIN).any()


def test_both_verdicts_occur(cases):
    """The random grasps exercise both outcomes, for every shape (else the comparisons are vacuous)."""
    for key in KEYS:
        c = cases(key)
        if c.d == 3 and key[1] == 2:
            continue
        assert 0 < c.ev.force_closure.sum() < len(c), key
    for d in (2, 3):
        fc_labels = set()
        for key in (KEYS_2D if d == 2 else KEYS_3D):
            c = cases(key)
            fc_labels |= set(c.labels[c.ev.force_closure])
        assert fc_labels == set(cases((d, 4, 8)).labels) - {"constructed single face"}, fc_labels


PAPER_KEYS = [k for k in KEYS if _with_paper(k)]


@pytest.mark.parametrize("key", PAPER_KEYS, ids=_ids(PAPER_KEYS))
def test_paper_torque_test(cases, key):
    """Eq. (15) never misses a force-closure grasp; in 2D eq. (21) is exact."""
    c = cases(key)
    fc, paper = c.ev.force_closure, c.paper_fc
    assert not np.any(fc & ~paper), "the paper's test missed a force-closure grasp"
    if c.d == 2:
        np.testing.assert_array_equal(paper, fc)


def test_paper_false_positives_on_two_finger_sphere_grasps(cases):
    """MATH.md fact 2: eq. (15) calls some 2-finger sphere grasps force-closure; they are not."""
    c = cases((3, 2, 8))
    sphere = c.labels == "sphere"
    false_pos = sphere & c.paper_fc & ~c.ev.force_closure
    assert false_pos.sum() >= 2, false_pos.sum()
    assert np.all(c.l_ref[false_pos] <= MARGIN) and np.all(c.margin[false_pos] <= MARGIN)
    # They are in equilibrium (eq. 17): only the torque test tells them apart.
    assert np.all(c.ev.equilibrium[false_pos]) and np.all(c.eq_ref[false_pos])
    assert not np.any(c.ev.torque_span[false_pos])


def test_paper_false_positives_rate_3d(cases):
    """Over all random 3D grasps, eq. (15) says force-closure more often than the exact test."""
    extra = sum(int(np.sum(cases(k).paper_fc & ~cases(k).ev.force_closure)) for k in KEYS_3D)
    assert extra > 0


@pytest.mark.parametrize("key", KEYS, ids=_ids(KEYS))
def test_certificates(cases, key):
    c = cases(key)
    cert = c.ev.certificate
    fc = c.ev.force_closure
    np.testing.assert_array_equal(cert[fc], 0.0)
    np.testing.assert_allclose(np.linalg.norm(cert[~fc], axis=1), 1.0, rtol=1e-9)
    for k in np.flatnonzero(~fc):
        w = reference.wrenches(c.points[k], c.normals[k], MU, c.m)
        scale = np.abs(w).max()
        assert (w @ cert[k]).min() >= -1e-6 * scale, (k, c.labels[k], (w @ cert[k]).min())


def _epsilon_direct(w: np.ndarray) -> float:
    """Ferrari-Canny epsilon computed directly: for each unit facet normal ``u`` of the hull, the
    support value ``max_k u . w_k`` is the distance from the origin to that facet's hyperplane
    (positive on the inner side); epsilon is the smallest, clipped at 0."""
    try:
        hull = ConvexHull(w, qhull_options="Qt")
    except Exception:  # noqa: BLE001 - degenerate (rank deficient) wrench sets
        return 0.0
    normals = hull.equations[:, :-1]
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, rtol=1e-9)
    support = (w @ normals.T).max(axis=0)
    return max(float(support.min()), 0.0)


FC_KEYS = [(2, 2, 8), (2, 3, 8), (2, 4, 8), (3, 3, 8), (3, 4, 8)]


@pytest.mark.parametrize("key", FC_KEYS, ids=_ids(FC_KEYS))
def test_ferrari_canny(cases, key):
    c = cases(key)
    idx = np.linspace(0, len(c) - 1, min(len(c), 40)).astype(int)  # a spread over all shapes
    eps, vol = gj.ferrari_canny(c.points[idx], c.normals[idx], mu=MU, num_edges=c.m)
    assert eps.shape == (len(idx),) and vol.shape == (len(idx),)
    assert np.all(eps >= 0) and np.all(vol >= 0)
    assert np.all(eps <= QMAX)  # the ball lies inside the hull of wrenches of norm >= |v| = QMAX
    direct = np.array([_epsilon_direct(reference.wrenches(c.points[k], c.normals[k], MU, c.m)) for k in idx])
    np.testing.assert_allclose(eps, direct, atol=1e-9)
    decided = np.abs(c.l_ref[idx]) > MARGIN
    fc = c.ev.force_closure[idx]
    np.testing.assert_array_equal((eps > 1e-9)[decided], fc[decided])
    assert fc.any() and not fc.all()
    assert np.all(vol[fc] > 0)


def test_public_wrappers_match_evaluate(cases):
    """gj.force_closure / gj.min_weight (concrete, chunked path) agree with the results computed
    under jit (and emit no warning: pytest turns warnings into errors). gj.quality: see
    test_autodiff and test_batching."""
    assert cases((2, 2, 8)).single_face.any()  # included: no "did not converge" warning
    for key in ((2, 2, 8), (2, 3, 8)):
        c = cases(key)
        fc = np.asarray(gj.force_closure(c.points, c.normals, mu=MU))
        np.testing.assert_array_equal(fc, c.ev.force_closure)
        margin = np.asarray(gj.min_weight(c.points, c.normals, mu=MU))
        np.testing.assert_allclose(margin, c.margin, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# Grasps with every contact on one flat face.


def _single_face_grasps():
    """Constructed grasps with all contacts on one face (same normal), added to the random grasps
    of their key: never force-closure, and their min-weight LP is infeasible."""
    quad = np.array([[0.3, 0.0], [1.6, 0.0]]), np.array([[0.0, -1.0], [0.0, -1.0]])
    top = np.array([[0.1, 0.2, 0.4], [-0.5, 0.3, 0.4], [0.6, -0.4, 0.4]]), np.tile([0.0, 0.0, 1.0], (3, 1))
    return quad, top, (top[0][:2], top[1][:2])


def test_single_face_grasps_are_sampled(cases):
    for key in ((2, 2, 8), (3, 3, 8)):
        c = cases(key)
        assert c.single_face.any()
        np.testing.assert_array_equal(c.l_ref[c.single_face], -np.inf)  # HiGHS: infeasible
        assert not np.any(c.ev.force_closure[c.single_face])
    c = cases((3, 2, 8))  # two contacts in 3D: rank-deficient wrenches, l* = 0, not a bug case
    assert c.single_face.any()
    np.testing.assert_array_equal(c.l_ref[c.single_face], 0.0)
    np.testing.assert_array_equal(c.margin[c.single_face], 0.0)


@pytest.mark.parametrize("key", [(2, 2, 8), (3, 3, 8)], ids=_ids([(2, 2, 8), (3, 3, 8)]))
def test_single_face_grasps_min_weight(cases, key):
    """All contacts on one face: the min-weight LP is infeasible with a rank-deficient constraint
    matrix (the sum of the normal force components equals the weight row), which the solver
    certifies up front from the null space of ``A^T``."""
    c = cases(key)
    sel = c.single_face
    assert sel.any()
    np.testing.assert_array_equal(c.margin[sel], c.l_ref[sel])


def test_single_face_grasps_torque_lp(cases):
    """Three contacts with one normal in 3D: the torque LP ends OPTIMAL or INFEASIBLE, never
    NOT_CONVERGED; on one plane (the constructed grasp) it is infeasible with a rank-deficient
    matrix; the certificate separates every primitive wrench."""
    c = cases((3, 3, 8))
    sel = np.flatnonzero(c.single_face)
    assert len(sel)
    assert np.all(np.isin(c.ev.torque_status[sel], [gj.Status.OPTIMAL, gj.Status.INFEASIBLE]))
    constructed = sel[c.labels[sel] == "constructed single face"]
    assert len(constructed) == 1
    np.testing.assert_array_equal(c.ev.torque_status[constructed], gj.Status.INFEASIBLE)
    assert not np.any(c.ev.torque_span[sel])
    for k in sel:
        w = reference.wrenches(c.points[k], c.normals[k], MU, c.m)
        assert (w @ c.ev.certificate[k]).min() >= -1e-6 * np.abs(w).max(), k


def test_single_face_grasps_verdict(cases):
    """Whatever the LP statuses, single-face grasps are never called force-closure."""
    for key in KEYS:
        c = cases(key)
        assert not np.any(c.ev.force_closure[c.single_face])


def test_ill_posed_quality_lp_converges():
    """A grasp whose only equilibrium uses the first contact alone (``delta* = -1``): its quality LP
    has no strictly feasible point, tau and kappa of the homogeneous model both go to 0, and the
    residuals stall just above the tolerance. It used to end NOT_CONVERGED at any budget."""
    p = np.array([[0.54923158, -0.53914488, 0.16211562], [0.63366817, 0.47040404, -0.19162],
                  [-0.72085384, 0.41473162, 0.17982255], [0.22515462, -0.59723012, 0.23525478]])
    n = np.array([[0.3950581, -0.79143432, 0.46643415], [0.45842906, 0.69452073, -0.55451217],
                  [-0.54438781, 0.63919334, 0.54320695], [0.14468182, -0.78321088, 0.60468826]])
    ev = gj.evaluate(p, n, mu=MU)
    assert ev.quality_status == gj.Status.OPTIMAL and ev.torque_status != gj.Status.NOT_CONVERGED
    assert ev.delta == pytest.approx(-1.0, abs=1e-5)
    assert not ev.force_closure and ev.quality == 0.0
    assert reference.quality_highs(p, n, MU) == (0.0, False)
    assert reference.min_weight_highs(p, n, MU) < -1e-3


def test_wandering_iterates_end_at_the_best_one():
    """A 4-finger, 25-edge grasp whose batched iterates reach a residual of 2e-9, just above the
    tolerance, then wander off (5e-2 at iteration 40): the best iterate is reported, optimal to
    HiGHS's value. It used to end NOT_CONVERGED at any budget."""
    p = np.array([[0.32821949271761786, -0.6303936274909832, -0.14253022785885136],
                  [0.47814720407880257, -0.6147920908479223, -0.0015249848336177639],
                  [-0.6551941483090504, -0.06741248399069681, -0.37464858686397323],
                  [0.3222894284565041, -0.3518155846821066, -0.4011013290497455]])
    n = np.array([[0.22714867339637165, -0.8903516526083171, -0.39455977350954985],
                  [0.3561052933420155, -0.934434792398047, -0.004542995687395705],
                  [-0.39918285933273, -0.0838197043830236, -0.913031928232572],
                  [0.18034858494518097, -0.40177755601920445, -0.8978024189026813]])
    ev = gj.evaluate(p, n, mu=MU, num_edges=25)
    assert ev.quality_status == gj.Status.OPTIMAL
    assert ev.delta == pytest.approx(-0.9184528415710564, abs=1e-7)  # HiGHS, the normalized LP
    assert reference.quality_highs(p, n, MU, 25) == (0.0, False)


@jit
def _quality_bounds(p, n, noise):
    from grasp_jax import _programs
    from grasp_jax import lp as _lp
    from grasp_jax._cones import cone_edges, safe_normalize

    def one(p, n, e):
        edges = cone_edges(safe_normalize(n), MU, 8, None)
        lp = _programs.quality_lp(_programs.about_first(p, safe_normalize(n), edges), edges)
        (sol,) = _lp.solve(lp, consistent=True)
        tight, _ = _programs.quality_bound(lp, sol.y)
        loose, slack = _programs.quality_bound(lp, sol.y + e)
        return -sol.value - _programs.SHIFT, sol.status, tight, loose, slack

    return jax.vmap(one)(p, n, noise)


def test_quality_bound_is_weak_duality():
    """``quality_bound`` (what turns an unfinished quality LP into ``BOUNDED``): at the optimal
    dual it is delta* itself; from any other dual vector it is never below delta*."""
    rng = np.random.default_rng(11)
    p, n = grasps(sample_sphere, 400, 4, rng)
    noise = 0.3 * rng.standard_normal((len(p), 7)) * rng.uniform(0, 1, (len(p), 1))
    delta, status, tight, loose, slack = map(np.asarray, _quality_bounds(p, n, noise))
    assert np.all(status == gj.Status.OPTIMAL)
    np.testing.assert_allclose(tight, delta, atol=1e-7)
    finite = np.isfinite(loose)
    assert finite.mean() > 0.5 and np.median(slack[finite]) < 1e-12
    assert np.all(loose[finite] + slack[finite] >= delta[finite] - 1e-9)
    assert np.any(loose[finite] > delta[finite] + 1e-3)  # the noise did move the bound


def test_full_rank_agrees_with_lapack():
    """``_closure.full_rank`` (the 6-D rank test of the min-weight margin, without an eigensolver)
    against NumPy's ``eigvalsh``: sets of every rank, and sets whose least eigenvalue is just
    either side of the threshold (1% in float64, 20% in float32, well above the rounding of a
    float32 Gram matrix), in float64 and float32."""
    from grasp_jax._programs import full_rank
    from grasp_jax._constants import tolerances

    rng = np.random.default_rng(7)
    rank_test = jax.jit(jax.vmap(full_rank))

    def lapack(X, dtype):
        ev = np.linalg.eigvalsh(np.einsum("bki,bkj->bij", X, X).astype(np.float64))
        return ev[:, 0] > tolerances(dtype).rank * ev[:, -1]

    for dtype in (np.float64, np.float32):
        r, near = tolerances(dtype).rank, (0.01 if dtype == np.float64 else 0.2)
        sets = [rng.normal(size=(300, K, rank)) @ rng.normal(size=(300, rank, 6)) for rank in range(1, 7) for K in (6, 20)]
        # A chosen spectrum: the least eigenvalue just above or below the threshold, the largest 1,
        # the second largest 0.99 (the slowest case of the squarings).
        for ratio in ((1 + near) * r, (1 - near) * r):
            Q = np.linalg.qr(rng.normal(size=(300, 6, 6)))[0]
            lam = np.exp(rng.uniform(np.log(ratio), 0.0, size=(300, 6)))
            lam[:, 0], lam[:, 1], lam[:, 2] = ratio, 1.0, 0.99
            sets.append(np.sqrt(lam)[:, :, None] * np.swapaxes(Q, 1, 2))
        for X in sets:
            X = X.astype(dtype)
            np.testing.assert_array_equal(np.asarray(rank_test(X)), lapack(X, dtype))
    assert not np.any(np.asarray(rank_test(np.zeros((2, 8, 6)))))
