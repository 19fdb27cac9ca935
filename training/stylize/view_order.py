"""The order in which stylization visits the views, and what kind of capture the cameras form.

Cross-view matching guidance hands the transport plan of one view to the next, so it helps only when consecutive
views overlap (the paper's view-order ablation: a random order loses most of the guidance's effect). Orders:

- ``dataset``: the cameras as the scene lists them (captures are usually taken along a path already);
- ``nearest``: a short open path through the cameras, where the distance between two cameras combines the distance
  between their centres (in units of the scene extent) and the angle between their viewing directions; built by
  greedy nearest neighbour from a few starts and improved by 2-opt;
- ``random``: a seeded shuffle (the ablation).

``scene_kind`` tells a forward-facing capture (LLFF: every camera looks roughly the same way) from an object- or
scene-centred one (cameras looking in from around the subject), which picks the paper's iteration schedule.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from training.scene.scene import Camera, camera_normalization

from training.stylize.defaults import VIEW_ORDERS  # noqa: F401  (re-exported: callers name the choices from here)
SCENE_KINDS = ("forward", "360")

# One radian between viewing directions costs as much as moving one scene extent (the cameras' enclosing radius).
ANGLE_WEIGHT = 1.0

# Forward-facing: the mean of the unit viewing directions is long (they agree) and no camera looks more than this
# far from that mean direction. LLFF captures stay within about 10-20 degrees; an orbit, even a partial one, does not.
FORWARD_MAX_ANGLE_DEG = 30.0
FORWARD_MIN_RESULTANT = 0.93  # |mean of unit forward vectors|; cos(~21 deg) on average


def camera_distance_matrix(cameras: Sequence[Camera], extent: float | None = None,
                           angle_weight: float = ANGLE_WEIGHT) -> np.ndarray:
    """(n, n) symmetric float64 distances: |c_i - c_j| / extent + angle_weight * angle(f_i, f_j) (radians)."""
    centers = np.stack([c.center for c in cameras]).astype(np.float64)
    forwards = np.stack([c.forward for c in cameras]).astype(np.float64)
    if extent is None:
        _, extent = camera_normalization(list(cameras))
    extent = float(extent) if extent and extent > 0 else 1.0
    diff = centers[:, None, :] - centers[None, :, :]
    d_pos = np.sqrt((diff ** 2).sum(-1)) / extent
    cos = np.clip(forwards @ forwards.T, -1.0, 1.0)
    d_ang = np.arccos(cos)
    dist = d_pos + angle_weight * d_ang
    np.fill_diagonal(dist, 0.0)
    return 0.5 * (dist + dist.T)  # exact symmetry despite rounding in arccos


def path_length(order: Sequence[int], dist: np.ndarray) -> float:
    """Length of the open path visiting ``order`` under the (n, n) distance matrix."""
    idx = np.asarray(order, dtype=np.int64)
    if len(idx) < 2:
        return 0.0
    return float(dist[idx[:-1], idx[1:]].sum())


def greedy_path(dist: np.ndarray, start: int) -> list[int]:
    """Open path from ``start``, always stepping to the nearest unvisited camera."""
    n = dist.shape[0]
    visited = np.zeros(n, dtype=bool)
    order = [int(start)]
    visited[start] = True
    for _ in range(n - 1):
        row = np.where(visited, np.inf, dist[order[-1]])
        nxt = int(np.argmin(row))
        order.append(nxt)
        visited[nxt] = True
    return order


def two_opt(order: Sequence[int], dist: np.ndarray, max_rounds: int = 1000) -> list[int]:
    """Improve an open path by segment reversals until none shortens it; never returns a longer path.

    Reversing order[i..j] replaces the edges (order[i-1], order[i]) and (order[j], order[j+1]) by
    (order[i-1], order[j]) and (order[i], order[j+1]); an edge beyond either end of the open path does not exist
    and costs nothing, so prefixes and suffixes may be reversed too.
    """
    path = np.asarray(order, dtype=np.int64).copy()
    n = len(path)
    if n < 3:
        return path.tolist()
    for _ in range(max_rounds):
        improved = False
        for i in range(n - 1):
            js = np.arange(i + 1, n)
            a = path[i - 1] if i > 0 else -1
            b = path[i]
            c = path[js]
            has_next = js + 1 < n
            d = path[np.minimum(js + 1, n - 1)]
            old = np.where(has_next, dist[c, d], 0.0)
            new = np.where(has_next, dist[b, d], 0.0)
            if a >= 0:
                old = old + dist[a, b]
                new = new + dist[a, c]
            delta = new - old
            k = int(np.argmin(delta))
            if delta[k] < -1e-12:
                j = int(js[k])
                path[i:j + 1] = path[i:j + 1][::-1].copy()
                improved = True
        if not improved:
            break
    return path.tolist()


def nearest_order(cameras: Sequence[Camera], extent: float | None = None,
                  angle_weight: float = ANGLE_WEIGHT) -> list[int]:
    """A short open path through the cameras (greedy from several starts, each improved by 2-opt; the shortest)."""
    n = len(cameras)
    if n < 3:
        return list(range(n))
    dist = camera_distance_matrix(cameras, extent, angle_weight)
    # Good starts are the ends of the capture path: the cameras farthest from everything else, plus view 0.
    remoteness = dist.sum(axis=1)
    starts = {0, *np.argsort(-remoteness)[:4].tolist()}
    best: list[int] | None = None
    best_len = np.inf
    for s in sorted(starts):
        path = two_opt(greedy_path(dist, s), dist)
        length = path_length(path, dist)
        if length < best_len - 1e-12:
            best, best_len = path, length
    assert best is not None
    return best


def random_order(n: int, seed: int = 0) -> list[int]:
    return np.random.default_rng(seed).permutation(n).tolist()


def view_order(cameras: Sequence[Camera], method: str = "nearest", seed: int = 0,
               extent: float | None = None) -> list[int]:
    """Indices into ``cameras`` in the order stylization visits them."""
    if method == "dataset":
        return list(range(len(cameras)))
    if method == "nearest":
        return nearest_order(cameras, extent)
    if method == "random":
        return random_order(len(cameras), seed)
    raise ValueError(f"unknown view order {method!r}; expected one of {', '.join(VIEW_ORDERS)}")


def forward_spread(cameras: Sequence[Camera]) -> tuple[float, float]:
    """(resultant length of the unit viewing directions in [0, 1], largest angle in degrees from their mean)."""
    forwards = np.stack([c.forward for c in cameras]).astype(np.float64)
    mean = forwards.mean(axis=0)
    resultant = float(np.linalg.norm(mean))
    if resultant < 1e-9:
        return 0.0, 180.0
    cos = np.clip(forwards @ (mean / resultant), -1.0, 1.0)
    return resultant, float(np.degrees(np.arccos(cos)).max())


def scene_kind(cameras: Sequence[Camera], override: str | None = None) -> str:
    """"forward" when every camera looks roughly the same way (LLFF-style), else "360" (cameras around the subject).

    A partial orbit such as the fox capture (cameras on a ~100 degree arc looking in at the subject, viewing
    directions up to ~53 degrees from their mean) is "360": the views look at the subject from different sides and
    each sees a different part of it, which is what the paper's 360 schedule (fewer iterations a view, every view
    visited) is for; forward-facing captures show nearly the same content in every view, hence 50 iterations a view.
    """
    if override not in (None, "auto"):
        if override not in SCENE_KINDS:
            raise ValueError(f"unknown scene kind {override!r}; expected auto or one of {', '.join(SCENE_KINDS)}")
        return override
    if len(cameras) < 2:
        return "forward"
    resultant, max_angle = forward_spread(cameras)
    if resultant >= FORWARD_MIN_RESULTANT and max_angle <= FORWARD_MAX_ANGLE_DEG:
        return "forward"
    return "360"
