"""An interactive page of hand grasps: the posed hand's collision geometry around the object,
the contacts and their normals, one grasp at a time (plotly; opens offline)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import plotly.graph_objects as go
import trimesh

from .._precision import float64_scope
from ..hands import forward
from ..hands._geometry import element_mesh
from ._draw import CONTACT, OBJECT_MESH, mesh_arrays
from ._grasp_figure import MAX_FACES, display_mesh
from .pages import write_page

_HAND = "#d9a066"


def posed_hand(hand, position, quaternion, joints) -> trimesh.Trimesh:
    """The hand's collision geometry at one configuration, as one mesh in the world frame.

    Args:
        hand: a :class:`grasp_jax.hands.Hand`; position: ``(3,)``; quaternion: ``(4,)`` wxyz;
            joints: ``(J,)``.
    """
    with float64_scope():
        pose = np.concatenate([np.asarray(position, float), np.asarray(quaternion, float)])
        frames = np.asarray(forward(hand, pose, np.asarray(joints, float)))
    parts = []
    for c in hand.collisions:
        m = element_mesh(c)
        m.apply_transform(frames[c.link])
        parts.append(m)
    return trimesh.util.concatenate(parts)


def hand_figure(result, hand, obj, *, top: int = 6, max_faces: int = MAX_FACES) -> go.Figure:
    """A plotly figure of the best ``top`` valid grasps of ``result`` (all grasps where none is
    valid), one shown at a time through a drop-down menu."""
    index = result.best(top)
    if not len(index):
        index = np.argsort(-np.asarray(result.quality), kind="stable")[:top]
    v, f, note = display_mesh(*mesh_arrays(obj), max_faces)
    traces = [go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2], color=OBJECT_MESH,
                        opacity=0.6, name="object", hoverinfo="skip")]
    owner = [-1]
    for rank, i in enumerate(index):
        m = posed_hand(hand, result.position[i], result.quaternion[i], result.joints[i])
        hv, hf = np.asarray(m.vertices), np.asarray(m.faces)
        label = (f"#{rank + 1} (start {i}): Q {result.quality[i]:.3f}, "
                 f"{'valid' if result.valid[i] else 'not valid'}")
        traces.append(go.Mesh3d(x=hv[:, 0], y=hv[:, 1], z=hv[:, 2], i=hf[:, 0], j=hf[:, 1], k=hf[:, 2],
                                color=_HAND, opacity=0.5, flatshading=True, name=label, hoverinfo="name"))
        touch = np.asarray(result.active[i], bool)  # the fingers that touch
        p, n = np.asarray(result.points[i])[touch], np.asarray(result.normals[i])[touch]
        scale = 0.15 * float(np.ptp(v, axis=0).max())
        tips = p + scale * n
        lines = np.full((3 * len(p), 3), np.nan)
        lines[0::3], lines[1::3] = p, tips
        traces.append(go.Scatter3d(x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="markers", name=f"contacts #{rank + 1}",
                                   marker=dict(size=5, color=CONTACT), hoverinfo="name"))
        traces.append(go.Scatter3d(x=lines[:, 0], y=lines[:, 1], z=lines[:, 2], mode="lines",
                                   line=dict(color=CONTACT, width=3), hoverinfo="skip", showlegend=False))
        owner += [rank] * 3
    owner = np.asarray(owner)
    buttons = [dict(label=f"grasp #{r + 1}", method="update", args=[{"visible": list((owner == -1) | (owner == r))}])
               for r in range(len(index))]
    fig = go.Figure(traces)
    for t, o in zip(fig.data, owner):
        t.visible = bool(o <= 0)
    title = (f"{result.hand} on {result.object_name}: {int(np.sum(result.valid))} of {len(result)} starts valid, "
             f"mu {result.mu:g}, {result.contact} contacts" + (f" ({note})" if note else ""))
    fig.update_layout(title=title, scene=dict(aspectmode="data"), margin=dict(l=0, r=0, t=40, b=0),
                      updatemenus=[dict(buttons=buttons, x=0.0, y=1.0, xanchor="left")] if buttons else [])
    return fig


def hand_page(result, hand, obj, page, *, top: int = 6, max_faces: int = MAX_FACES) -> Path:
    """Write :func:`hand_figure` as a self-contained HTML page (atomically); returns its path."""
    fig = hand_figure(result, hand, obj, top=top, max_faces=max_faces)
    return write_page(fig, page, title=f"{result.hand} on {result.object_name}")
