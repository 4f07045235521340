"""The software rasteriser: coverage, depth order, Lambert shading, the side-by-side PNG."""
from __future__ import annotations

import cv2
import numpy as np

from workers.faces.preview import BACKGROUND_BGR, LIGHT, SURFACE_BGR, frame, preview_png, render, side_by_side

SQUARE = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
SQUARE_TRIS = np.array([[0, 1, 2], [0, 2, 3]])


def test_a_facing_square_fills_its_pixels_with_the_lambert_shade():
    img = render(SQUARE, SQUARE_TRIS, size=64, view=(np.zeros(2), 16.0))  # 2 units -> 32 px
    inside, outside = img[32, 32], img[2, 2]
    assert tuple(outside) == BACKGROUND_BGR
    expected = np.clip((0.15 + 0.85 * LIGHT[2]) * SURFACE_BGR, 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(inside, expected)
    covered = np.all(img != BACKGROUND_BGR, axis=2)
    assert abs(covered.sum() - 33 * 33) <= 2 * 33  # a 32 px square, edges inclusive


def test_orientation_y_up_and_nearer_surfaces_win():
    # A small triangle high in y appears in the top half of the image.
    top = np.array([[-0.2, 0.6, 0], [0.2, 0.6, 0], [0, 0.9, 0]], float)
    img = render(top, np.array([[0, 1, 2]]), size=64, view=(np.zeros(2), 30.0))
    rows = np.nonzero(np.any(img != BACKGROUND_BGR, axis=(1, 2)))[0]
    assert rows.max() < 32
    # Two overlapping squares: the one with larger z (nearer the viewer) is drawn, whatever the order.
    tilted = SQUARE.copy()
    tilted[:, 2] = [1.0, 1.0, 1.0, 1.0]
    tilted[:, 0] *= 0.5
    both = np.concatenate([tilted, SQUARE])
    tris = np.concatenate([SQUARE_TRIS, SQUARE_TRIS + 4])
    for order in (tris, tris[::-1]):
        a = render(both, order, size=64, view=(np.zeros(2), 16.0))
        assert np.array_equal(a, render(both, tris, size=64, view=(np.zeros(2), 16.0)))


def test_side_by_side_shares_the_framing_and_encodes_as_png():
    moved = SQUARE * [1.0, 1.5, 1.0]
    centre, scale = frame([SQUARE, moved], 100)
    np.testing.assert_allclose(centre, [0, 0])
    assert scale == 100 * 0.88 / 3.0
    img = side_by_side(SQUARE, moved, SQUARE_TRIS, ("a", "b"), size=100)
    assert img.shape == (100, 204, 3) and img.dtype == np.uint8
    decoded = cv2.imdecode(np.frombuffer(preview_png(SQUARE, moved, SQUARE_TRIS, size=100), np.uint8),
                           cv2.IMREAD_COLOR)
    np.testing.assert_array_equal(decoded, side_by_side(SQUARE, moved, SQUARE_TRIS, ("input", "output"), 100))
    # The taller right panel covers more pixels than the left one.
    left, right = decoded[:, :100], decoded[:, 104:]
    assert np.sum(np.any(right != BACKGROUND_BGR, axis=2)) > 1.3 * np.sum(np.any(left != BACKGROUND_BGR, axis=2))
