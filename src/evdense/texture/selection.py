"""Step 2: one view per face, a Markov random field solved by alpha-expansion (graph cuts)."""

from __future__ import annotations

import maxflow
import numpy as np

from evdense.log import get_logger

log = get_logger("texture")


# --- 2. view selection ------------------------------------------------------------------------
def _tedges(g, nodes, cost0: np.ndarray, cost1: np.ndarray) -> None:
    """Unary costs of label 0 (source side) and 1 (sink side), made non-negative."""
    d = cost1 - cost0
    g.add_grid_tedges(nodes, np.maximum(d, 0), np.maximum(-d, 0))


# Over 80 lines on purpose: one MRF optimisation by alpha-expansion (initial labels, then per
# cycle one binary graph cut per view) whose per-face arrays every expansion updates in place.
def select_views(
    num_faces: int,
    cand: tuple[np.ndarray, np.ndarray, np.ndarray],
    adjacency: np.ndarray,
    smoothness: float,
    cycles: int = 2,
    seed: int = 0,
) -> np.ndarray:
    """One view per face (-1 when none may texture it) minimising data + Potts costs by alpha-expansion.

    Args:
        num_faces: F.
        cand: ``(face, view, quality)`` arrays from :func:`view_candidates`.
        adjacency: ``(E, 2)`` face pairs sharing an edge.
        smoothness: Potts weight.
    """
    f, v, q = cand
    labels = np.full(num_faces, -1, dtype=np.int64)
    if len(f) == 0:
        return labels
    qbest = np.zeros(num_faces)
    np.maximum.at(qbest, f, q)
    cost = 1.0 - q / np.maximum(qbest[f], 1e-12)
    # Initial labels: the best view of each face.
    order = np.lexsort((cost, f))
    first = np.unique(f[order], return_index=True)[1]
    labels[f[order][first]] = v[order][first]
    cur = np.full(num_faces, np.inf)
    cur[f[order][first]] = cost[order][first]
    if smoothness <= 0 or len(adjacency) == 0:
        return labels
    by_view = np.argsort(v, kind="stable")
    bounds = np.searchsorted(v[by_view], np.arange(v.max() + 2))
    ea, eb = adjacency[:, 0], adjacency[:, 1]
    rng = np.random.default_rng(seed)
    view_ids = np.unique(v)

    def energy() -> float:
        seen = labels >= 0
        both = seen[ea] & seen[eb]
        return float(cur[seen].sum() + smoothness * np.sum(labels[ea][both] != labels[eb][both]))

    e0 = energy()
    for _cycle in range(cycles):
        changed = 0
        for alpha in rng.permutation(view_ids):
            sel = by_view[bounds[alpha] : bounds[alpha + 1]]
            fa, ca = f[sel], cost[sel]
            keep = labels[fa] != alpha
            fa, ca = fa[keep], ca[keep]
            if len(fa) == 0:
                continue
            node = np.full(num_faces, -1, dtype=np.int64)
            node[fa] = np.arange(len(fa))
            c0 = cur[fa].copy()
            c1 = ca.copy()
            pa, pb = node[ea], node[eb]
            la, lb = labels[ea], labels[eb]
            # Edges with one variable end: the fixed end adds unary costs.
            for var, fix, lv, lf in ((pa, pb, la, lb), (pb, pa, lb, la)):
                m = (var >= 0) & (fix < 0) & (lf >= 0)
                np.add.at(c0, var[m], smoothness * (lv[m] != lf[m]))
                np.add.at(c1, var[m], smoothness * (lf[m] != alpha))
            # Edges with two variable ends: E00 = w[la != lb], E01 = E10 = w, E11 = 0.
            m = (pa >= 0) & (pb >= 0)
            e00 = smoothness * (la[m] != lb[m])
            # E = E00 + (E10 - E00) x_a + (E11 - E10) x_b + (E01 + E10 - E00 - E11) (1 - x_a) x_b
            np.add.at(c0, pa[m], e00)
            np.add.at(c1, pa[m], smoothness)
            np.add.at(c1, pb[m], -smoothness)
            g = maxflow.Graph[float](len(fa), int(m.sum()))
            nodes = g.add_nodes(len(fa))
            shift = np.minimum(c0, c1)
            _tedges(g, nodes, c0 - shift, c1 - shift)
            g.add_edges(pa[m], pb[m], 2 * smoothness - e00, np.zeros(int(m.sum())))
            g.maxflow()
            switch = g.get_grid_segments(nodes)
            if switch.any():
                labels[fa[switch]] = alpha
                cur[fa[switch]] = ca[switch]
                changed += int(switch.sum())
        if changed == 0:
            break
    log.info("view selection: energy %.1f -> %.1f", e0, energy())
    return labels
