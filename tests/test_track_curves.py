"""The curve model: Catmull-Rom sampling matrices (nnsf.roto.curves)."""
import numpy as np
import pytest

from nnsf.frames.curves import catmull_rom_matrix
from nnsf.roto import curves


@pytest.mark.parametrize("C,n", [(2, 5), (4, 17), (5, 12), (7, 40)])
def test_basis_matches_the_shared_spline(C, n):
    # H-frames' independent implementation is the oracle for the shared curve model
    B0, _, _ = curves.basis(C, n)
    np.testing.assert_allclose(B0, catmull_rom_matrix(C, n), atol=1e-12)


def test_derivative_matrices_are_derivatives_of_the_samples():
    rng = np.random.default_rng(0)
    P = rng.uniform(0, 100, (5, 2))
    C, n, m = 5, 13, 12 * 400 + 1          # every coarse sample is a fine sample
    B0, B1, B2 = curves.basis(C, n)
    dense = curves.sample(P, m)               # fine samples: finite differences
    h_n = (C - 1) / (n - 1)                   # spline parameter per coarse sample step
    h_m = (C - 1) / (m - 1)
    idx = np.round(np.linspace(0, m - 1, n)).astype(int)[1:-1]   # interior, away from ends
    d1 = (dense[idx + 1] - dense[idx - 1]) / (2 * h_m) * h_n
    # (at knots the central difference straddles a jump of c'': O(h) error there)
    np.testing.assert_allclose((B1 @ P)[1:-1], d1, atol=2e-2)
    # second derivative: away from knots (Catmull-Rom is only C1 there)
    u = np.linspace(0, C - 1, n)
    interior = np.abs(u - np.round(u)) > 0.2
    d2 = (dense[idx + 1] - 2 * dense[idx] + dense[idx - 1]) / h_m ** 2 * h_n ** 2
    np.testing.assert_allclose((B2 @ P)[1:-1][interior[1:-1]], d2[interior[1:-1]], atol=1e-2)


def test_curve_interpolates_its_control_points_and_two_points_make_a_segment():
    P = np.array([[0.0, 0.0], [10.0, 5.0], [20.0, -3.0], [35.0, 2.0]])
    s = curves.sample(P, 3 * 8 + 1)           # knots at every 8th sample
    np.testing.assert_allclose(s[::8], P, atol=1e-12)
    seg = curves.sample(P[[0, 3]], 11)
    np.testing.assert_allclose(seg, np.linspace(P[0], P[3], 11), atol=1e-12)
    n = curves.normals(P[[0, 3]], 4)
    d = (P[3] - P[0]) / np.linalg.norm(P[3] - P[0])
    np.testing.assert_allclose(n, np.tile([-d[1], d[0]], (4, 1)), atol=1e-12)


def test_bad_sizes_raise():
    with pytest.raises(ValueError):
        curves.basis(1, 10)
    with pytest.raises(ValueError):
        curves.basis(4, 1)
