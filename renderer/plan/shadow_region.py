"""Where on screen a shadow can fall: the camera pass looks shadows up only there.

A receiver point is in a light's shadow only if a caster lies between it and the light: the point
is inside that caster's *shadow volume*, the caster swept away from the light. The shadow-map
lookup itself can shade a little more than that: a filtered lookup reads texels up to
``PCF radius + 1.5`` texels from the point's own (plus the normal offset), so each caster box is
first grown by that many texels (:func:`lookup_reach`). Per visible receiver, the screen
rectangle around these volumes clipped to its box bounds every pixel of it that any light's lookup
can shade; outside it the visibility is 1 for every light, and the camera pass draws those pixels
with the variant that has no shadow code at all (:class:`ShadowRegion`): on a software rasterizer
the lookup is a large share of a pixel's cost, and a shadow covers a small part of most frames.

Everything here is a pure function of boxes, lights and the camera (numpy in, new numpy out),
exact for boxes: the volume swept by a box is bounded per receiver box by the range of sweep
parameters at which the moved (directional light) or scaled (point and spot light) caster box
still overlaps the receiver box, which is a per-axis interval test.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .geometry import (
    box_corners,
    column_max,
    column_min,
    corner_max,
    corner_min,
    points_product,
    row_norm,
    slice_max,
    slice_min,
)
from .instances import _frozen

if TYPE_CHECKING:  # the camera imports this package: types only, no import cycle
    from ..camera import Camera
    from .plan import LightShadow

#: Caster-receiver pairs tested one by one at most; past that each caster is tested against the
#: box around all visible receivers (looser, never wrong).
MAX_PAIRS = 20_000
#: Pairs whose swept boxes a scene-fitted light's kept plan holds at most (:class:`PairBoxes`,
#: about 200 KB): the renderer keeps up to four such plans per scene cache entry, so past this
#: each view sweeps its own pairs again instead.
MAX_KEPT_PAIRS = 4096
#: Texels beyond the PCF radius that a lookup may read from a caster: the gathered footprint's
#: half texel plus half a texel of rounding.
LOOKUP_REACH_TEXELS = 2.0
#: Frames of fewer pixels are drawn with lookups on every receiver: the plan's region costs
#: about a millisecond of Python for a small scene, the lookups of 100,000 pixels about as much
#: on a software rasterizer (bench/results/floor.md).
MIN_REGION_PIXELS = 100_000
#: Below this share of the frame drawn without lookups instead of with them (estimated from the
#: receivers' boxes on screen) the camera pass draws as if there were no region: drawing some
#: receivers twice and switching programs costs about as much as the lookups of 10 % of a
#: 640x480 frame on a software rasterizer (bench/results/floor.md).
MIN_SAVED_SHARE = 0.1
#: Distinct shadow rectangles the camera pass draws receivers in at most; more are merged.
MAX_BINS = 4
#: Visible receivers the camera pass splits at most: past that, drawing each one twice (with
#: lookups inside its rectangle, without outside) costs more vertex work than the lookups it
#: saves, and every receiver is drawn once, with lookups.
MAX_SPLIT_RECEIVERS = 2048
#: Camera pixels added around the projected region (rasterization rounding).
PAD_PIXELS = 2
#: Above this share of the frame the camera pass draws every receiver with shadow lookups:
#: splitting would save too little to pay for drawing the geometry again.
MAX_SPLIT_SHARE = 0.85

# The 12 edges of a box in box_corners' order (corner i: x from bit 2, y from bit 1, z bit 0).
_EDGES = np.array([(a, a | bit) for bit in (1, 2, 4) for a in range(8) if not a & bit])


Rect = tuple[int, int, int, int]

#: Draw classes of the visible instances (:attr:`ShadowRegion.classes`): drawn without lookups,
#: receiving no shadow, or receiving none on screen; drawn with lookups inside rectangle k
#: (``LOOKUP + 2 k``), and again whole without them (``LOOKUP + 2 k + 1``: the instance also
#: shows outside that rectangle).
NO_SHADOW, UNREACHED, LOOKUP = 0, 1, 2


def classes_count() -> int:
    """How many draw classes there are (the group key's modulus)."""
    return LOOKUP + 2 * MAX_BINS


@dataclass(frozen=True)
class ShadowRegion:
    """Where on screen some light's lookup may return less than 1, and how the camera pass
    draws each visible instance around it.

    Attributes
    ----------
    rect : tuple of int or None
        ``(x, y, width, height)`` in window pixels, GL's convention (origin at the bottom-left
        corner), around every pixel a shadow may reach; None: none can.
    width, height : int
        The frame's size.
    rects : tuple of tuple of int
        The rectangles receivers are drawn with lookups in (the scissor; the whole frame for
        none), at most :data:`MAX_BINS`.
    classes : ndarray, shape (N,), int8
        Per scene instance, its draw class (:data:`NO_SHADOW`, :data:`UNREACHED`, or
        ``LOOKUP + 2 k (+ 1)`` for rectangle k); only the visible instances' mean anything.
    counts : tuple of int
        Visible instances drawn with lookups, drawn without, and drawn both ways.
    saved_share : float
        Share of the frame that the receivers' boxes cover outside their rectangles: an upper
        bound on the pixels drawn without lookups that would have had them.
    """

    rect: Rect | None
    width: int
    height: int
    rects: tuple[Rect, ...]
    classes: np.ndarray
    counts: tuple[int, int, int] = (0, 0, 0)
    saved_share: float = 0.0

    @property
    def split(self) -> bool:
        """Whether the camera pass draws around the rectangles: enough is saved
        (:data:`MIN_SAVED_SHARE`); else every visible instance is drawn with lookups."""
        return self.saved_share >= MIN_SAVED_SHARE

    @property
    def share(self) -> float:
        """``rect``'s share of the frame, in [0, 1]."""
        if self.rect is None:
            return 0.0
        return self.rect[2] * self.rect[3] / float(self.width * self.height)

    def whole(self, rect: Rect | None) -> bool:
        """``rect`` is the frame: no scissor."""
        return rect == (0, 0, self.width, self.height)

    def outside(self, rect: Rect | None) -> list[Rect]:
        """The frame less ``rect`` (see :func:`outside`)."""
        return outside(rect, self.width, self.height)

    def to_dict(self) -> dict:
        lookup, plain, split = self.counts
        return {"rect": None if self.rect is None else list(self.rect),
                "share": round(self.share, 4),
                "rects": [list(r) for r in self.rects],
                "instances": {"lookup": lookup, "plain": plain, "split": split},
                "saved_share": round(self.saved_share, 4), "split": self.split}


def outside(rect: Rect | None, width: int, height: int) -> list[Rect]:
    """A frame less ``rect``, as at most four rectangles (below, above, left, right)."""
    if rect is None:
        return [(0, 0, width, height)]
    x, y, w, h = rect
    parts = [(0, 0, width, y), (0, y + h, width, height - y - h),
             (0, y, x, h), (x + w, y, width - x - w, h)]
    return [p for p in parts if p[2] > 0 and p[3] > 0]


def divide(receiver_rects: np.ndarray, visible: np.ndarray, receive: np.ndarray,
           on_screen: np.ndarray, width: int, height: int) -> ShadowRegion:
    """Sort the visible instances out by where shadows may fall on them.

    Receivers with the same rectangle share it. With more than :data:`MAX_BINS` distinct
    rectangles, or more than :data:`MAX_SPLIT_RECEIVERS` receivers to split, all receivers share
    their bounding rectangle, and a rectangle over :data:`MAX_SPLIT_SHARE` of the frame becomes
    the whole frame: drawing the geometry around it again would save too little.

    Parameters
    ----------
    receiver_rects : ndarray, shape (N, 4), int
        Per scene instance, ``(x0, y0, x1, y1)`` (exclusive ends) around the pixels where a
        shadow may fall on it; empty (``x1 <= x0``) where none can (:func:`receiver_rects`).
    visible : ndarray, shape (V,), intp
        Instances the camera pass draws.
    receive : ndarray, shape (N,), bool
        Every instance's receive flag.
    on_screen : ndarray, shape (N, 4), int
        Per scene instance, the rectangle around its box on screen (:func:`screen_rects`); read
        for the visible receivers only, and not at all past :data:`MAX_SPLIT_RECEIVERS` of them.
    """
    visible = np.asarray(visible, np.intp)
    classes = np.where(receive, UNREACHED, NO_SHADOW).astype(np.int8)
    rr = receiver_rects[visible]
    shaded = receive[visible] & (rr[:, 2] > rr[:, 0]) & (rr[:, 3] > rr[:, 1])
    cand, rr = visible[shaded], rr[shaded]
    frame = (0, 0, width, height)
    rects: list[tuple[int, int, int, int]] = []  # (x0, y0, x1, y1)
    if len(cand):
        union = (int(rr[:, 0].min()), int(rr[:, 1].min()), int(rr[:, 2].max()),
                 int(rr[:, 3].max()))
        which = np.zeros(len(cand), np.intp)
        if len(cand) > MAX_SPLIT_RECEIVERS:
            rects = [frame]
        else:
            first: dict[tuple[int, ...], int] = {}
            which = np.array([first.setdefault(tuple(r), len(first)) for r in rr.tolist()],
                             np.intp)
            rects = [tuple(r) for r in first]  # type: ignore[misc]
            if len(rects) > MAX_BINS:
                rects, which = [union], np.zeros(len(cand), np.intp)
        big = MAX_SPLIT_SHARE * width * height
        rects = [frame if (x1 - x0) * (y1 - y0) > big else (x0, y0, x1, y1)
                 for x0, y0, x1, y1 in rects]
        # Receivers whose rectangle is the frame are drawn with lookups, whole: no need to
        # know where they show.
        r = np.array(rects, np.int64)[which]  # (cand, 4): each receiver's rectangle
        placed = ~(r == frame).all(axis=1)
        seen = r.copy()
        seen[placed] = on_screen[cand[placed]]
        live = (seen[:, 2] > seen[:, 0]) & (seen[:, 3] > seen[:, 1])
        meets = live & np.all(seen[:, :2] < r[:, 2:], axis=1) & np.all(
            seen[:, 2:] > r[:, :2], axis=1)
        within = np.all(seen[:, :2] >= r[:, :2], axis=1) & np.all(seen[:, 2:] <= r[:, 2:],
                                                                  axis=1)
        # Rectangles none of whose receivers shows inside go; a receiver whose own pixels all
        # lie outside its rectangle stays UNREACHED.
        used = sorted(set(which[meets].tolist()))
        renumber = np.full(len(rects), -1, np.intp)
        renumber[used] = np.arange(len(used))
        classes[cand[meets]] = LOOKUP + 2 * renumber[which[meets]] + ~within[meets]
        rects = [rects[k] for k in used]
        # What is drawn without lookups: each receiver's box on screen outside its rectangle.
        ox0, oy0 = np.maximum(seen[:, 0], r[:, 0]), np.maximum(seen[:, 1], r[:, 1])
        ox1, oy1 = np.minimum(seen[:, 2], r[:, 2]), np.minimum(seen[:, 3], r[:, 3])
        overlap = np.where(meets, np.maximum(ox1 - ox0, 0) * np.maximum(oy1 - oy0, 0), 0)
        saved = int(np.where(live, (seen[:, 2] - seen[:, 0]) * (seen[:, 3] - seen[:, 1]),
                             0).sum() - overlap.sum())
    else:
        saved = 0
    # Visible receivers no shadow reaches on screen are drawn without lookups, whole.
    unreached = visible[receive[visible] & ~shaded]
    if len(unreached) and len(unreached) <= MAX_SPLIT_RECEIVERS:
        o = on_screen[unreached]
        saved += int(np.maximum((o[:, 2] - o[:, 0]) * (o[:, 3] - o[:, 1]), 0).sum())
    classes.flags.writeable = False
    c = classes[visible]
    looked = c >= LOOKUP
    counts = (int(looked.sum()), len(c) - int(looked.sum()),
              int((looked & ((c - LOOKUP) % 2 == 1)).sum()))
    share = min(saved / float(width * height), 1.0)
    if not rects:
        return ShadowRegion(None, width, height, (), classes, counts, share)
    ub = np.array(rects)
    x0, y0, x1, y1 = (int(v) for v in (ub[:, 0].min(), ub[:, 1].min(), ub[:, 2].max(),
                                      ub[:, 3].max()))
    return ShadowRegion((x0, y0, x1 - x0, y1 - y0), width, height,
                        tuple((a, b, c - a, d - b) for a, b, c, d in rects), classes, counts,
                        share)


def _swept_directional(lo: np.ndarray, hi: np.ndarray, r_lo: np.ndarray, r_hi: np.ndarray,
                       u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of (box swept along ``u``) ∩ receiver box, per pair.

    The box moved by ``s u`` overlaps the receiver box for ``s`` in an interval (one linear
    inequality per side and axis); over that interval the moved box stays inside its two end
    positions' hull.

    Parameters
    ----------
    lo, hi, r_lo, r_hi : ndarray, shape (..., 3)
        Caster and receiver boxes (broadcast against each other).
    u : ndarray, shape (3,)
        Unit vector the light travels along.

    Returns
    -------
    lo, hi : ndarray, shape (..., 3)
        Empty where ``lo > hi`` on some axis.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        # Overlap on axis k: lo + s u <= r_hi and hi + s u >= r_lo.
        a = (r_hi - lo) / u  # s bound from the first inequality
        b = (r_lo - hi) / u  # from the second
        pos, neg = u > 0, u < 0
        s_min = np.where(pos, b, np.where(neg, a, -np.inf))
        s_max = np.where(pos, a, np.where(neg, b, np.inf))
        # An axis the light does not travel along: the boxes overlap on it or never do.
        flat = ~(pos | neg) & ((lo > r_hi) | (hi < r_lo))
        s0 = np.maximum(slice_max(s_min, -1), 0.0)
        s1 = slice_min(s_max, -1)
        s1 = np.where(slice_max(flat, -1), -np.inf, s1)
        out_lo = np.maximum(lo + np.minimum(s0[..., None] * u, s1[..., None] * u), r_lo)
        out_hi = np.minimum(hi + np.maximum(s0[..., None] * u, s1[..., None] * u), r_hi)
    empty = (s0 > s1)[..., None]
    return np.where(empty, np.inf, out_lo), np.where(empty, -np.inf, out_hi)


def _swept_positional(lo: np.ndarray, hi: np.ndarray, r_lo: np.ndarray, r_hi: np.ndarray,
                      light: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of (box swept away from a point light) ∩ receiver box, per pair.

    The swept volume is the union over ``t >= 1`` of the box scaled by ``t`` about the light,
    ``light + t (box - light)``, itself a box; it overlaps the receiver box for ``t`` in an
    interval, and over that interval the scaled box stays inside its two end positions' hull.
    A light inside the box sweeps it over everything (``t`` unbounded).

    Parameters
    ----------
    lo, hi, r_lo, r_hi : ndarray, shape (..., 3)
    light : ndarray, shape (3,)

    Returns
    -------
    lo, hi : ndarray, shape (..., 3)
        Empty where ``lo > hi`` on some axis.
    """
    a = lo - light  # the scaled box on axis k: [light + t a, light + t b], a <= b
    b = hi - light
    p = r_hi - light  # overlap: t a <= p and t b >= q
    q = r_lo - light
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = p / a, q / b
        lower = np.maximum(np.where(a < 0, ta, -np.inf), np.where(b > 0, tb, -np.inf))
        upper = np.minimum(np.where(a > 0, ta, np.inf), np.where(b < 0, tb, np.inf))
        never = ((a == 0) & (p < 0)) | ((b == 0) & (q > 0))
        t0 = np.maximum(slice_max(lower, -1), 1.0)
        t1 = np.where(slice_max(never, -1), -np.inf, slice_min(upper, -1))
        # t a and t b are linear in t: their extremes over [t0, t1] are at the ends (an
        # unbounded t1 reaches infinity on every side the box extends from the light).
        t0e, t1e = t0[..., None], t1[..., None]
        ends_a = np.where(a == 0, 0.0, np.minimum(t0e * a, t1e * a))
        ends_b = np.where(b == 0, 0.0, np.maximum(t0e * b, t1e * b))
        out_lo = np.maximum(light + ends_a, r_lo)
        out_hi = np.minimum(light + ends_b, r_hi)
    empty = (t0 > t1)[..., None]
    return np.where(empty, np.inf, out_lo), np.where(empty, -np.inf, out_hi)


def swept_bounds(casters: np.ndarray, receivers: np.ndarray, light: LightShadow,
                 pad_texels: float) -> np.ndarray:
    """Per caster and receiver, a box holding every point of the receiver that the caster may
    shadow in the light's map.

    Parameters
    ----------
    casters : ndarray, shape (C, 2, 3)
        Caster boxes (min, max), origin-relative.
    receivers : ndarray, shape (R, 2, 3)
        Receiver boxes.
    light : LightShadow
        A light with a pass: its kind, position, direction and texel size.
    pad_texels : float
        Map texels each caster box grows by (the lookup's reach, :func:`lookup_reach`).

    Returns
    -------
    ndarray, shape (C, R, 2, 3)
        Empty boxes (min > max on some axis) where the caster cannot shadow the receiver.
        With more than :data:`MAX_PAIRS` pairs the receivers are taken together, as their
        bounding box: shape (C, 1, 2, 3); with more than that many casters, the casters too:
        shape (1, 1, 2, 3). Looser, never wrong.
    """
    if len(casters) > MAX_PAIRS:
        # Past that many casters, their box stands in for them (looser, never wrong).
        casters = np.stack([column_min(casters[:, 0]), column_max(casters[:, 1])])[None]
    lo, hi = casters[:, 0], casters[:, 1]
    maps = light.maps
    positional = light.kind in ("perspective", "cube")
    if positional:
        # A texel's world size grows with the distance to the light: grow each box by the
        # texel at its farthest corner (the sweep scales that pad along with the box).
        far = row_norm(np.maximum(np.abs(lo - light.position), np.abs(hi - light.position)))
        pad = pad_texels * max(m.texel[1] for m in maps) * far
    else:
        pad = np.full(len(lo), pad_texels * max(m.texel[0] for m in maps))
    lo, hi = (lo - pad[:, None])[:, None], (hi + pad[:, None])[:, None]  # (C, 1, 3)
    if len(casters) * len(receivers) <= MAX_PAIRS:
        r_lo, r_hi = receivers[None, :, 0], receivers[None, :, 1]  # (1, R, 3)
    else:
        r_lo = column_min(receivers[:, 0])[None, None]
        r_hi = column_max(receivers[:, 1])[None, None]
    if positional:
        out_lo, out_hi = _swept_positional(lo, hi, r_lo, r_hi, light.position)
    else:
        u = np.asarray(light.light.direction, np.float64)
        out_lo, out_hi = _swept_directional(lo, hi, r_lo, r_hi, u / np.linalg.norm(u))
    return np.stack([out_lo, out_hi], axis=2)


def screen_rects(boxes: np.ndarray, view_proj: np.ndarray, width: int, height: int
                 ) -> np.ndarray:
    """Per box, the window rectangle covering its projection, clipped to the frame.

    Parts of a box behind the camera's near plane are cut off first (the corners in front of it
    and the points where its edges cross it), so a box reaching behind the camera still projects
    to a finite rectangle.

    Parameters
    ----------
    boxes : ndarray, shape (K, 2, 3)
    view_proj : ndarray, shape (4, 4)
        World (as the boxes) to clip space.
    width, height : int

    Returns
    -------
    ndarray, shape (K, 4), int64
        ``(x0, y0, x1, y1)``, GL window pixels from the bottom-left corner (x1, y1 exclusive),
        padded by :data:`PAD_PIXELS`; ``x1 <= x0`` where no part of the box is in front of the
        camera or inside the frame.
    """
    k = len(boxes)
    if k == 0:
        return np.zeros((0, 4), np.int64)
    corners = box_corners(boxes)  # (K, 8, 3)
    clip = points_product(corners, view_proj[:, :3].T) + view_proj[:, 3]  # (K, 8, 4)
    # In front of the near plane: z_clip >= -w.
    front = clip[..., 2] + clip[..., 3]  # (K, 8)
    ahead = corner_min(front) >= 0
    if ahead.all():
        ndc = clip[..., :2] / clip[..., 3:]  # (K, 8, 2)
        lo, hi = corner_min(ndc), corner_max(ndc)
    else:
        lo, hi = _clipped_extent(clip, front, ahead)
    size = np.array([width, height, width, height], np.float64)
    # NDC past +-2 is outside the frame either way (and keeps the products finite).
    ext = np.clip(np.concatenate([lo, hi], axis=1), -2.0, 2.0)
    ext = (ext + 1.0) * 0.5 * size
    out = np.concatenate([np.floor(ext[:, :2]) - PAD_PIXELS, np.ceil(ext[:, 2:]) + PAD_PIXELS],
                         axis=1)
    out = np.clip(out, 0.0, size).astype(np.int64)
    # No part in front of the camera: empty. A NaN (a non-finite corner) says nothing of where
    # the box is: all of the frame.
    out[~np.isfinite(lo).all(axis=1) & ~np.isnan(lo).any(axis=1)] = 0
    out[np.isnan(lo).any(axis=1) | np.isnan(hi).any(axis=1)] = (0, 0, width, height)
    return out


def _clipped_extent(clip: np.ndarray, front: np.ndarray, ahead: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
    """NDC extent (lo, hi), shape (K, 2) each, of boxes cut at the near plane: their corners in
    front of it and the points where their edges cross it (+-inf where nothing is in front).

    Parameters
    ----------
    clip : ndarray, shape (K, 8, 4)
        The corners in clip space.
    front : ndarray, shape (K, 8)
        ``z + w`` per corner, >= 0 in front of the near plane.
    ahead : ndarray, shape (K,), bool
        Boxes wholly in front (no cut needed).
    """
    k = len(clip)
    lo = np.full((k, 2), np.inf)
    hi = np.full((k, 2), -np.inf)
    if ahead.any():
        c = clip[ahead]
        ndc = c[..., :2] / c[..., 3:]
        lo[ahead], hi[ahead] = ndc.min(axis=1), ndc.max(axis=1)
    cut = np.flatnonzero(~ahead)
    xyw = clip[cut][..., [0, 1, 3]]  # (M, 8, 3)
    fr = front[cut]
    ea, eb = _EDGES[:, 0], _EDGES[:, 1]
    fa, fb = fr[:, ea], fr[:, eb]  # (M, 12)
    crosses = (fa >= 0) != (fb >= 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(crosses, fa / (fa - fb), np.nan)
        pts = np.concatenate([np.where((fr >= 0)[..., None], xyw, np.nan),
                              xyw[:, ea] + t[..., None] * (xyw[:, eb] - xyw[:, ea])], axis=1)
        # On the near plane w is the camera's near distance: never zero.
        ndc = pts[..., :2] / pts[..., 2:]  # (M, 20, 2)
    keep = ~np.isnan(pts[..., 2])
    lo[cut] = np.where(keep[..., None], ndc, np.inf).min(axis=1)
    hi[cut] = np.where(keep[..., None], ndc, -np.inf).max(axis=1)
    return lo, hi


def pair_boxes(light: LightShadow, bounds: np.ndarray, receivers: np.ndarray,
               pad_texels: float) -> tuple[np.ndarray, np.ndarray]:
    """The non-empty swept boxes of a light's (caster, receiver) pairs (:func:`swept_bounds`).

    Returns
    -------
    boxes : ndarray, shape (P, 2, 3)
    pairs : ndarray, shape (P,), intp
        Each box's receiver, as a position in ``receivers``; -1 for a box that stands for every
        receiver (past :data:`MAX_PAIRS` pairs, one box around all the swept ones).
    """
    casters = sorted(set().union(*(m.casters for m in light.maps)))
    if not casters or len(receivers) == 0:
        return np.zeros((0, 2, 3)), np.zeros(0, np.intp)
    sweeps = swept_bounds(bounds[casters], bounds[receivers], light, pad_texels)
    c, r = sweeps.shape[:2]
    flat = sweeps.reshape(-1, 2, 3)
    live = np.all(flat[:, 0] <= flat[:, 1], axis=1)
    if r == 1 and len(receivers) > 1:
        # The receivers taken together: one box around the casters' swept boxes is all that is
        # drawn with, so only it is projected.
        if not live.any():
            return np.zeros((0, 2, 3)), np.zeros(0, np.intp)
        sub = flat[live]
        return (np.stack([column_min(sub[:, 0]), column_max(sub[:, 1])])[None],
                np.full(1, -1, np.intp))
    return flat[live], np.tile(np.arange(r, dtype=np.intp), c)[live]


@dataclass(frozen=True)
class PairBoxes:
    """A light's swept (caster, receiver) boxes (:func:`pair_boxes`) over every receiver of the
    scene, from which a view takes its visible receivers' (:meth:`of`).

    A map shared by every view (``shadows.fit: "scene"``) has the same casters and texels in
    each, so its pairs' boxes are the same too: a view selects them instead of sweeping again.
    Only where the pairs are swept one by one (:data:`MAX_PAIRS`): then a view's selection is
    what :func:`pair_boxes` gives its receivers, box for box.

    Attributes
    ----------
    boxes : ndarray, shape (P, 2, 3)
    receiver : ndarray, shape (P,), intp
        Each box's receiver, as an instance index.
    """

    boxes: np.ndarray
    receiver: np.ndarray

    @classmethod
    def every(cls, light: LightShadow, bounds: np.ndarray, receive: np.ndarray,
              pad_texels: float) -> PairBoxes | None:
        """The pairs of every receiver (``receive``, shape (N,), bool) with the light's casters;
        None where there are more than :data:`MAX_KEPT_PAIRS` (a view then sweeps its own; below
        :data:`MAX_PAIRS` every pair is swept one by one, so a view's selection is what
        :func:`pair_boxes` gives it)."""
        receivers = np.flatnonzero(receive)
        if len(set().union(*(m.casters for m in light.maps))) * len(receivers) > MAX_KEPT_PAIRS:
            return None
        boxes, which = pair_boxes(light, bounds, receivers, pad_texels)
        return cls(_frozen(boxes), _frozen(receivers[which]))

    def of(self, receivers: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
        """:func:`pair_boxes` for ``receivers`` (R,), instance indices among ``count``: the
        boxes of their pairs (in another order) and each one's position in ``receivers``."""
        position = np.full(count, -1, np.intp)
        position[receivers] = np.arange(len(receivers))
        which = position[self.receiver]
        keep = which >= 0
        return self.boxes[keep], which[keep]


def plan_region(lights: list[LightShadow], bounds: np.ndarray, visible: np.ndarray,
                receive: np.ndarray, view_proj: np.ndarray, width: int, height: int,
                pad_texels: float, pairs: list[PairBoxes | None] | None = None
                ) -> tuple[list[bool], ShadowRegion]:
    """Where each light's lookups may shade on screen, and how the camera pass draws around it.

    Every box is projected in one call: the swept boxes of every light's pairs and the visible
    receivers' own boxes.

    Parameters
    ----------
    lights : list of LightShadow
        The plan's lights (those without a pass add nothing).
    bounds : ndarray, shape (N, 2, 3)
        Every instance's box, origin-relative.
    visible : ndarray, shape (V,), intp
        Instances the camera pass draws.
    receive : ndarray, shape (N,), bool
    view_proj : ndarray, shape (4, 4)
        Origin-relative world to the camera's clip space (:func:`view_projection`).
    pad_texels : float
        See :func:`lookup_reach`.
    pairs : list of PairBoxes or None, optional
        Per light, its pairs over every receiver where they are kept (a scene-fit map's), else
        None: the light's pairs are swept here. The region is the same either way.

    Returns
    -------
    reached : list of bool
        Per light, whether a shadow of it may show on a visible pixel (False for a light
        without a pass).
    region : ShadowRegion
    """
    visible = np.asarray(visible, np.intp)
    receivers = visible[receive[visible]]
    kept = pairs if pairs is not None else [None] * len(lights)
    parts = [(np.zeros((0, 2, 3)), np.zeros(0, np.intp)) if lp.kind is None
             else pair_boxes(lp, bounds, receivers, pad_texels) if pk is None
             else pk.of(receivers, len(bounds))
             for lp, pk in zip(lights, kept, strict=True)]
    own = receivers if len(receivers) <= MAX_SPLIT_RECEIVERS else receivers[:0]
    boxes = np.concatenate([b for b, _ in parts] + [bounds[own]])
    rects = screen_rects(boxes, view_proj, width, height)
    n = len(bounds)
    on_screen = np.zeros((n, 4), np.int64)
    on_screen[own] = rects[len(rects) - len(own):]
    live = (rects[:, 2] > rects[:, 0]) & (rects[:, 3] > rects[:, 1])
    reached, start = [], 0
    for box, _ in parts:
        reached.append(bool(live[start:start + len(box)].any()))
        start += len(box)
    paired = len(rects) - len(own)  # the pairs' rectangles, every light's, then the receivers'
    which = np.concatenate([w for _, w in parts]) if parts else np.zeros(0, np.intp)
    per = union_per_receiver(rects[:paired], which, len(receivers))
    rect_of = np.zeros((n, 4), np.int64)
    rect_of[receivers] = per
    return reached, divide(rect_of, visible, receive, on_screen, width, height)


def union_per_receiver(rects: np.ndarray, which: np.ndarray, count: int) -> np.ndarray:
    """Per receiver in ``range(count)``, the bounding rectangle of the non-empty rectangles
    given to it.

    Parameters
    ----------
    rects : ndarray, shape (M, 4), int
        ``(x0, y0, x1, y1)``; empty where ``x1 <= x0`` or ``y1 <= y0`` (left out).
    which : ndarray, shape (M,), intp
        Each rectangle's receiver; -1 gives it to every receiver.
    count : int

    Returns
    -------
    ndarray, shape (count, 4), int64
        All zeros for a receiver given no non-empty rectangle.
    """
    big = np.iinfo(np.int64).max
    lo = np.full((count, 2), big, np.int64)
    hi = np.full((count, 2), -big, np.int64)
    live = (rects[:, 2] > rects[:, 0]) & (rects[:, 3] > rects[:, 1])
    every = live & (which < 0)
    if every.any():
        np.minimum(lo, column_min(rects[every, :2]), out=lo)
        np.maximum(hi, column_max(rects[every, 2:]), out=hi)
    own = live & (which >= 0)
    np.minimum.at(lo, which[own], rects[own, :2])
    np.maximum.at(hi, which[own], rects[own, 2:])
    out = np.concatenate([lo, hi], axis=1)
    out[lo[:, 0] == big] = 0
    return out


def view_projection(camera: Camera, origin: np.ndarray) -> np.ndarray:
    """The camera's view-projection matrix for origin-relative points, shape (4, 4)
    (:meth:`~renderer.camera.Camera.view_from`)."""
    return camera.view_projection(origin)


def lookup_reach(pcf_radius: int, normal_offset: float) -> float:
    """Map texels between a lookup point and the farthest texel centre its lookup compares."""
    return pcf_radius + LOOKUP_REACH_TEXELS + normal_offset
