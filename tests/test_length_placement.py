import numpy as np

from lab.length_placement import length_offsets


def ribbon(rows=6, x0=0.0, top=1.0, step=0.1):
    """A vertical ribbon of two columns hanging down from y = top (vertices row by row)."""
    V = np.array([[x0 + c * step, top - r * step, 0.0] for r in range(rows) for c in range(2)])
    F = []
    for r in range(rows - 1):
        a, b, c, d = 2 * r, 2 * r + 1, 2 * r + 2, 2 * r + 3
        F += [[a, c, b], [b, c, d]]
    return V, np.array(F)


def test_an_unchanged_garment_gets_no_move():
    V, F = ribbon()
    move, excess = length_offsets(V, V.copy(), F, up=1)
    np.testing.assert_allclose(move, 0.0, atol=1e-12)
    np.testing.assert_allclose(excess, 0.0, atol=1e-12)


def test_a_stretched_hanging_strip_gets_its_length_back_exactly():
    V, F = ribbon()
    top = V[:, 1].max()
    A = V.copy()
    A[:, 1] = top - 1.5 * (top - V[:, 1])          # stretched down by half, from its top
    A += [0.3, -0.2, 0.1]                          # and carried elsewhere
    move, excess = length_offsets(V, A, F, up=1)
    np.testing.assert_allclose(excess, 0.5 * (top - V[:, 1]), atol=1e-9)
    # The whole move gives each vertex its source distance from the (carried) top again.
    np.testing.assert_allclose(A + move, V + [0.3, -0.2, 0.1], atol=1e-9)


def test_each_piece_hangs_from_its_own_top():
    V1, F1 = ribbon(top=1.0)
    V2, F2 = ribbon(rows=4, x0=1.0, top=0.5)
    V, F = np.vstack([V1, V2]), np.vstack([F1, F2 + len(V1)])
    A = V.copy()
    A[len(V1):, 1] = 0.5 - 2.0 * (0.5 - V2[:, 1])   # only the lower piece stretched (twice its length)
    move, excess = length_offsets(V, A, F, up=1)
    np.testing.assert_allclose(excess[:len(V1)], 0.0, atol=1e-12)
    np.testing.assert_allclose(excess[len(V1):], 0.5 - V2[:, 1], atol=1e-9)
    np.testing.assert_allclose((A + move)[len(V1):], V2, atol=1e-9)
