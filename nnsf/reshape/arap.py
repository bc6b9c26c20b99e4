"""Two-step as-rigid-as-possible deformation (Igarashi, Moscovich & Hughes 2005).

Notation: n rest vertices v ``(n, 2)``, t triangles, m handles.  A handle is
a fixed linear combination of vertices, a row of the sparse matrix C ``(m, n)``:
barycentric weights of the triangle that contains a key point, or a single 1
for a subkey vertex.  Handle h has weight w_h and, per frame, a target
position g_h; handles are soft constraints w_h ‖C_h v' − g_h‖².

**Step 1, similarity fit.**  In every triangle (a, b, c) and for each of its
three corners c, the rest corner in the frame of the opposite edge,
v_c = v_a + x e + y R90 e with e = v_b − v_a, is invariant to rotation and
uniform scale.  Step 1 minimises, over the deformed v',

    Σ_tri Σ_corners ‖v'_c − v'_a − x (v'_b − v'_a) − y R90 (v'_b − v'_a)‖²
      + Σ_h w_h² ‖C_h v' − g_h‖²,

linear least squares in the 2n coordinates (x and y are coupled through R90).
Its normal matrix G₁ = A₁ᵀA₁ + I₂ ⊗ CᵀW²C does not depend on the targets.

**Step 2, scale adjustment.**  Each rest triangle is fitted to its step-1
image by a rotation about the centroids (2-D orthogonal Procrustes in closed
form: the angle of Σ (rest corner) · / × (deformed corner)), removing the
scale step 1 allowed.  Then, separately for x and y,

    Σ_tri Σ_edges ‖(v''_b − v''_a) − R_tri (v_b − v_a)‖² + Σ_h w_h² ‖C_h v'' − g_h‖²,

with normal matrix G₂ = A₂ᵀA₂ + CᵀW²C, again fixed.

Both normal matrices are factorised once (``scipy.sparse.linalg.splu`` with
a symmetric fill-reducing ordering; scipy has no sparse Cholesky) when the
deformer is built, in float64.  A frame then costs a few sparse mat-vecs
(right-hand sides, and step 2's rotation fit, which is linear up to a
per-triangle normalisation) and back-solves: one of size 2n, one of size n
with two columns.  :meth:`TwoStepARAP.deform` takes a whole clip in one call.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from nnsf.reshape.mesh import triangle_areas


# --------------------------------------------------------------------------- handles

@dataclass
class Handles:
    """Soft position constraints on a mesh.

    Attributes
    ----------
    matrix : scipy.sparse.csr_matrix, shape (m, n)
        Row h gives handle h's position as a combination of the vertices.
    weights : ndarray, shape (m,)
        w_h (unitless; the shape terms have weight 1 per triangle corner).
    """

    matrix: sp.csr_matrix
    weights: np.ndarray

    def __len__(self) -> int:
        return self.matrix.shape[0]

    def positions(self, vertices: np.ndarray) -> np.ndarray:
        """Handle positions ``(..., m, 2)`` on vertices ``(..., n, 2)``."""
        v = np.asarray(vertices, dtype=np.float64)
        if v.ndim == 2:
            return self.matrix @ v
        F, n, _ = v.shape
        out = self.matrix @ v.transpose(1, 0, 2).reshape(n, 2 * F)
        return out.reshape(-1, F, 2).transpose(1, 0, 2)

    def __add__(self, other: "Handles") -> "Handles":
        return Handles(sp.vstack([self.matrix, other.matrix]).tocsr(),
                       np.concatenate([self.weights, other.weights]))

    @classmethod
    def at_vertices(cls, n_vertices: int, index, weight: float = 1.0) -> "Handles":
        """One handle per listed vertex ``(k,)``."""
        index = np.asarray(index, dtype=np.int64)
        k = len(index)
        m = sp.csr_matrix((np.ones(k), (np.arange(k), index)), shape=(k, n_vertices))
        return cls(m, np.full(k, float(weight)))

    @classmethod
    def at_points(cls, vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray,
                  weight: float = 1.0) -> "Handles":
        """One handle per point ``(k, 2)``: barycentric in its containing triangle.

        A point outside every triangle (it may sit in the sliver between the
        pixel mask and the simplified outline) uses the nearest triangle's
        barycentric coordinates, slightly outside [0, 1]; the constraint stays
        linear and exact at rest.
        """
        bary, tri = barycentric(vertices, triangles, points)
        k = len(tri)
        rows = np.repeat(np.arange(k), 3)
        m = sp.csr_matrix((bary.ravel(), (rows, triangles[tri].ravel())), shape=(k, len(vertices)))
        return cls(m, np.full(k, float(weight)))


def barycentric(vertices: np.ndarray, triangles: np.ndarray, points: np.ndarray):
    """Barycentric coordinates ``(k, 3)`` and triangle index ``(k,)`` of points ``(k, 2)``.

    The triangle chosen maximises the smallest coordinate: the containing
    triangle when there is one, otherwise the one the point is least outside.
    """
    points = np.atleast_2d(np.asarray(points, dtype=np.float64))
    p = vertices[triangles]  # (t, 3, 2)
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]  # (t,)
    r = points[:, None, :] - p[None, :, 0]  # (k, t, 2)
    l1 = (r[..., 0] * e2[:, 1] - r[..., 1] * e2[:, 0]) / det
    l2 = (e1[:, 0] * r[..., 1] - e1[:, 1] * r[..., 0]) / det
    bary = np.stack([1 - l1 - l2, l1, l2], -1)  # (k, t, 3)
    best = np.argmax(bary.min(-1), axis=1)
    return bary[np.arange(len(points)), best], best


# --------------------------------------------------------------------------- deformer

def _similarity_rows(vertices: np.ndarray, triangles: np.ndarray) -> sp.csr_matrix:
    """A₁ ``(6t, 2n)``: step-1 residual rows, columns x_0..x_{n-1}, y_0..y_{n-1}."""
    n, t = len(vertices), len(triangles)
    rows, cols, vals = [], [], []
    for k in range(3):
        a, b, c = triangles[:, k], triangles[:, (k + 1) % 3], triangles[:, (k + 2) % 3]
        e = vertices[b] - vertices[a]
        r = vertices[c] - vertices[a]
        ee = (e * e).sum(1)
        x = (r * e).sum(1) / ee
        y = (r[:, 0] * -e[:, 1] + r[:, 1] * e[:, 0]) / ee  # r · R90 e
        rx = 6 * np.arange(t) + 2 * k  # row of the x residual; the y residual is rx + 1
        ry = rx + 1
        # x residual: x'_c − x'_a − x (x'_b − x'_a) + y (y'_b − y'_a)
        # y residual: y'_c − y'_a − x (y'_b − y'_a) − y (x'_b − x'_a)
        for row, col, val in (
            (rx, c, 1.0), (rx, a, x - 1.0), (rx, b, -x), (rx, n + b, y), (rx, n + a, -y),
            (ry, n + c, 1.0), (ry, n + a, x - 1.0), (ry, n + b, -x), (ry, b, -y), (ry, a, y),
        ):
            rows.append(row)
            cols.append(col)
            vals.append(np.broadcast_to(val, row.shape))
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(6 * t, 2 * n))


def _edge_rows(n: int, triangles: np.ndarray) -> sp.csr_matrix:
    """A₂ ``(3t, n)``: row (tri, k) is v_b − v_a for edge k = (a, b) = (k, k+1 mod 3)."""
    t = len(triangles)
    a = triangles[:, [0, 1, 2]].ravel()
    b = triangles[:, [1, 2, 0]].ravel()
    rows = np.arange(3 * t)
    return sp.csr_matrix((np.concatenate([-np.ones(3 * t), np.ones(3 * t)]),
                          (np.concatenate([rows, rows]), np.concatenate([a, b]))), shape=(3 * t, n))


def _factorise(G: sp.spmatrix, what: str):
    """Sparse LU of a symmetric positive (semi)definite normal matrix; refuse a singular one."""
    # G is symmetric positive definite once the handles pin a similarity; a
    # symmetric ordering and diagonal pivots keep the LU as sparse as a
    # Cholesky factor would be.  Diagonal pivoting does not stop at a
    # numerically zero pivot, so singularity is tested on U's diagonal.
    msg = (f"ARAP {what} system is singular: the handles must pin at least two distinct points "
           "of every connected piece of the mesh")
    try:
        lu = splu(G.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                  options={"SymmetricMode": True})
    except RuntimeError:
        raise ValueError(msg) from None
    pivots = np.abs(lu.U.diagonal())
    if not np.all(np.isfinite(pivots)) or pivots.min() <= 1e-12 * pivots.max():
        raise ValueError(msg)
    return lu


#: Right-hand-side columns per SuperLU back-solve.  SuperLU's multi-column
#: solve is several times slower per column beyond ~8-16 columns (its work
#: arrays fall out of cache), so clips are solved in blocks of this many.
SOLVE_BLOCK = 8


def _block_solve(lu, B: np.ndarray) -> np.ndarray:
    """``lu.solve`` on the columns of ``B`` ``(N, K)`` in blocks of :data:`SOLVE_BLOCK`."""
    if B.shape[1] <= SOLVE_BLOCK:
        return lu.solve(np.asfortranarray(B))
    out = np.empty(B.shape, order="F")
    for k in range(0, B.shape[1], SOLVE_BLOCK):
        out[:, k:k + SOLVE_BLOCK] = lu.solve(np.asfortranarray(B[:, k:k + SOLVE_BLOCK]))
    return out


class TwoStepARAP:
    """Two-step ARAP deformer for one mesh and one handle set (module docstring).

    Parameters
    ----------
    vertices : ``(n, 2)`` rest positions, pixels.
    triangles : ``(t, 3)`` vertex indices.
    handles : :class:`Handles`

    Building the deformer assembles and factorises both systems; then
    :meth:`deform` maps handle targets ``(m, 2)`` or ``(F, m, 2)`` to vertex
    positions ``(n, 2)`` or ``(F, n, 2)``.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, handles: Handles):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self.handles = handles
        check_orientation(self.vertices, self.triangles)
        n = len(self.vertices)
        C = handles.matrix.tocsr()
        W2 = sp.diags(handles.weights ** 2)
        self._B = (C.T @ W2).tocsr()  # (n, m): right-hand side of the handle terms
        K = (C.T @ W2 @ C).tocsr()
        self._A1 = _similarity_rows(self.vertices, self.triangles)
        self._A2 = _edge_rows(n, self.triangles)
        self._A2T = self._A2.T.tocsr()
        self._G1 = (self._A1.T @ self._A1 + sp.block_diag([K, K])).tocsc()
        self._G2 = (self._A2.T @ self._A2 + K).tocsc()
        self._lu1 = _factorise(self._G1, "similarity (step 1)")
        self._lu2 = _factorise(self._G2, "scale (step 2)")
        p = self.vertices[self.triangles]  # (t, 3, 2)
        self._rest_centred = p - p.mean(axis=1, keepdims=True)
        self._rest_edges = p[:, [1, 2, 0]] - p  # edge k = v_{k+1} − v_k
        self._fit_ops()

    def _fit_ops(self) -> None:
        """Sparse operators that turn step 2's per-triangle work into two mat-vecs.

        The rotation of triangle τ has (unnormalised) cosine and sine
        c_τ = Σ_k P_k · q_k and s_τ = Σ_k P_k × q_k, with P the centred rest
        corners and q the step-1 corners: both linear in the step-1 vertices,
        so ``(c; s) = F z₁`` with F ``(2t, 2n)``.  The right-hand side of the
        edge terms, A₂ᵀ (rotated rest edges), is linear in the normalised
        (c; s): ``S (ĉ; ŝ)`` with S ``(2n, 2t)``.  Gathering corners and
        rotating edges triangle by triangle in numpy costs several times more.
        """
        n, t = self.n_vertices, len(self.triangles)
        P = self._rest_centred
        tri_rows = np.repeat(np.arange(t), 3)
        cols = self.triangles.ravel()
        px, py = P[..., 0].ravel(), P[..., 1].ravel()
        # c = Σ px qx + py qy ; s = Σ px qy − py qx
        self._F = sp.csr_matrix((np.concatenate([px, py, -py, px]),
                                 (np.concatenate([tri_rows, tri_rows, t + tri_rows, t + tri_rows]),
                                  np.concatenate([cols, n + cols, cols, n + cols]))), shape=(2 * t, 2 * n))
        E = self._rest_edges
        A2T = self._A2T  # (n, 3t), column (τ, k)
        Sx = A2T @ sp.csr_matrix((E[..., 0].ravel(), (np.arange(3 * t), tri_rows)), shape=(3 * t, t))
        Sy = A2T @ sp.csr_matrix((E[..., 1].ravel(), (np.arange(3 * t), tri_rows)), shape=(3 * t, t))
        # rhs_x = Sx ĉ − Sy ŝ ; rhs_y = Sy ĉ + Sx ŝ
        self._S = sp.bmat([[Sx, -Sy], [Sy, Sx]]).tocsr()

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    # ---- per-frame pieces (targets: (m, 2) or (F, m, 2))

    def _handle_rhs(self, g: np.ndarray) -> np.ndarray:
        """CᵀW² g for targets ``(F, m, 2)``: ``(n, 2F)``, columns interleaved per frame (x0, y0, x1, ...)."""
        F, m, _ = g.shape
        return self._B @ g.transpose(1, 0, 2).reshape(m, 2 * F)

    def _solve1(self, rhs: np.ndarray) -> np.ndarray:
        """Step-1 back-solve: handle rhs ``(n, 2F)`` -> stacked z₁ ``(2n, F)``."""
        n = self.n_vertices
        F = rhs.shape[1] // 2
        r = rhs.reshape(n, F, 2)
        return _block_solve(self._lu1, np.concatenate([r[..., 0], r[..., 1]]))

    @staticmethod
    def _unstack(z: np.ndarray, n: int, F: int | None) -> np.ndarray:
        """Stacked (x; y) ``(2n, F)`` -> ``(F, n, 2)``, or ``(n, 2)`` when ``F`` is None."""
        out = np.stack([z[:n].T, z[n:].T], axis=-1)
        return out[0] if F is None else out

    def _frames(self, targets) -> tuple[np.ndarray, int | None]:
        g = np.asarray(targets, dtype=np.float64)
        if g.shape[-2:] != (len(self.handles), 2) or g.ndim not in (2, 3):
            raise ValueError(f"expected handle targets ({len(self.handles)}, 2) or "
                             f"(frames, {len(self.handles)}, 2), got {g.shape}")
        return (g[None], None) if g.ndim == 2 else (g, g.shape[0])

    def _step2(self, z1: np.ndarray, hrhs: np.ndarray) -> np.ndarray:
        """Step 2 from stacked z₁ ``(2n, F)`` and handle rhs ``(n, 2F)``: stacked z₂ ``(2n, F)``."""
        n, t = self.n_vertices, len(self.triangles)
        F = z1.shape[1]
        cs = self._F @ z1  # (2t, F)
        r = np.hypot(cs[:t], cs[t:])
        ok = r > 0  # a triangle collapsed to a point keeps its rest orientation
        inv = np.where(ok, 1.0 / np.where(ok, r, 1.0), 0.0)
        cs[:t] = np.where(ok, cs[:t] * inv, 1.0)
        cs[t:] *= inv
        rhs = self._S @ cs  # (2n, F)
        h = hrhs.reshape(n, F, 2)
        # x and y share G₂: one solve with 2F columns.
        z = _block_solve(self._lu2, np.concatenate([rhs[:n] + h[..., 0], rhs[n:] + h[..., 1]], axis=1))
        return np.concatenate([z[:, :F], z[:, F:]])

    def similarity_step(self, targets) -> np.ndarray:
        """Step 1: vertices ``(n, 2)`` (or ``(F, n, 2)``) for targets ``(m, 2)`` (or ``(F, m, 2)``)."""
        g, F = self._frames(targets)
        z1 = self._solve1(self._handle_rhs(g))
        return self._unstack(z1, self.n_vertices, F)

    def fitted_edges(self, v1: np.ndarray) -> np.ndarray:
        """Rest edges rotated onto the step-1 triangles: ``(..., n, 2)`` -> ``(..., t, 3, 2)``.

        The per-triangle reference implementation of what :meth:`_step2`
        does with sparse operators; used by :meth:`scale_system`.
        """
        q = v1[..., self.triangles, :]  # (..., t, 3, 2)
        P = self._rest_centred
        c = (P * q).sum(axis=(-1, -2))
        s = (P[..., 0] * q[..., 1] - P[..., 1] * q[..., 0]).sum(-1)
        r = np.hypot(c, s)
        ok = r > 0
        c = np.where(ok, c / np.where(ok, r, 1.0), 1.0)[..., None]
        s = np.where(ok, s / np.where(ok, r, 1.0), 0.0)[..., None]
        E = self._rest_edges
        return np.stack([c * E[..., 0] - s * E[..., 1], s * E[..., 0] + c * E[..., 1]], axis=-1)

    def scale_step(self, v1: np.ndarray, targets) -> np.ndarray:
        """Step 2 from step-1 vertices ``(n, 2)`` / ``(F, n, 2)`` and the same targets."""
        g, F = self._frames(targets)
        v1 = np.asarray(v1, dtype=np.float64).reshape(g.shape[0], self.n_vertices, 2)
        z1 = np.concatenate([v1[..., 0].T, v1[..., 1].T])
        return self._unstack(self._step2(z1, self._handle_rhs(g)), self.n_vertices, F)

    def deform(self, targets, steps: int = 2) -> np.ndarray:
        """Vertex positions for handle targets: ``(m, 2)`` -> ``(n, 2)``; ``(F, m, 2)`` -> ``(F, n, 2)``.

        ``steps=1`` returns the similarity step alone.  Frames are
        independent, so a clip is solved with all frames as columns of one
        right-hand side.
        """
        g, F = self._frames(targets)
        hrhs = self._handle_rhs(g)
        z = self._solve1(hrhs)
        if steps != 1:
            z = self._step2(z, hrhs)
        return self._unstack(z, self.n_vertices, F)

    # ---- the same systems, stacked, for checks against dense solvers

    def similarity_system(self, targets) -> tuple[sp.csr_matrix, np.ndarray]:
        """Step 1 as a stacked least-squares problem ``min ‖M z − r‖``, z = (x; y) ``(2n,)``."""
        g = np.asarray(targets, dtype=np.float64)
        W = sp.diags(self.handles.weights)
        WC = W @ self.handles.matrix
        M = sp.vstack([self._A1, sp.block_diag([WC, WC])]).tocsr()
        r = np.concatenate([np.zeros(self._A1.shape[0]), self.handles.weights * g[:, 0],
                            self.handles.weights * g[:, 1]])
        return M, r

    def scale_system(self, v1, targets) -> tuple[sp.csr_matrix, np.ndarray]:
        """Step 2 as ``min ‖M z − R‖`` with z ``(n, 2)`` and R ``(3t + m, 2)``."""
        g = np.asarray(targets, dtype=np.float64)
        W = sp.diags(self.handles.weights)
        M = sp.vstack([self._A2, W @ self.handles.matrix]).tocsr()
        R = np.vstack([self.fitted_edges(np.asarray(v1, dtype=np.float64)).reshape(-1, 2),
                       self.handles.weights[:, None] * g])
        return M, R


def check_orientation(vertices: np.ndarray, triangles: np.ndarray) -> None:
    """Raise ``ValueError`` unless every rest triangle has positive area (CCW)."""
    if np.any(triangle_areas(vertices, triangles) <= 0):
        raise ValueError("rest triangles must be counter-clockwise with positive area")
