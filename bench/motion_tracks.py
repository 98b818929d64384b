"""The ground-truth TAP-Vid tracks of a motion scene: query points spread over each part of the object, followed
through every frame by the scene's forward model, occluded where the camera does not see them."""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np

from bench.motion_bodies import LimbsJump
from bench.motion_models import _Model
from bench.motion_spec import MotionSpec
from bench.tracking import Tracks

#: Tracks per part of the object (one part but for limbs_jump), their query frames spread evenly over the clip
#: (TRACKS / QUERY_FRAMES points of each part each).
TRACKS = 16
QUERY_FRAMES = 4
#: A query point lies where the object covers its pixel fully (not on the anti-aliased rim).
FULL_COVERAGE = 0.999
#: ...at least this far inside the object's mask (px), or half its thickness for a thinner object: a point on the
#: rim is half background.
QUERY_MARGIN_PX = 4.0
#: Of an object in several parts, half of each query frame's points are ones hidden within this many frames of it
#: (when there are such points): the tracks then ask for a point through its disappearance and return.
NEIGHBOUR_FRAMES = 3


def _spread(points: np.ndarray, k: int) -> np.ndarray:
    """Indices of ``k`` of ``points`` [N, 2] spread over them: farthest-point sampling from the one nearest
    their centroid (deterministic)."""
    if len(points) <= k:
        return np.arange(len(points))
    chosen = [int(np.argmin(((points - points.mean(0)) ** 2).sum(-1)))]
    d2 = ((points - points[chosen[0]]) ** 2).sum(-1)
    for _ in range(k - 1):
        nxt = int(np.argmax(d2))
        chosen.append(nxt)
        d2 = np.minimum(d2, ((points - points[nxt]) ** 2).sum(-1))
    return np.asarray(chosen)


def _query_points(
    spec: MotionSpec, model: _Model, tq: int, cov: np.ndarray, part: np.ndarray, p: int, count: int
) -> list[np.ndarray]:
    """``count`` query pixels [2] (x, y) of part ``p`` in frame ``tq``, spread over it: fully covered pixel centres
    inside the part's visible region by QUERY_MARGIN_PX (or half its thickness). Of an object in several parts,
    half of them among those hidden within NEIGHBOUR_FRAMES of ``tq``, where there are such."""
    inside = (part == p).astype(np.uint8)
    depth = cv2.distanceTransform(np.pad(inside, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    margin = min(QUERY_MARGIN_PX, 0.5 * float(depth.max()))
    ys, xs = np.nonzero((cov >= FULL_COVERAGE) & (depth >= margin) & (inside > 0))
    ok = model.query_ok(float(tq), xs.astype(np.float64), ys.astype(np.float64))
    if isinstance(model, LimbsJump):  # a part seen in a sliver has no margin: no rim of a part in front either
        ok &= model.unblended(float(tq), xs.astype(np.float64), ys.astype(np.float64))
    pts = np.stack((xs[ok], ys[ok]), -1).astype(np.float64)
    if model.n_parts == 1 or not len(pts):
        return [pts[i] for i in _spread(pts, count)]
    uv = model.surface(float(tq), pts[:, 0], pts[:, 1])[0]
    hidden = np.zeros(len(pts), bool)
    for t in range(max(0, tq - NEIGHBOUR_FRAMES), min(spec.frames, tq + NEIGHBOUR_FRAMES + 1)):
        hidden |= ~model.position(float(t), uv)[1]
    first = [pts[hidden][i] for i in _spread(pts[hidden], count // 2)]
    return first + [pts[~hidden][i] for i in _spread(pts[~hidden], count - len(first))]


def query_frames(spec: MotionSpec) -> list[int]:
    """The frames whose points the tracks start from: QUERY_FRAMES spread over the clip."""
    return [int(t) for t in np.unique(np.rint(np.linspace(0, spec.frames - 1, QUERY_FRAMES)).astype(int))]


#: Per frame: every frame's array [T, ...], or a mapping of some frames' arrays.
Frames = Mapping[int, np.ndarray] | np.ndarray


def ground_truth_tracks(spec: MotionSpec, model: _Model, cov: Frames, part: Frames) -> Tracks:
    """TRACKS points on each part of the object, QUERY_FRAMES query frames spread over the clip (``_query_points``);
    in every frame the point's exact position from the forward model, occluded where the camera does not see it
    (it faces away, or a part in front hides it), it leaves the frame or falls off the object's coverage. ``cov``
    and ``part``: the coverage and the part each pixel shows, of every frame or of the ``query_frames`` alone."""
    t_n, h, w = spec.frames, spec.height, spec.width
    starts = query_frames(spec)
    per = -(-TRACKS // len(starts))
    queries, uvs = [], []
    for tq in starts:
        for k in range(model.n_parts):
            for x, y in _query_points(spec, model, int(tq), cov[tq], part[tq], k, per):
                queries.append((tq, x + 0.5, y + 0.5))
                uvs.append(model.surface(float(tq), x, y)[0])
    query = np.asarray(queries, np.float64)[: TRACKS * model.n_parts]
    uv = np.asarray(uvs, np.float64)[: TRACKS * model.n_parts]
    xy = np.empty((len(query), t_n, 2), np.float64)
    occluded = np.empty((len(query), t_n), bool)
    for t in range(t_n):
        p, facing = model.position(float(t), uv)
        _, c = model.surface(float(t), p[:, 0], p[:, 1])
        inside = (p[:, 0] >= -0.5) & (p[:, 0] < w - 0.5) & (p[:, 1] >= -0.5) & (p[:, 1] < h - 0.5)
        xy[:, t] = p + 0.5
        occluded[:, t] = ~(facing & inside & (c > 0.5))
    return Tracks(xy.astype(np.float32), occluded, query.astype(np.float32), (w, h), np.ones(len(query), dtype=bool))
