"""Robust grasp labels: force-closure and quality under noise, by Monte Carlo (Dex-Net 2.0's
robust metrics).

:func:`robust` draws ``samples`` perturbations of every grasp (``_noise``) and scores them with
the single-grasp programs of :func:`grasp_jax.evaluate` and :func:`grasp_jax.min_weight` through
``_batch.map_grasps``, grasps x samples flattened, :data:`ROWS` at a time. The draws depend on the
key, the sample and the contact slot only (common random numbers: every grasp meets the same
perturbations).
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from . import _closure, _noise
from ._api import MIN_WEIGHT_BLOCK, _bind, _check_common, _passes, _unfinished, contact_model
from ._batch import Retry, Staged, map_grasps, pad_rows
from ._constants import DEFAULT_NUM_EDGES
from ._contact import ContactModel
from ._noise import Noise, perturb_all
from ._validate import check_int, check_key, check_scalar, is_traced
from .lp import Status
from .surfaces import as_surface

#: Perturbed grasps (grasps x samples) scored per slice: memory is set by this, not by the batch.
ROWS = 65536
# ---------------------------------------------------------------------------------------------
# Scoring: the single-grasp functions of evaluate and min_weight, with per-contact friction.


def _evaluate_single(points, normals, tangents, mu, shared, *, torque_test):
    model, iterations, restarts = shared  # traced: every pass runs one compiled program
    return _closure.evaluate_one(points, normals, mu, model, torque_test, tangents, iterations, restarts)


def _torque_stage(points, normals, tangents, mu, shared):
    model, iterations, restarts = shared
    return _closure.torque_stage(points, normals, mu, model, tangents, iterations, restarts)


def _quality_stage(points, normals, tangents, mu, torques, shared):
    model, iterations, restarts = shared
    return _closure.quality_stage(points, normals, mu, model, torques, tangents, iterations, restarts)


def _dual_single(points, normals, tangents, mu, shared):
    (model,) = shared
    return _closure.quality_dual_one(points, normals, mu, model, tangents)


def _settled_single(points, normals, tangents, mu, y, shared):
    (model,) = shared
    return _closure.out_of_equilibrium(points, normals, mu, model, y, tangents)


def _min_weight_single(points, normals, tangents, mu, shared):
    model, origin, torque_scale = shared
    return _closure.min_weight_one(points, normals, mu, model, origin, torque_scale, tangents, None)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class RobustResult:
    """What :func:`grasp_jax.robust` estimates for each grasp, from ``samples`` perturbations.

    Every array field has the leading batch shape ``B`` of the grasps (NumPy arrays). Q counts 0
    where a perturbed grasp is not in equilibrium (as :func:`grasp_jax.evaluate` reports it); the
    min-weight margin ``l*`` counts 0 where it is not force-closure (``max(l*, 0)``), so that
    both are "expected quality" in the sense of Dex-Net's robust metrics.

    Attributes:
        p_fc: ``B`` float: the fraction of perturbations that are force-closure, P(force-closure).
        p_fc_se: ``B`` float: its Monte Carlo standard error, ``sqrt(p (1 - p) / samples)``.
        q_mean: ``B`` float: mean Q.
        q_mean_se: ``B`` float: its standard error (sample standard deviation / ``sqrt(samples)``).
        q_low: ``B`` float: the ``quantile`` quantile of Q (NumPy's linear interpolation).
        margin_mean, margin_mean_se, margin_low: ``B`` float: the same for ``max(l*, 0)`` of
            :func:`grasp_jax.min_weight`; ``None`` when ``margin=False``.
        unconverged: ``B`` int32: perturbations whose LPs did not converge (counted as not
            force-closure, Q 0, as :func:`grasp_jax.evaluate` does).
        samples: perturbations per grasp (static).
        quantile: the quantile of ``q_low`` (static).
    """

    p_fc: np.ndarray
    p_fc_se: np.ndarray
    q_mean: np.ndarray
    q_mean_se: np.ndarray
    q_low: np.ndarray
    margin_mean: np.ndarray | None
    margin_mean_se: np.ndarray | None
    margin_low: np.ndarray | None
    unconverged: np.ndarray
    samples: int = dataclasses.field(metadata=dict(static=True), default=0)
    quantile: float = dataclasses.field(metadata=dict(static=True), default=0.1)

    #: The per-grasp columns, in the order result files store them (``None`` fields left out).
    COLUMNS = ("p_fc", "p_fc_se", "q_mean", "q_mean_se", "q_low", "margin_mean", "margin_mean_se", "margin_low",
               "unconverged")

    def columns(self) -> dict:
        """``{name: (B,) array}`` of the fields that are there (for result files)."""
        return {name: np.asarray(getattr(self, name)) for name in self.COLUMNS if getattr(self, name) is not None}

    def __str__(self) -> str:
        """One line, e.g. ``RobustResult(1000 grasps x 100 samples, P(FC) mean 0.62, median 0.71,
        q_mean median 0.031, q_low(10%) median 0.004)``."""
        p = np.asarray(self.p_fc)
        parts = [f"{p.size:,} grasps x {self.samples} samples"]
        if p.size:
            parts.append(f"P(FC) mean {p.mean():.3g}, median {np.median(p):.3g}")
            parts.append(f"q_mean median {np.median(self.q_mean):.3g}")
            parts.append(f"q_low({100 * self.quantile:g}%) median {np.median(self.q_low):.3g}")
            bad = int(np.sum(self.unconverged))
            if bad:
                parts.append(f"{bad} perturbations not converged")
        return f"RobustResult({', '.join(parts)})"

    __repr__ = __str__

    def __getitem__(self, index) -> RobustResult:
        """Index every field with the same batch index."""
        return jax.tree_util.tree_map(lambda a: a[index], self)

    def __len__(self) -> int:
        return len(self.p_fc)


def _stats(values: np.ndarray, quantile: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(mean, standard error, quantile)`` over the last axis (samples) of ``values: (g, S)``.
    Taken about the first sample, so that equal samples give back exactly their value."""
    first = values[:, :1]
    dev = values - first
    mean = first[:, 0] + dev.mean(axis=1)
    se = dev.std(axis=1, ddof=1) / math.sqrt(values.shape[1])
    low = np.quantile(values, quantile, axis=1)
    low = np.where(np.all(dev == 0, axis=1), first[:, 0], low)
    return mean, se, low


class _Perturber:
    """The perturbations of one call: validated grasps, the surface, the draws; called on a slice
    of grasps, gives their perturbed copies (NumPy)."""

    def __init__(self, obj, points, normals, mu, noise, key, samples, num_edges=DEFAULT_NUM_EDGES, torsion=None,
                 normal_kind="flat"):
        if not isinstance(noise, Noise):
            raise TypeError(f"noise must be a grasp_jax.Noise; got {type(noise).__name__}")
        self.samples = check_int("samples", samples, 1)
        key = check_key(key, "robust and perturb")
        points, normals, _, batch, mu, num_edges, scope = _check_common(points, normals, mu, num_edges, None, torsion)
        if is_traced(points, normals, mu):
            raise ValueError("robust and perturb run on concrete arrays (outside jit, grad and vmap)")
        n, d = points.shape[-2:]
        self.surface = None
        if noise.moves_contacts:
            if obj is None:
                raise ValueError(f"{noise} moves contacts over the object: pass the object (or its surface), "
                                 "not None")
            self.surface = as_surface(obj, normal_kind)
            if self.surface.dim != d:
                raise ValueError(f"the object is {self.surface.dim}D but the grasps are {d}D")
        self.scale = 1.0 if self.surface is None else float(self.surface.scale)
        self.noise, self.batch, self.mu, self.scope, self.num_edges = noise, batch, mu, scope, num_edges
        self.dtype = points.dtype
        self.total = int(np.prod(batch, dtype=np.int64))
        self.points = points.reshape(self.total, n, d)
        self.normals = normals.reshape(self.total, n, d)
        self.draw = _noise.draws(key, self.samples, n, d, self.dtype)
        self.per = max(1, ROWS // self.samples)  # grasps per slice: ROWS perturbed grasps
        self.sigmas = np.array([noise.position * self.scale, noise.normal, noise.friction[0], noise.friction[1],
                                noise.friction_sigma, noise.rotation, noise.translation * self.scale], self.dtype)

    def start(self) -> None:
        """Put the surface on the device, inside ``self.scope`` (before the first slice)."""
        if self.surface is not None:
            self.surface = jax.device_put(self.surface)

    @property
    def center(self):
        """The origin of the min-weight margin's torques: the object's centre (else 0)."""
        return np.zeros(self.points.shape[-1]) if self.surface is None else self.surface.center

    def slice(self, start: int, stop: int):
        """What :func:`_label` scores: ``(points, normals, mu, ok)``, ``ok`` ``None`` (free
        contacts always touch the object)."""
        return (*self(start, stop), None)

    def __call__(self, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Grasps ``start..stop`` (of the flattened batch) perturbed: ``(g, S, n, d)`` points and
        normals, ``(g, S, n)`` friction coefficients. Call inside ``self.scope``."""
        p, nrm = self.points[start:stop], self.normals[start:stop]
        g, (n, d), S = len(p), p.shape[1:], self.samples
        if self.noise.is_zero:  # every sample is the nominal grasp, bit for bit
            return (np.broadcast_to(p[:, None], (g, S, n, d)), np.broadcast_to(nrm[:, None], (g, S, n, d)),
                    np.full((g, S, n), self.mu, self.dtype))
        contacts = None
        if self.surface is not None:
            located = self.surface.locate(p)
            contacts = type(located)(np.asarray(located.face), np.asarray(located.coords, self.dtype))
        # Pieces of one padded size whatever the batch: one compiled perturbation per surface and
        # sample count, and bit for bit the same perturbations of a grasp in any batch (XLA's
        # programs of two sizes can round differently in the last bit).
        size = self.per
        pieces = []
        for lo in range(0, g, size):
            hi = min(lo + size, g)
            pad = lambda a, lo=lo, hi=hi: pad_rows(a[lo:hi], size)  # noqa: E731
            args = (None if contacts is None else jax.tree_util.tree_map(pad, contacts), pad(p), pad(nrm))
            out = perturb_all(self.surface, *args, self.draw, self.sigmas, jnp.asarray(self.mu, self.dtype),
                           flags=self.noise._flags())
            pieces.append(tuple(np.asarray(a)[:hi - lo] for a in out))
        return tuple(np.concatenate(a) if len(pieces) > 1 else a[0] for a in zip(*pieces))


def perturb(obj, points, normals, *, mu, noise: Noise, key, samples: int = 100, surface_normals: str = "flat"):
    """The perturbed grasps :func:`robust` scores (the same draws from the same key).

    Args:
        obj, points, normals, mu, noise, key, samples, surface_normals: as :func:`robust`
            (``samples >= 1``).

    Returns:
        ``(points, normals, mu)``: ``(..., S, n, d)`` perturbed contact points and normals and
        ``(..., S, n)`` friction coefficients, one per contact, NumPy arrays.
    """
    perturber = _Perturber(obj, points, normals, mu, noise, key, samples, normal_kind=surface_normals)
    with perturber.scope:
        perturber.start()
        p, n, m = perturber(0, perturber.total)
    lead = perturber.batch + (perturber.samples,)
    return p.reshape(lead + p.shape[2:]), n.reshape(lead + n.shape[2:]), m.reshape(lead + m.shape[2:])


def robust(
    obj,
    points,
    normals,
    *,
    mu,
    noise: Noise,
    key,
    samples: int = 100,
    quantile: float = 0.1,
    num_edges: int = DEFAULT_NUM_EDGES,
    torque_test: str = "exact",
    contact: str = "hard",
    torsion=None,
    margin: bool = True,
    torque_scale: float | None = None,
    progress: bool = False,
    surface_normals: str = "flat",
) -> RobustResult:
    """Robust labels of a batch of grasps: P(force-closure), mean and low quantile of Q and of
    the min-weight margin under ``noise``, with Monte Carlo standard errors.

    Every grasp is scored under the same ``samples`` perturbations (common random numbers, drawn
    from ``key``; the result is reproducible from it and does not depend on the batch it is in;
    :func:`perturb` gives the perturbed grasps). Grasps x samples are scored by the programs of
    :func:`grasp_jax.evaluate` (and :func:`grasp_jax.min_weight`) through the one batching path,
    :data:`ROWS` perturbed grasps at a time. With zero noise every sample is the nominal grasp:
    ``p_fc`` is its verdict (0 or 1) and ``q_mean == q_low`` its Q, exactly.

    Args:
        obj: the object the grasps are on (:mod:`grasp_jax.objects`) or its
            :class:`~grasp_jax.surfaces.Surface`; may be ``None`` where the noise moves no
            contact (only ``normal`` and friction noise).
        points: ``(..., n, d)`` contact points on the object's surface, ``d`` in {2, 3}.
        normals: ``(..., n, d)`` outward normals. Where contacts move, the perturbed normals are
            the surface's at the new contacts.
        mu: nominal friction coefficient > 0.
        noise: a :class:`Noise`.
        key: a ``jax.random.key``.
        samples: perturbations per grasp (>= 2).
        quantile: the low quantile of ``q_low`` and ``margin_low``, in [0, 1] (10% by default).
        num_edges, torque_test, contact, torsion: as :func:`grasp_jax.evaluate` (``torsion``
            stays fixed while friction varies).
        margin: also estimate the min-weight margin (about a third more time).
        torque_scale: the length torques are divided by in the min-weight margin (default the
            object's radius, else 1).
        progress: a progress bar over slices of grasps.
        surface_normals: the normals of moved contacts on meshes and polygons: ``"flat"`` (face
            normals, as :mod:`grasp_jax.sampling` gives them, the default) or ``"smooth"``
            (interpolated, as :func:`grasp_jax.optimize` uses by default); analytic shapes have
            exact normals.

    Returns:
        :class:`RobustResult` whose fields have the leading batch shape.

    Raises:
        ValueError: bad shapes or values, a negative sigma (:class:`Noise`), or noise that moves
            contacts without an object.
    """
    samples, quantile = check_labels(samples, quantile, torque_test)
    perturber = _Perturber(obj, points, normals, mu, noise, key, samples, num_edges, torsion, surface_normals)
    model = contact_model(contact, torsion, perturber.num_edges, perturber.points.shape[-1])
    torque_scale = check_scalar("torque_scale", perturber.scale if torque_scale is None else torque_scale)
    result, stuck = label(perturber, quantile=quantile, torque_test=torque_test, model=model, margin=margin,
                          torque_scale=torque_scale, progress=progress)
    warn_unconverged(result, stuck, "robust")
    return result


def check_labels(samples, quantile, torque_test) -> tuple[int, float]:
    """``(samples, quantile)`` of :func:`robust` validated (and ``torque_test``)."""
    samples = check_int("samples", samples, 2, " (a standard error needs two samples)")
    quantile = check_scalar("quantile", quantile, positive=False, minimum=0.0)
    if quantile > 1:
        raise ValueError(f"quantile must be in [0, 1]; got {quantile!r}")
    if torque_test not in ("exact", "paper"):
        raise ValueError(f"torque_test must be 'exact' or 'paper'; got {torque_test!r}")
    return samples, quantile


def warn_unconverged(result: RobustResult, stuck: int, what: str) -> None:
    """The warning of :func:`robust` where perturbed grasps did not converge (in the caller's caller)."""
    bad = int(np.sum(result.unconverged))
    if bad or stuck:
        total = int(np.size(result.p_fc)) * result.samples
        warnings.warn(f"{what}: {bad} evaluations and {stuck} min-weight LPs of {total:,} perturbed grasps "
                      "did not converge in the iteration budget; they count as not force-closure with Q 0 "
                      "(margin 0); see RobustResult.unconverged", RuntimeWarning, stacklevel=3)


def _nominal_duals(perturber, model: ContactModel) -> np.ndarray:
    """``(total, rows)`` the quality LP's dual of each nominal grasp of ``perturber``
    (``_closure.quality_dual_one``; zeros where unsolved): what screens its perturbations."""
    points, normals = perturber.points, perturber.normals
    mu = np.full(points.shape[:-1], perturber.mu, perturber.dtype)
    return np.asarray(map_grasps(_dual_single, (points, normals, None, mu), (model,), (perturber.total,)))


def label(perturber, *, quantile, torque_test, model: ContactModel, margin, torque_scale, progress):
    """Score the perturbations of ``perturber`` and reduce them to a :class:`RobustResult`: the one
    scoring path of :func:`robust` and :func:`grasp_jax.grippers.robust_jaws`.

    ``perturber`` has ``total`` grasps (leading shape ``batch``), ``samples``, ``per`` grasps per
    slice, ``dtype``, ``num_edges``, ``points`` (the nominal grasps, for the LP budgets),
    ``scope`` (the precision context), ``start()`` (called inside it), ``center`` (the margin's
    origin) and ``slice(start, stop) -> (points, normals, mu, ok)``: ``(g, S, n, d)``,
    ``(g, S, n, d)``, ``(g, S, n)`` and ``(g, S) bool`` or ``None``; a perturbation whose ``ok``
    is ``False`` (no grasp at all: jaws that miss) counts as not force-closure, Q 0, margin 0, and
    not as unconverged. Returns ``(result, min-weight LPs not converged)``.
    """
    dtype, total, samples = perturber.dtype, perturber.total, perturber.samples
    if _closure.staged(perturber.points, torque_test):  # as gj.evaluate: the quality LP where needed
        evaluate_fn = Staged(_torque_stage, _quality_stage)
    else:
        evaluate_fn = _bind(_evaluate_single, torque_test=torque_test)
    budget, retry = _passes(perturber.points, model, None)
    per = perturber.per
    fields = {name: [] for name in RobustResult.COLUMNS}
    starts = range(0, total, per)
    if progress:
        from tqdm.auto import tqdm

        starts = tqdm(starts, unit="slice", desc=f"robust: {total:,} grasps x {samples}")
    stuck = 0  # min-weight LPs that did not converge
    with perturber.scope:
        perturber.start()
        typed = model.astype(dtype)
        shared = (typed, *budget)
        retries = tuple(Retry((typed, *pass_), _unfinished) for pass_ in retry)
        weight_shared = (typed, jnp.asarray(perturber.center, dtype), jnp.asarray(torque_scale, dtype))
        duals = _nominal_duals(perturber, typed)
        for start in starts:
            stop = min(start + per, total)
            g = stop - start
            pp, nn, mm, ok = perturber.slice(start, stop)
            # Screening (SETTLED): a perturbation that the dual of its nominal grasp's quality LP
            # proves out of equilibrium is not force-closure, Q 0, margin 0, with no LP solved;
            # only the others ("live") are scored, gathered into full blocks.
            y = np.broadcast_to(duals[start:stop, None], (g, samples, duals.shape[-1]))
            settled = np.asarray(map_grasps(_settled_single, (pp, nn, None, mm, y), (typed,), (g, samples)))
            if ok is not None:
                settled = settled | ~ok
            live = np.flatnonzero(~settled.reshape(-1))
            n, d = pp.shape[-2:]
            gathered = (pp.reshape(-1, n, d)[live], nn.reshape(-1, n, d)[live], None, mm.reshape(-1, n)[live])
            fc, q = np.zeros(g * samples, bool), np.zeros(g * samples, dtype)
            conv = np.ones(g * samples, bool)
            if len(live):
                res = map_grasps(evaluate_fn, gathered, shared, (len(live),), retry=retries)
                fc[live], q[live], conv[live] = (np.asarray(res.force_closure), np.asarray(res.quality),
                                                 np.asarray(res.converged))
            fc, q, conv = fc.reshape(g, samples), q.reshape(g, samples), conv.reshape(g, samples)
            fields["p_fc"].append(fc.mean(axis=1))
            fields["unconverged"].append((~conv).sum(axis=1).astype(np.int32))
            for name, value in zip(("q_mean", "q_mean_se", "q_low"), _stats(q, quantile)):
                fields[name].append(value)
            if margin:
                l_star, open_ = np.zeros(g * samples, dtype), np.zeros(g * samples, bool)
                if len(live):
                    l_live, status = map_grasps(_min_weight_single, gathered, weight_shared, (len(live),),
                                                block=MIN_WEIGHT_BLOCK)
                    l_star[live] = np.maximum(np.asarray(l_live), 0.0)
                    open_[live] = np.asarray(status) == Status.NOT_CONVERGED
                l_star, open_ = l_star.reshape(g, samples), open_.reshape(g, samples)
                stuck += int(np.sum(open_))
                for name, value in zip(("margin_mean", "margin_mean_se", "margin_low"), _stats(l_star, quantile)):
                    fields[name].append(value)
    out = {}
    for name in RobustResult.COLUMNS:
        parts = fields[name]
        if (name.startswith("margin") and not margin) or name == "p_fc_se":
            out[name] = None
            continue
        dt = np.int32 if name == "unconverged" else dtype
        value = np.concatenate(parts) if parts else np.zeros(0, dt)
        out[name] = value.reshape(perturber.batch)
    p = out["p_fc"]
    out["p_fc_se"] = np.sqrt(p * (1.0 - p) / samples)
    return RobustResult(**out, samples=samples, quantile=quantile), stuck
