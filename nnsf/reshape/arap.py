"""Two-step as-rigid-as-possible deformation (Igarashi, Moscovich & Hughes 2005; docs/method.md §13).

Notation: n rest vertices v ``(n, 2)``, t triangles, m handles.  A handle is a fixed linear
combination of vertices, a row of the sparse matrix C ``(m, n)`` (barycentric weights of the
triangle holding a key point, or a single 1 for a vertex); handle h has weight w_h and, per frame,
a target g_h: a soft constraint w_h² ‖C_h v' − g_h‖².

* **Step 1, similarity fit**: each rest corner, written in the frame of the opposite edge
  (v_c = v_a + x e + y R90 e, e = v_b − v_a), keeps its (x, y) in least squares with the handle
  terms; normal matrix G₁ = A₁ᵀA₁ + I₂ ⊗ CᵀW²C.
* **Step 2, scale adjustment**: each rest triangle is fitted to its step-1 image by a rotation
  (2-D Procrustes in closed form), then per coordinate Σ ‖(v''_b − v''_a) − R_tri (v_b − v_a)‖²
  plus the handle terms; normal matrix G₂ = A₂ᵀA₂ + CᵀW²C.

Neither normal matrix depends on the targets: both are factorised once (``splu``, symmetric
ordering; G₁ as the Hermitian n × n matrix H whose real form it is, since step 1 is
complex-linear in x + iy).  Step 1 is z₁ = M₁ g with M₁ = H⁻¹CᵀW² computed once, so a frame is a
few sparse products and one back-solve with x and y as two columns; :meth:`TwoStepARAP.deform`
takes a whole clip in one call.
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
        return Handles(sp.vstack([self.matrix, other.matrix]).tocsr(), np.concatenate([self.weights, other.weights]))

    @classmethod
    def at_vertices(cls, n_vertices: int, index, weight=1.0) -> "Handles":
        """One handle per listed vertex ``(k,)``, of ``weight`` (one, or ``(k,)``)."""
        index = np.asarray(index, dtype=np.int64)
        k = len(index)
        m = sp.csr_matrix((np.ones(k), (np.arange(k), index)), shape=(k, n_vertices))
        return cls(m, np.full(k, weight, dtype=np.float64))


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
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(6 * t, 2 * n))


def _edge_rows(n: int, triangles: np.ndarray) -> sp.csr_matrix:
    """A₂ ``(3t, n)``: row (tri, k) is v_b − v_a for edge k = (a, b) = (k, k+1 mod 3)."""
    t = len(triangles)
    a = triangles[:, [0, 1, 2]].ravel()
    b = triangles[:, [1, 2, 0]].ravel()
    rows = np.arange(3 * t)
    return sp.csr_matrix((np.concatenate([-np.ones(3 * t), np.ones(3 * t)]),
                          (np.concatenate([rows, rows]), np.concatenate([a, b]))), shape=(3 * t, n))


def _factorise(G: sp.spmatrix, what: str):
    """Sparse LU of a symmetric (Hermitian) positive (semi)definite normal matrix; refuse a singular one."""
    # G is positive definite once the handles pin a similarity; a symmetric ordering and diagonal
    # pivots keep the LU as sparse as a Cholesky factor would be.  Diagonal pivoting does not stop
    # at a numerically zero pivot, so singularity is tested on U's diagonal.
    msg = (f"ARAP {what} system is singular: the handles must pin at least two distinct points "
           "of every connected piece of the mesh")
    try:
        lu = splu(G.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    except RuntimeError:
        raise ValueError(msg) from None
    pivots = np.abs(lu.U.diagonal())
    if not np.all(np.isfinite(pivots)) or pivots.min() <= 1e-12 * pivots.max():
        raise ValueError(msg)
    return lu


#: Real right-hand-side columns per SuperLU back-solve (a complex column counts
#: as two).  SuperLU's multi-column solve is several times slower per column
#: beyond ~8-16 real columns (its work arrays fall out of cache), so clips are
#: solved in blocks.
SOLVE_BLOCK = 8


def _block_solve(lu, B: np.ndarray) -> np.ndarray:
    """``lu.solve`` on the columns of ``B`` ``(N, K)`` in blocks of :data:`SOLVE_BLOCK` real columns."""
    block = SOLVE_BLOCK // 2 if np.iscomplexobj(B) else SOLVE_BLOCK
    if B.shape[1] <= block:
        return lu.solve(np.asfortranarray(B))
    out = np.empty(B.shape, dtype=B.dtype, order="F")
    for k in range(0, B.shape[1], block):
        out[:, k:k + block] = lu.solve(np.asfortranarray(B[:, k:k + block]))
    return out


#: Largest n × m (vertices × handles) for which step 1 keeps the dense operator M₁ = H⁻¹ CᵀW²
#: (16 bytes an entry: 4·10⁶ is 64 MB); a larger system back-solves every frame.
DENSE_STEP1_MAX = 4_000_000


def _points(z: np.ndarray) -> np.ndarray:
    """Complex vertex columns ``(n, F)`` -> points ``(F, n, 2)`` (x = real part, y = imaginary part)."""
    return np.ascontiguousarray(z.T).view(np.float64).reshape(z.shape[1], z.shape[0], 2)


class TwoStepARAP:
    """Two-step ARAP deformer for one mesh and one handle set (module docstring).

    Parameters
    ----------
    vertices : ``(n, 2)`` rest positions, pixels.
    triangles : ``(t, 3)`` vertex indices.
    handles : :class:`Handles`

    Building the deformer assembles and factorises both systems; then
    :meth:`deform` maps handle targets ``(m, 2)`` or ``(F, m, 2)`` to vertex
    positions ``(n, 2)`` or ``(F, n, 2)``.  Internally a point (x, y) is the
    complex number x + iy, and step 1's real normal matrix G₁ = [[P, −Q], [Q, P]]
    (P symmetric, Q antisymmetric) is factorised as H = P + iQ.  With
    n · m ≤ :data:`DENSE_STEP1_MAX`, step 1 is the product of the precomputed
    M₁ = H⁻¹CᵀW² with the targets; otherwise a back-solve with H.
    """

    def __init__(self, vertices: np.ndarray, triangles: np.ndarray, handles: Handles):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self.handles = handles
        if np.any(triangle_areas(self.vertices, self.triangles) <= 0):
            raise ValueError("rest triangles must be counter-clockwise with positive area")
        n = len(self.vertices)
        C = handles.matrix.tocsr()
        W2 = sp.diags(handles.weights ** 2)
        self._B = (C.T @ W2).tocsr()  # (n, m): right-hand side of the handle terms
        K = (C.T @ W2 @ C).tocsr()
        self._A1 = _similarity_rows(self.vertices, self.triangles)
        self._A2 = _edge_rows(n, self.triangles)
        self._A2T = self._A2.T.tocsr()
        self._G1 = (self._A1.T @ self._A1 + sp.block_diag([K, K])).tocsc()
        self._H1 = (self._G1[:n, :n] + 1j * self._G1[n:, :n]).tocsc()  # H = P + iQ (class docstring)
        self._G2 = (self._A2.T @ self._A2 + K).tocsc()
        self._lu1 = _factorise(self._H1, "similarity (step 1)")
        self._lu2 = _factorise(self._G2, "scale (step 2)")
        # Step 1 is linear in the m handle targets: z₁ = H⁻¹ CᵀW² g = M₁ g.  With few handles,
        # M₁ (n, m) (m back-solves, once) makes a frame's step 1 one matrix-vector product.  It is
        # kept as a sparse matrix: on a pieced mesh a handle moves only its own piece (the other
        # entries are exact zeros), and scipy's sparse product never starts BLAS threads, which
        # on a busy machine made a threaded dense product (OpenBLAS zgemv) up to 100 times slower.
        m = len(handles)
        self._M1 = (sp.csr_matrix(_block_solve(self._lu1, self._B.toarray().astype(np.complex128)))
                    if n * m <= DENSE_STEP1_MAX else None)
        p = self.vertices[self.triangles]  # (t, 3, 2)
        self._rest_centred = p - p.mean(axis=1, keepdims=True)
        self._rest_edges = p[:, [1, 2, 0]] - p  # edge k = v_{k+1} − v_k
        self._fit_ops()

    def _fit_ops(self) -> None:
        """Sparse operators that turn step 2's per-triangle work into two mat-vecs.

        The rotation of triangle τ has the (unnormalised) complex direction
        c_τ + i s_τ = Σ_k conj(P_k) q_k, with P the centred rest corners and q
        the step-1 corners (c = Σ P·q, s = Σ P×q): linear in the step-1
        vertices, ``F z₁`` with F ``(t, n)`` complex.  The right-hand side
        of the edge terms, A₂ᵀ (rest edges rotated by the unit ĉ + iŝ), is
        ``S (ĉ + iŝ)`` with S = A₂ᵀ E ``(n, t)``, E the complex rest edges.
        Gathering corners and rotating edges triangle by triangle in numpy
        costs several times more.
        """
        n, t = self.n_vertices, len(self.triangles)
        P = self._rest_centred
        tri_rows = np.repeat(np.arange(t), 3)
        self._F = sp.csr_matrix(((P[..., 0] - 1j * P[..., 1]).ravel(), (tri_rows, self.triangles.ravel())),
                                shape=(t, n))
        E = self._rest_edges
        self._S = (self._A2T @ sp.csr_matrix(((E[..., 0] + 1j * E[..., 1]).ravel(), (np.arange(3 * t), tri_rows)),
                                              shape=(3 * t, t))).tocsr()

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    # ---- per-frame pieces (targets: (m, 2) or (F, m, 2))

    @staticmethod
    def _complex(g: np.ndarray) -> np.ndarray:
        """Targets ``(F, m, 2)`` -> complex columns ``(m, F)``."""
        return (g[..., 0] + 1j * g[..., 1]).T

    def _handle_rhs(self, g: np.ndarray) -> np.ndarray:
        """CᵀW² g for targets ``(F, m, 2)``: complex ``(n, F)``."""
        return self._B @ self._complex(g)

    def _step1(self, g: np.ndarray) -> np.ndarray:
        """Step 1 for targets ``(F, m, 2)``: complex vertices ``(n, F)``."""
        return self._M1 @ self._complex(g) if self._M1 is not None else _block_solve(self._lu1, self._handle_rhs(g))

    def _frames(self, targets) -> tuple[np.ndarray, int | None]:
        g = np.asarray(targets, dtype=np.float64)
        if g.shape[-2:] != (len(self.handles), 2) or g.ndim not in (2, 3):
            raise ValueError(f"expected handle targets ({len(self.handles)}, 2) or "
                             f"(frames, {len(self.handles)}, 2), got {g.shape}")
        return (g[None], None) if g.ndim == 2 else (g, g.shape[0])

    def _step2(self, z1: np.ndarray, hrhs: np.ndarray) -> np.ndarray:
        """Step 2 from complex step-1 vertices ``(n, F)`` and handle rhs ``(n, F)``: points ``(F, n, 2)``."""
        n, F = z1.shape
        cs = self._F @ z1  # (t, F)
        r = np.abs(cs)
        if r.min() > 0:
            cs /= r
        else:  # a triangle collapsed to a point keeps its rest orientation
            cs = np.divide(cs, r, out=np.ones_like(cs), where=r > 0)
        rhs = self._S @ cs
        rhs += hrhs
        # x and y share G₂: the complex columns viewed as real ones, (n, 2F) = x0, y0, x1, y1, ...
        z = _block_solve(self._lu2, rhs.view(np.float64))
        return np.ascontiguousarray(np.ascontiguousarray(z).reshape(n, F, 2).transpose(1, 0, 2))

    def fitted_edges(self, v1: np.ndarray) -> np.ndarray:
        """Rest edges rotated onto the step-1 triangles: ``(..., n, 2)`` -> ``(..., t, 3, 2)``.

        The per-triangle reference implementation of what :meth:`_step2`
        does with sparse operators, for :meth:`scale_system`.
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

    def deform(self, targets, steps: int = 2) -> np.ndarray:
        """Vertex positions for handle targets: ``(m, 2)`` -> ``(n, 2)``; ``(F, m, 2)`` -> ``(F, n, 2)``.

        ``steps=1`` returns the similarity step alone.  Frames are independent, so a clip is solved
        with all frames as columns of one right-hand side.
        """
        g, F = self._frames(targets)
        z1 = self._step1(g)
        out = _points(z1) if steps == 1 else self._step2(z1, self._handle_rhs(g))
        return out[0] if F is None else out

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
