"""ISOMAP diagnostics of the weights V (docs/method.md §15.3; the paper's Fig. 6).

Residual variance (Tenenbaum, de Silva & Langford 2000) measures how much of
the geodesic-distance structure a ``d``-dimensional ISOMAP embedding misses:

    rv(d) = 1 − R²(D_geodesic, D_embedding(d)),

with ``R`` the linear correlation over all point pairs.  This is *not*
scikit-learn's ``Isomap.reconstruction_error()``, which is a kernel-matrix
norm of the full embedding and has no per-dimension curve.

ISOMAP needs O(n²) memory and O(n³) time for the dense eigen-solver, so the
stage embeds a :func:`stratified_sample` of the frames, not all of them.
"""
from __future__ import annotations

import numbers
import warnings

import numpy as np
from scipy.sparse import SparseEfficiencyWarning
from scipy.sparse.csgraph import connected_components
from scipy.spatial.distance import pdist
from sklearn.manifold import Isomap
from sklearn.neighbors import NearestNeighbors


def _int(name, value, lo):
    if not (isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= lo):
        raise ValueError(f"{name} must be an integer >= {lo}, got {value!r}")


def connected_n_neighbors(V, n_neighbors: int) -> int:
    """Smallest ``k ≥ n_neighbors`` whose k-nearest-neighbour graph of ``V`` is connected.

    ISOMAP's geodesic distances are infinite between components of a
    disconnected neighbour graph (scikit-learn then bridges the components
    with Euclidean edges and warns).  We raise the neighbour count instead of
    dropping rows: every frame stays in the embedding -- a Fig. 6 coloured
    by character needs every character -- and the larger ``k`` only makes
    geodesics a little more Euclidean.  The graph is symmetric (an edge if
    either point is among the other's neighbours), as in ISOMAP, so
    connectivity is monotone in ``k`` and the smallest ``k`` is found by
    doubling and then bisection.  ``k = n − 1`` is always connected.
    """
    V = np.asarray(V, dtype=float)
    n = V.shape[0]
    _int("n_neighbors", n_neighbors, 1)
    if n < 2:
        raise ValueError(f"need at least 2 points, got {n}")
    k_lo = min(n_neighbors, n - 1)
    nn = NearestNeighbors().fit(V)

    def connected(k):
        graph = nn.kneighbors_graph(n_neighbors=k, mode="connectivity")
        return connected_components(graph, directed=False)[0] == 1

    if connected(k_lo):
        return k_lo
    bad, k = k_lo, k_lo
    while True:
        k = min(2 * k, n - 1)
        if k == n - 1 or connected(k):
            good = k
            break
        bad = k
    while good - bad > 1:                    # invariant: bad disconnected, good connected
        mid = (bad + good) // 2
        if connected(mid):
            good = mid
        else:
            bad = mid
    return good


def residual_variance(V, n_neighbors: int = 10, max_dim: int = 40, disconnected: str = "neighbors"):
    """Residual variance of ISOMAP embeddings of ``V`` for d = 1..D.

    Parameters
    ----------
    V : array, shape (n, k)
        Points to embed (rows of NNSF weights).
    n_neighbors : int >= 1
        Neighbours of the ISOMAP graph.
    max_dim : int >= 1
        Largest embedding dimension; ``D = min(max_dim, k, n − 1)``.
    disconnected : {"neighbors", "bridge"}
        What to do when the ``n_neighbors`` graph is disconnected (weights of
        different motions often form separate clusters).  ``"neighbors"``
        (default): raise ``n_neighbors`` to :func:`connected_n_neighbors`,
        the smallest value that connects the graph -- every geodesic is then
        a path through the data.  ``"bridge"``: keep ``n_neighbors`` and let
        scikit-learn join the components by their closest pairs of points
        (one Euclidean shortcut per pair of components).  Either way every
        row stays in the embedding and a ``UserWarning`` says what was done.

    Returns
    -------
    dims : ndarray of int, shape (D,)
        ``1..D``.
    rv : ndarray, shape (D,)
        Residual variance ``1 − R²`` in [0, 1] (dimensionless).
    embedding : ndarray, shape (n, D)
        The D-dimensional embedding; its first ``d`` columns are the
        d-dimensional embedding (one eigen-decomposition serves every d).

    Notes
    -----
    ``eigen_solver="dense"`` makes the result deterministic.  Eigenvector
    signs are arbitrary, which does not change any distance.
    """
    V = np.asarray(V, dtype=float)
    if V.ndim != 2 or not np.isfinite(V).all():
        raise ValueError(f"V must be a finite 2-D array, got shape {V.shape}")
    n, k = V.shape
    if n < 3:
        raise ValueError(f"ISOMAP needs at least 3 points, got {n}")
    _int("n_neighbors", n_neighbors, 1)
    _int("max_dim", max_dim, 1)
    if disconnected not in ("neighbors", "bridge"):
        raise ValueError(f"disconnected must be 'neighbors' or 'bridge', got {disconnected!r}")
    D = min(max_dim, k, n - 1)
    k_asked = min(n_neighbors, n - 1)
    if disconnected == "neighbors":
        k_used = connected_n_neighbors(V, n_neighbors)
        if k_used != k_asked:
            warnings.warn(f"the {n_neighbors}-nearest-neighbour graph is disconnected; ISOMAP uses "
                          f"n_neighbors={k_used}, the smallest value that connects it", UserWarning,
                          stacklevel=2)
    else:
        k_used = k_asked
        if connected_n_neighbors(V, k_asked) != k_asked:
            warnings.warn(f"the {n_neighbors}-nearest-neighbour graph is disconnected; its components "
                          "are bridged by their closest pairs of points", UserWarning, stacklevel=2)
    iso = Isomap(n_neighbors=k_used, n_components=D, eigen_solver="dense")
    with warnings.catch_warnings():
        # Our own warning above already says what happened to the graph.
        warnings.filterwarnings("ignore", message=".*connected components.*")
        # scikit-learn's bridging edits a CSR matrix in place; harmless at this size.
        warnings.filterwarnings("ignore", category=SparseEfficiencyWarning)
        embedding = iso.fit_transform(V)
    geo = iso.dist_matrix_[np.triu_indices(n, 1)]
    dims = np.arange(1, D + 1)
    rv = np.empty(D)
    for i, d in enumerate(dims):
        emb = pdist(embedding[:, :d])
        rv[i] = 1.0 - _corr(geo, emb) ** 2
    return dims, rv, embedding


def _corr(a, b) -> float:
    """Pearson correlation; 0 when either side is constant (nothing explained)."""
    a = a - a.mean()
    b = b - b.mean()
    den = np.sqrt(np.dot(a, a) * np.dot(b, b))
    return float(np.dot(a, b) / den) if den > 0 else 0.0


def intrinsic_dimension(dims, rv, threshold: float = 0.01) -> int:
    """Elbow of the residual-variance curve.

    The smallest ``d`` such that going to ``d + 1`` lowers the residual
    variance by less than ``threshold`` (absolute); the last ``d`` if every
    step still helps.  Residual variance is a fraction of the geodesic
    distances' variance, so the default 0.01 reads "one more dimension
    explains less than 1 % more" -- scale-free, and the 'elbow' criterion
    Tenenbaum et al. read off their curves.  A local rule rather than "within
    ``threshold`` of the minimum" because the tail of a noisy curve keeps
    creeping down by tiny amounts and the minimum sits at the largest d.

    Parameters
    ----------
    dims : array of int, shape (D,), increasing
    rv : array, shape (D,)
    threshold : float > 0
    """
    dims = np.asarray(dims)
    rv = np.asarray(rv, dtype=float)
    if dims.ndim != 1 or rv.shape != dims.shape or len(dims) == 0:
        raise ValueError(f"dims and rv must be 1-D of the same non-zero length, got "
                         f"{dims.shape} and {rv.shape}")
    if not (isinstance(threshold, numbers.Real) and threshold > 0):
        raise ValueError(f"threshold must be a number > 0, got {threshold!r}")
    gain = rv[:-1] - rv[1:]                  # what adding dimension d+1 buys
    small = np.flatnonzero(gain < threshold)
    return int(dims[small[0]] if small.size else dims[-1])


def stratified_sample(labels, n: int, seed: int = 0) -> np.ndarray:
    """Indices of at most ``n`` rows spread evenly over ``labels``.

    Each label gets ``n // L`` rows (the first ``n mod L`` labels in sorted
    order one more); a label with fewer rows gives all of them and its unused
    share goes to the others (water-filling), so the sample has
    ``min(n, len(labels))`` rows.  Rows are drawn without replacement with
    ``numpy.random.default_rng(seed)``.

    Returns
    -------
    ndarray of int, sorted ascending.
    """
    labels = np.asarray(labels)
    if labels.ndim != 1:
        raise ValueError(f"labels must be 1-D, got shape {labels.shape}")
    _int("n", n, 1)
    if n >= len(labels):
        return np.arange(len(labels))
    classes, inverse, counts = np.unique(labels, return_inverse=True, return_counts=True)
    # Water-filling: a level q with Σ min(count, q) ≤ n, then hand out the rest.
    quota = np.zeros(len(classes), dtype=int)
    left = n
    open_ = np.ones(len(classes), bool)
    while left > 0 and open_.any():
        share = left // open_.sum()
        if share == 0:
            # Fewer rows left than open labels: one each to the first ones.
            idx = np.flatnonzero(open_)[:left]
            quota[idx] += 1
            break
        add = np.minimum(share, counts - quota) * open_
        quota += add
        left -= int(add.sum())
        open_ &= quota < counts
    rng = np.random.default_rng(seed)
    picked = [rng.choice(np.flatnonzero(inverse == c), size=q, replace=False)
              for c, q in enumerate(quota) if q > 0]
    return np.sort(np.concatenate(picked))
