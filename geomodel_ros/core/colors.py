"""One colour per object id, the same in every output of a scene.

The labelled clouds published to RViz (``msg_adapters.markers``), the reconstruction PLY
written by the command line and the PNG pictures (``tools.render``) all colour a point by
its object id through :func:`id_colors`, so an object has the same colour everywhere.

The colour depends on the id alone (not on which other ids a scene holds, nor on the
object's type), so it also stays the same from frame to frame. Small ids, the usual case,
take the hand-picked :data:`PALETTE` (most distinct first); larger ids step around the
hue circle by the golden ratio, which keeps neighbouring ids far apart.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["PALETTE", "NO_OBJECT_RGB", "as_ids", "id_colors"]

#: Colours (RGB) of ids 0 .. len - 1, most distinct first: a qualitative palette whose
#: entries are at least 60 apart in RGB space (checked by a test).
PALETTE: Final[NDArray[np.uint8]] = np.array([
    (228, 26, 28), (30, 120, 220), (40, 170, 60), (250, 140, 0), (150, 60, 190),
    (0, 175, 175), (225, 50, 200), (150, 95, 40), (120, 130, 0), (20, 40, 140),
    (245, 200, 20), (120, 0, 30), (110, 220, 120), (250, 150, 170), (90, 160, 255),
    (190, 110, 255), (0, 100, 80), (255, 110, 70),
], dtype=np.uint8)
PALETTE.setflags(write=False)
#: Colour of points without an object (negative id): mid grey, unlike any palette entry.
NO_OBJECT_RGB: Final[tuple[int, int, int]] = (128, 128, 128)

#: Hue step per id beyond the palette [turns]: the golden ratio's fractional part spreads
#: consecutive ids over the whole hue circle.
_GOLDEN_STEP: Final = 0.6180339887498949
#: Saturation and value of the hues beyond the palette: strong but not glaring, and never
#: grey.
_SATURATION: Final = 0.75
_VALUE: Final = 0.95


def _golden_hues(ids: NDArray[np.int64]) -> NDArray[np.uint8]:
    """(N, 3) uint8 HSV -> RGB colours with hue ``ids * golden ratio`` (mod 1)."""
    hue = np.mod(ids.astype(np.float64) * _GOLDEN_STEP, 1.0)
    h6 = hue * 6.0
    sector = np.floor(h6).astype(np.int64) % 6
    f = h6 - np.floor(h6)
    v = np.full_like(hue, _VALUE)
    p = np.full_like(hue, _VALUE * (1.0 - _SATURATION))
    q = _VALUE * (1.0 - _SATURATION * f)
    t = _VALUE * (1.0 - _SATURATION * (1.0 - f))
    rgb = np.select(
        [sector[:, None] == k for k in range(6)],
        [np.stack(c, axis=1) for c in ((v, t, p), (q, v, p), (p, v, t),
                                       (p, q, v), (t, p, v), (v, p, q))],
    )
    return np.round(rgb * 255.0).astype(np.uint8)


def as_ids(ids: ArrayLike) -> NDArray[np.int64]:
    """Return ``ids`` as an (N,) int64 array.

    Raises
    ------
    ValueError
        If ``ids`` is not a 1-D integer array.
    """
    arr = np.asarray(ids)
    if arr.ndim != 1 or (arr.size and arr.dtype.kind not in "ui"):
        raise ValueError(f"ids must be an (N,) integer array, got {arr.dtype} {arr.shape}")
    return arr.astype(np.int64, copy=False)


def id_colors(ids: ArrayLike) -> NDArray[np.uint8]:
    """RGB colour of every object id.

    Parameters
    ----------
    ids : (N,) integer array_like
        Object ids; negative = no object.

    Returns
    -------
    (N, 3) uint8 array
        :data:`PALETTE` ``[id]`` for ``0 <= id < len(PALETTE)``, a golden-ratio hue for
        larger ids, :data:`NO_OBJECT_RGB` for negative ids.

    Raises
    ------
    ValueError
        If ``ids`` is not a 1-D integer array.
    """
    arr = as_ids(ids)
    out = np.empty((len(arr), 3), dtype=np.uint8)
    small = (arr >= 0) & (arr < len(PALETTE))
    out[small] = PALETTE[arr[small]]
    large = arr >= len(PALETTE)
    out[large] = _golden_hues(arr[large])
    out[arr < 0] = NO_OBJECT_RGB
    return out
