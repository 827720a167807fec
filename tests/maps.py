"""Comparing light maps drawn two ways (every face, or the far side of closed casters left out)."""

from __future__ import annotations

import numpy as np

#: One step of a 16-bit map's stored depth.
STEP16 = 1.0 / 65535


def assert_same_but_silhouettes(a: np.ndarray, b: np.ndarray, step: float = STEP16) -> None:
    """The same texels drawn, and the same depths but at a few silhouette texels.

    Where a closed caster's front and back faces meet at its silhouette, both can cover a texel
    centre at nearly one depth; drawing both kept the back face's where rounding put it nearer
    (the front face is the true first surface). The faces there are steep to the light, so the
    rounding is of a few steps of a 16-bit map, or a few millionths of the depth range.

    Parameters
    ----------
    a, b : ndarray
        Decoded maps (``ShadowMap.read_depth`` or a ``light_depth`` output's depths), NaN
        where nothing was drawn.
    step : float
        One step of the map's stored depth.
    """
    np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
    d = np.abs(a.astype(np.float64) - b)[~np.isnan(a)]
    assert np.count_nonzero(d) <= max(2, 1e-4 * d.size), np.count_nonzero(d)
    assert d.max(initial=0.0) <= max(1.5 * step, 3.5 * STEP16), d.max()
