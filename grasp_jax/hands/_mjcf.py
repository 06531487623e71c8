"""Reading a hand from an MJCF file (MuJoCo XML) into the same tree as a URDF one.

The file is compiled by MuJoCo itself (the format's reference reader: defaults, includes,
degrees, ``fromto``, mesh frames as MuJoCo sees them). Links follow MuJoCo's body order; a link's
frame is its body's frame moved to its joint's anchor (the same frame where the anchor is the
body's origin, as in every file converted from a URDF). A body with several hinge or slide joints
gives one link per joint, chained in MuJoCo's order, named ``body/joint`` except the last (the
body's name). The root is the world's only child body (its pose and free joint dropped: the wrist
pose is the optimizer's), or the world itself when it holds collision geometry or several bodies.
Equality constraints ``joint1 = f(joint2)`` with a linear ``polycoef`` are mimic joints; other
equality constraints are ignored. Geoms with ``contype = conaffinity = 0`` are visual and skipped;
a mesh geom's compiled vertices (in MuJoCo's recentred mesh frame, the geom's compiled pose) are
written once to ``$XDG_CACHE_HOME/grasp_jax/mjcf/<hash>.obj``.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np

from ..storage import write_atomically
from ._hand import FIXED, PRISMATIC, REVOLUTE, Collision, Tree

#: MuJoCo's joint types (mjtJoint) and geom types (mjtGeom) used here; equality type mjEQ_JOINT.
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3
_PLANE, _HFIELD, _SPHERE, _CAPSULE, _ELLIPSOID, _CYLINDER, _BOX, _MESH = 0, 1, 2, 3, 4, 5, 6, 7
_EQ_JOINT = 2


def read(path) -> Tree:
    """Parse the MJCF file ``path`` (see the module's docstring for what is read, and how).

    Raises:
        ValueError: mujoco missing, a file MuJoCo cannot compile, a ball joint, a free joint below
            the root, a nonlinear joint coupling, a geom kind a hand cannot use (ellipsoid,
            height field, SDF), each naming the file and the element.
    """
    path = Path(path).expanduser()
    where = str(path)
    if not path.is_file():
        raise ValueError(f"{where}: hand description not found")
    try:
        import mujoco
    except ImportError:
        raise ValueError(f"{where}: reading an MJCF hand needs MuJoCo: pip install 'grasp_jax[sim]'") from None
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except Exception as exc:  # noqa: BLE001 - any compiler failure is an unreadable file
        first = (str(exc).strip().splitlines() or [repr(exc)])[0]
        raise ValueError(f"{where}: MuJoCo cannot compile it as MJCF ({first})") from None
    return _tree(model, where)


def _pose(pos, quat) -> np.ndarray:
    """``(4, 4)`` of a position and a wxyz unit quaternion."""
    w, x, y, z = np.asarray(quat, dtype=np.float64) / np.linalg.norm(quat)
    out = np.eye(4)
    out[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                   [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                   [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]]
    out[:3, 3] = pos
    return out


def _shift(p) -> np.ndarray:
    out = np.eye(4)
    out[:3, 3] = p
    return out


def _name(model, kind: str, i: int) -> str:
    return getattr(model, kind)(i).name or f"{kind}{i}"


def _root(model, where: str) -> int:
    """The body whose frame is the wrist: the world's only child, or the world (0)."""
    children = [b for b in range(1, model.nbody) if model.body_parentid[b] == 0]
    world_geoms = [g for g in _collision_geoms(model) if model.geom_bodyid[g] == 0
                   and model.geom_type[g] not in (_PLANE, _HFIELD)]
    if len(children) != 1 or world_geoms:
        return 0
    root = children[0]
    for j in range(model.body_jntadr[root], model.body_jntadr[root] + model.body_jntnum[root]):
        if model.jnt_type[j] != _FREE:
            raise ValueError(f"{where}: the root body {_name(model, 'body', root)!r} has joint "
                             f"{_name(model, 'joint', j)!r}; the root of a hand is fixed or free "
                             "(its pose is the wrist's)")
    return root


def _links(model, root: int, where: str):
    """Links parent first: ``(names, parents, origins, joints (-1: fixed), last link of each body,
    each body's frame in its last link's frame)``."""
    names, parents, origins, joints = [_name(model, "body", root)], [-1], [np.eye(4)], [-1]
    last, inside = {root: 0}, {root: np.eye(4)}
    for b in range(root + 1, model.nbody):
        up = model.body_parentid[b]
        if up not in last:
            continue
        body = _name(model, "body", b)
        offset, link = inside[up] @ _pose(model.body_pos[b], model.body_quat[b]), last[up]
        first, count = model.body_jntadr[b], model.body_jntnum[b]
        anchor = np.zeros(3)
        for j in range(first, first + count):
            if model.jnt_type[j] not in (_HINGE, _SLIDE):
                kind = "a ball joint" if model.jnt_type[j] == _BALL else "a free joint below the hand's root"
                raise ValueError(f"{where}: joint {_name(model, 'joint', j)!r} of body {body!r} is {kind}; "
                                 "a hand's joints must be hinge or slide joints")
            origins.append(offset @ _shift(model.jnt_pos[j]))
            names.append(body if j == first + count - 1 else f"{body}/{_name(model, 'joint', j)}")
            parents.append(link)
            joints.append(j)
            link, anchor, offset = len(names) - 1, model.jnt_pos[j], _shift(-model.jnt_pos[j])
        if count == 0:
            names.append(body)
            parents.append(link)
            origins.append(offset)
            joints.append(-1)
            link = len(names) - 1
        last[b], inside[b] = link, _shift(-anchor)
    return names, parents, origins, joints, last, inside


def _couplings(model, where: str) -> dict:
    """``{joint1: (joint2, m, o)}``: ``qpos[joint1] = m * qpos[joint2] + o`` of the active joint
    equality constraints (MuJoCo: ``y - y0 = a0 + a1 (x - x0)``)."""
    out = {}
    for e in range(model.neq):
        if model.eq_type[e] != _EQ_JOINT or not model.eq_active0[e]:
            continue
        j1, j2, coef = int(model.eq_obj1id[e]), int(model.eq_obj2id[e]), model.eq_data[e, :5]
        name = _name(model, "joint", j1)
        if j2 < 0:
            raise ValueError(f"{where}: equality constraint {e} locks joint {name!r}; make the joint fixed instead")
        if np.any(coef[2:] != 0):
            raise ValueError(f"{where}: equality constraint {e} couples joint {name!r} to "
                             f"{_name(model, 'joint', j2)!r} by a nonlinear polycoef {list(coef)}; only "
                             "linear ones (polycoef=\"a0 a1 0 0 0\") are read, as mimic joints")
        if j1 in out:
            raise ValueError(f"{where}: joint {name!r} is coupled by two equality constraints")
        y0, x0 = model.qpos0[model.jnt_qposadr[j1]], model.qpos0[model.jnt_qposadr[j2]]
        out[j1] = (j2, float(coef[1]), float(y0 + coef[0] - coef[1] * x0))
    return out


def _follow(j: int, couplings: dict, model, where: str) -> tuple[int, float, float]:
    """``(actuated joint, m, o)``: ``qpos[j] = m * qpos[actuated] + o``, through chains of couplings."""
    mult, off, seen = 1.0, 0.0, {j}
    while j in couplings:
        j, m, o = couplings[j]
        if j in seen:
            raise ValueError(f"{where}: joint equality constraints form a cycle through {_name(model, 'joint', j)!r}")
        seen.add(j)
        mult, off = mult * m, off + mult * o
    return j, mult, off


def _tree(model, where: str) -> Tree:
    root = _root(model, where)
    names, parent, origins, joints, last, inside = _links(model, root, where)
    couplings = _couplings(model, where)
    count = len(names)
    moving = [j for j in joints if j >= 0]
    actuated = [j for j in moving if j not in couplings]
    act = {j: k for k, j in enumerate(actuated)}
    axis = np.tile(np.array([0.0, 0.0, 1.0]), (count, 1))
    multiplier, offset = np.ones(count), np.zeros(count)
    kind, source = [FIXED] * count, [-1] * count
    for i, j in enumerate(joints):
        if j < 0:
            continue
        kind[i] = REVOLUTE if model.jnt_type[j] == _HINGE else PRISMATIC
        axis[i] = model.jnt_axis[j] / np.linalg.norm(model.jnt_axis[j])
        target, mult, off = _follow(j, couplings, model, where)
        if target not in act:
            raise ValueError(f"{where}: joint {_name(model, 'joint', j)!r} is coupled to "
                             f"{_name(model, 'joint', target)!r}, which is not a moving joint of the hand")
        # MuJoCo turns a joint by qpos - qpos0 (qpos0: its ``ref``)
        source[i], multiplier[i], offset[i] = act[target], mult, off - model.qpos0[model.jnt_qposadr[j]]
    limited = np.array([bool(model.jnt_limited[j]) for j in actuated], dtype=bool)
    ranges = np.array([model.jnt_range[j] for j in actuated], dtype=np.float64).reshape(-1, 2)
    lower = np.where(limited, ranges[:, 0], -np.inf)
    upper = np.where(limited, ranges[:, 1], np.inf)
    collisions = tuple(_collisions(model, last, inside, where))
    name = model.names.split(b"\0", 1)[0].decode() or "hand"
    return Tree(order=names, origin=np.stack(origins), axis=axis, multiplier=multiplier, offset=offset,
                parent=tuple(parent), kind=tuple(kind), source=tuple(source),
                joint_names=tuple(_name(model, "joint", j) for j in actuated), lower=lower, upper=upper,
                collisions=collisions, name=name, where=where)


def _collision_geoms(model) -> list[int]:
    return [g for g in range(model.ngeom) if model.geom_contype[g] or model.geom_conaffinity[g]]


def _collisions(model, last: dict, inside: dict, where: str):
    for g in _collision_geoms(model):
        b, kind, size = int(model.geom_bodyid[g]), int(model.geom_type[g]), model.geom_size[g]
        if b not in last:  # the world's floor, below a root body
            continue
        if b == 0 and kind in (_PLANE, _HFIELD):
            continue
        link = last[b]
        origin = tuple(float(v) for v in (inside[b] @ _pose(model.geom_pos[g], model.geom_quat[g])).reshape(-1))
        if kind == _BOX:
            yield Collision(link, "box", tuple(float(2 * v) for v in size), origin)
        elif kind in (_CYLINDER, _CAPSULE):
            yield Collision(link, "cylinder" if kind == _CYLINDER else "capsule", (float(size[0]), float(2 * size[1])),
                            origin)
        elif kind == _SPHERE:
            yield Collision(link, "sphere", (float(size[0]),), origin)
        elif kind == _MESH:
            yield Collision(link, "mesh", (1.0, 1.0, 1.0), origin, _mesh_file(model, int(model.geom_dataid[g]), where))
        else:
            raise ValueError(f"{where}: geom {_name(model, 'geom', g)!r} of body {_name(model, 'body', b)!r} has "
                             "a type a hand cannot use (box, cylinder, sphere, capsule, mesh are read)")


def _cache_dirs() -> list[Path]:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    user = getattr(os, "getuid", lambda: 0)()
    return [Path(base) / "grasp_jax" / "mjcf", Path(tempfile.gettempdir()) / f"grasp_jax-{user}" / "mjcf"]


def _mesh_file(model, mesh: int, where: str) -> str:
    """The compiled mesh ``mesh`` (vertices in MuJoCo's mesh frame, scale applied) as an OBJ file
    in the cache, named by a hash of its vertices and faces."""
    start, n = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
    vertices = np.asarray(model.mesh_vert[start:start + n], dtype=np.float64)
    start = model.mesh_faceadr[mesh]
    faces = np.asarray(model.mesh_face[start:start + model.mesh_facenum[mesh]], dtype=np.int64)
    key = hashlib.sha256(vertices.tobytes() + faces.tobytes()).hexdigest()[:32]
    text = "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in vertices)
    text += "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces)
    for folder in _cache_dirs():
        path = folder / f"{key}.obj"
        if path.is_file():
            return str(path)
        try:
            folder.mkdir(parents=True, exist_ok=True)
            return str(write_atomically(path, lambda f: f.write(text), what="MJCF mesh cache file"))
        except (OSError, ValueError):  # an unwritable cache: the next folder
            continue
    raise ValueError(f"{where}: cannot write mesh {_name(model, 'mesh', mesh)!r} as an OBJ file into the cache "
                     f"({', '.join(str(d) for d in _cache_dirs())})")
