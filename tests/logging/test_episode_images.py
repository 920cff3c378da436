"""A recorded episode as images: the zoomed view around its action."""

from __future__ import annotations

import numpy as np
import pytest

from aia.logging.episode_images import action_view


def test_action_view_is_the_padded_square_around_the_episode():
    points = np.array([[10.0, 20.0], [14.0, 22.0], [np.nan, np.nan]])  # a point not yet seen is left out
    # the padded box is x in [7, 17], y in [17, 25]: a square of side 10 around (12, 21)
    assert action_view(points, margin=3.0, limit=(100.0, 100.0)) == pytest.approx((7.0, 16.0, 17.0, 26.0))
    assert action_view(points, margin=60.0, limit=(100.0, 100.0)) is None  # not smaller than the map
    assert action_view(np.full((2, 2), np.nan), margin=3.0, limit=(100.0, 100.0)) is None
